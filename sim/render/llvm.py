"""Finding libLLVM for Dr.Jit's CPU backend before Mitsuba is imported."""

from __future__ import annotations

import glob
import os
import re

MIN_VERSION = (
    16  # LLVM 15 cannot select Mitsuba 3.9's fminimum kernels (measured: "LLVM ERROR: Cannot select")
)
_SEARCH = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib",
    "/usr/local/lib",
    "/usr/lib/llvm-*/lib",
)


class RendererUnavailable(RuntimeError):
    """Mitsuba cannot run here; the message says which package to install."""


def find_libllvm() -> str:
    """The newest libLLVM ≥ 16 on this machine (``DRJIT_LIBLLVM_PATH`` wins when set)."""
    if path := os.environ.get("DRJIT_LIBLLVM_PATH"):
        return path
    found = []
    for folder in _SEARCH:
        for path in glob.glob(os.path.join(folder, "libLLVM*.so*")):
            m = re.search(r"LLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
            if m and int(m.group(1)) >= MIN_VERSION:
                found.append((int(m.group(1)), path))
    if not found:
        raise RendererUnavailable(
            f"the simulated camera renders with Mitsuba 3, whose CPU backend needs libLLVM {MIN_VERSION} or newer; "
            "install it (Debian/Ubuntu: sudo apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH"
        )
    return max(found)[1]


def load_mitsuba(variant: str | None = None):
    """Import Mitsuba and set ``variant`` (default: ``cuda_ad_rgb`` when Dr.Jit sees a CUDA device, else
    ``llvm_ad_rgb``); returns the module. The libLLVM path is set before Dr.Jit is first imported, which is
    when it decides which library to load."""
    missing = None
    try:
        os.environ["DRJIT_LIBLLVM_PATH"] = find_libllvm()
    except RendererUnavailable as exc:
        missing = exc  # fatal only if the LLVM backend is the one we need
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise RendererUnavailable("Mitsuba is not installed: pip install 'hlr-lab[sim]'") from exc
    if variant is None:
        variant = "cuda_ad_rgb" if dr.has_backend(dr.JitBackend.CUDA) else "llvm_ad_rgb"
    if variant.startswith("llvm") and missing is not None:
        raise missing
    mi.set_variant(variant)
    return mi
