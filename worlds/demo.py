"""The whole instrument on the simulated rig — segment, plan, acquire, fit, report, export — then the
fitted materials against the simulated world's truth (``hlr-lab demo``).

Each step is the library function its command calls (:mod:`hlr_lab.pipeline`), with the command's
defaults; what it shows goes to a :class:`Display`, so that the command line and other programs run the
same demo.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Protocol

from rich.console import RenderableType
from rich.markup import escape

from hlr_lab.display.materials import fit_notes, materials_table
from hlr_lab.display.plan import coverage_table
from hlr_lab.display.regions import region_table
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import write_plan
from hlr_lab.formats.regions import write_regions
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, export_materials, fit_into, load_object, plan_object, report_into
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.reflectance.session_fit import MATERIALS
from hlr_lab.rig.file import sim_rig
from worlds.plan_world import ObjectOffset, scene_file_object, sim_links
from worlds.truth import truth_table

DEFAULT_OBJECT = "builtin:pebble"
EXPORTS = (("obj", "object.obj"), ("gltf", "object.glb"), ("mitsuba", "mitsuba"))


class Display(Protocol):
    """Where the demo shows what it does."""

    def step(self, name: str, what: str) -> None:
        """A step begins: its command's name and what it reads and writes."""
        ...

    def show(self, item: RenderableType) -> None:
        """A table or a line (rich markup) to show."""
        ...

    def busy(self, what: str) -> AbstractContextManager[Callable[[str], None]]:
        """While long work runs: a status line, updated through the callable it gives."""
        ...


def run_demo(
    out: Path,
    display: Display,
    scene_path: Path | None = None,
    *,
    up: str = "z",
    scale: float = 1.0,
    true_rig: str | None = None,
    speed_factor: float = 20.0,
    offset: ObjectOffset | None = None,
) -> Path:
    """Measure the scene's object (default: builtin:pebble in the default world) into ``out``, a new or
    empty folder: regions.json, plan.json, session/ (with materials.json and report.html), export/.
    ``offset``: the world's object off where the plan puts it (hlr-lab is not told).

    Returns the report's path.
    """
    if out.exists() and any(out.iterdir()):
        raise InputError("the folder is not empty; give a new --out", path=out, field="--out")
    out.mkdir(parents=True, exist_ok=True)
    mesh_spec = DEFAULT_OBJECT if scene_path is None else str(scene_file_object(scene_path).mesh)
    regions_path, plan_path, session = out / "regions.json", out / "plan.json", out / "session"
    rig = sim_rig()

    display.step("segment", f"{mesh_spec} → {regions_path}")
    mesh = load_object(mesh_spec)
    seg = segment(mesh)
    write_regions(regions_path, mesh, seg, mesh_name=mesh_spec, regions_requested=None)
    display.show(region_table(seg.regions, f"{seg.n_regions} regions of {mesh_spec}"))

    display.step("plan", f"→ {plan_path}")
    with display.busy("planning…"):
        plan, planned = plan_object(mesh, seg, rig, PlanSettings(), mesh_spec=mesh_spec, plan_folder=out, up=up,
                                     scale=scale)  # fmt: skip
    write_plan(plan_path, plan)
    display.show(coverage_table(planned, seg))
    if planned.uncovered:
        display.show("[yellow]some regions cannot be covered; the demo goes on with the others[/]")

    display.step("acquire", f"on the simulated rig{f' built as {true_rig}' if true_rig else ''} → {session}")
    with contextlib.ExitStack() as stack:
        links = sim_links(stack, rig, plan, plan_path, scene_path, true_rig, speed_factor, offset)
        with display.busy("acquiring…") as status:
            outcome = acquire_plan(
                plan_path, rig, session, links=links,
                progress=lambda s: status(escape(f"pose {s.index + 1}/{s.poses}: {s.pose}: {s.action}")),
            )  # fmt: skip
    display.show(f"{outcome.taken} frames in {outcome.duration_s:.1f} s")

    display.step("fit", f"{session}")
    with display.busy("fitting…"):
        fitted = fit_into(session)
    display.show(materials_table(fitted.materials))
    for line in fit_notes(fitted):
        display.show(line)

    display.step("report", f"{session / 'report.html'}")
    with display.busy("building the report…"):
        report, _, _ = report_into(session)

    exports = out / "export"
    exports.mkdir()
    for fmt, name in EXPORTS:
        display.step("export", f"{fmt} → {exports / name}")
        _, stand_ins = export_materials(
            session / MATERIALS, mesh, fmt, exports / name, regions_path=regions_path
        )
        if stand_ins:
            display.show(f"[yellow]region(s) {', '.join(map(str, stand_ins))}: no fitted material, exported with "
                         "their colour as a stand-in[/]")  # fmt: skip
    display.show(truth_table(plan, plan_path, scene_path, session))
    return report
