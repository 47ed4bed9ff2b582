"""Skip renderer tests where Mitsuba or libLLVM is missing — except in CI, which installs both, so that
there a missing renderer fails instead of passing silently."""

import os

import pytest

from sim.render.llvm import RendererUnavailable, find_libllvm


def require_renderer(*, module_level: bool = False) -> None:
    try:
        find_libllvm()
        import mitsuba  # noqa: F401
    except (RendererUnavailable, ImportError) as exc:  # pragma: no cover - CI installs both
        if os.environ.get("CI"):
            raise
        pytest.skip(f"no renderer here: {exc}", allow_module_level=module_level)
