"""hlr-lab: reflectance measurement with highlight-priority light planning.

The public surface: the measurement's steps (:mod:`hlr_lab.pipeline`), the rig opened and made safe
(:func:`open_rig`), rig files (:func:`load_rig`) and the errors every step raises. Each name is imported
when first used, so that ``import hlr_lab`` (and ``hlr-lab --help``) stays instant.

Example::

    import hlr_lab

    rig = hlr_lab.load_rig("rig.toml")
    outcome = hlr_lab.acquire_plan(Path("plan.json"), rig, Path("session"))
    hlr_lab.fit_into(Path("session"))
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# public name → the module that defines it
_SURFACE = {
    "load_object": "hlr_lab.pipeline",
    "plan_object": "hlr_lab.pipeline",
    "acquire_plan": "hlr_lab.pipeline",
    "fit_into": "hlr_lab.pipeline",
    "report_into": "hlr_lab.pipeline",
    "export_materials": "hlr_lab.pipeline",
    "open_rig": "hlr_lab.instrument.control",
    "OpenRig": "hlr_lab.instrument.control",
    "RunStopped": "hlr_lab.instrument.control",
    "load_rig": "hlr_lab.rig.file",
    "sim_rig": "hlr_lab.rig.file",
    "Rig": "hlr_lab.rig.file",
    "HlrLabError": "hlr_lab.errors",
    "InputError": "hlr_lab.errors",
    "PlanningError": "hlr_lab.errors",
    "RigNotReady": "hlr_lab.errors",
    "DiskFull": "hlr_lab.errors",
}
__all__ = [  # the names of _SURFACE (a test keeps them equal)
    "DiskFull",
    "HlrLabError",
    "InputError",
    "OpenRig",
    "PlanningError",
    "Rig",
    "RigNotReady",
    "RunStopped",
    "__version__",
    "acquire_plan",
    "export_materials",
    "fit_into",
    "load_object",
    "load_rig",
    "open_rig",
    "plan_object",
    "report_into",
    "sim_rig",
]

if TYPE_CHECKING:  # the same names, for type checkers and editors
    from hlr_lab.errors import DiskFull, HlrLabError, InputError, PlanningError, RigNotReady
    from hlr_lab.instrument.control import OpenRig, RunStopped, open_rig
    from hlr_lab.pipeline import (
        acquire_plan,
        export_materials,
        fit_into,
        load_object,
        plan_object,
        report_into,
    )
    from hlr_lab.rig.file import Rig, load_rig, sim_rig


def __getattr__(name: str) -> Any:
    if name not in _SURFACE:
        raise AttributeError(f"module 'hlr_lab' has no attribute {name!r}")
    value = getattr(importlib.import_module(_SURFACE[name]), name)
    globals()[name] = value  # once imported, an ordinary attribute
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
