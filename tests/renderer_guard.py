"""Skip renderer tests where Mitsuba or libLLVM is missing, and GenICam tests where Aravis is — except in
CI, which installs all of them, so that there a missing one fails instead of passing silently. The
simulated camera is a GigE Vision device reached through Aravis, so a renderer test needs both."""

import os

import pytest

from sim.render.llvm import RendererUnavailable, find_libllvm


def require_aravis(*, module_level: bool = False) -> None:
    from drivers.genicam_camera import AravisMissing, aravis

    try:
        aravis()
    except AravisMissing as exc:  # pragma: no cover - CI installs it
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no Aravis here: {exc}", allow_module_level=module_level)


def require_renderer(*, module_level: bool = False) -> None:
    try:
        find_libllvm()
        import mitsuba  # noqa: F401
    except (RendererUnavailable, ImportError) as exc:  # pragma: no cover - CI installs both
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no renderer here: {exc}", allow_module_level=module_level)
    require_aravis(module_level=module_level)
