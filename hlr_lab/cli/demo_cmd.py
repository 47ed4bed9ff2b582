"""``hlr-lab demo``: the whole instrument on the simulated rig in one command — segment, plan, acquire,
fit, report, export — then the fitted materials against the simulated world's truth.

Each step is the library function its command calls (:mod:`hlr_lab.pipeline`), with the command's
defaults. It is the one place that reads the simulator's ground truth, to show the error.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import click
import numpy as np
from rich.markup import escape
from rich.table import Table

from hlr_lab.cli.common import placement_options, region_table, speed_factor_option, true_rig_option
from hlr_lab.cli.console import console
from hlr_lab.cli.fit_cmd import materials_table
from hlr_lab.cli.plan_cmd import coverage_table
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.plan import PlanFile, write_plan
from hlr_lab.formats.regions import write_regions
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, export_materials, fit_into, load_object, plan_object, report_into
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.reflectance.session_fit import MATERIALS
from hlr_lab.rig.file import sim_rig
from worlds.plan_world import scene_file_object, sim_links, sim_scene

DEFAULT_OBJECT = "builtin:pebble"


@click.command("demo")
@click.option(
    "--scene",
    "scene_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="A sim scene file: its mesh (with colours) is the object, its regions the true materials. "
    "Default: the built-in procedural multi-region object.",
)
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("hlr-lab-demo"),
    show_default=True,
    help="Folder for everything the demo writes (a new one: the demo never overwrites).",
)
@placement_options
@true_rig_option
@speed_factor_option("Simulated", default=20.0)
def demo(
    scene_path: Path | None, out: Path, up: str, scale: float, true_rig: str | None, speed_factor: float
) -> None:
    """Run the whole measurement on the simulated rig and compare the result with the truth.

    \b
    Steps (each does what the hlr-lab command of the same name does, with its defaults):
      segment → plan → acquire (simulated rig) → fit → report → export (OBJ, glTF, Mitsuba)

    \b
    Examples:
      hlr-lab demo
      hlr-lab demo --scene my-object/scene.toml --out demo-2
      hlr-lab demo --scene scan/scene.toml --up y --scale 0.001 --out demo-scan   # a y-up scan in mm
      hlr-lab demo --true-rig builtin:bench-offsets --out demo-3   # the rig is not its drawing
    """
    if out.exists() and any(out.iterdir()):
        raise InputError("the folder is not empty; give a new --out", path=out, field="--out")
    out.mkdir(parents=True, exist_ok=True)
    mesh_spec = _object(scene_path)
    regions_path, plan_path, session = out / "regions.json", out / "plan.json", out / "session"
    rig = sim_rig()

    _step("segment", f"{mesh_spec} → {regions_path}")
    mesh = load_object(mesh_spec)
    seg = segment(mesh)
    write_regions(regions_path, mesh, seg, mesh_name=mesh_spec, regions_requested=None)
    console.print(region_table(seg.regions, f"{seg.n_regions} regions of {mesh_spec}"))

    _step("plan", f"→ {plan_path}")
    with console.status("planning…"):
        plan, planned = plan_object(mesh, seg, rig, PlanSettings(), mesh_spec=mesh_spec, plan_folder=out, up=up,
                                     scale=scale)  # fmt: skip
    write_plan(plan_path, plan)
    console.print(coverage_table(planned, seg))
    if planned.uncovered:
        console.print("[yellow]some regions cannot be covered; the demo goes on with the others[/]")

    _step("acquire", f"on the simulated rig{f' built as {true_rig}' if true_rig else ''} → {session}")
    with contextlib.ExitStack() as stack:
        links = sim_links(stack, rig, plan, plan_path, scene_path, true_rig, speed_factor)
        with console.status("acquiring…") as status:
            outcome = acquire_plan(
                plan_path, rig, session, links=links,
                progress=lambda s: status.update(escape(f"pose {s.index + 1}/{s.poses}: {s.pose}: {s.action}")),
            )  # fmt: skip
    console.print(f"{outcome.taken} frames in {outcome.duration_s:.1f} s")

    _step("fit", f"{session}")
    with console.status("fitting…"):
        fitted = fit_into(session)
    console.print(materials_table(fitted.materials))

    _step("report", f"{session / 'report.html'}")
    with console.status("building the report…"):
        report, _, _ = report_into(session)

    exports = out / "export"
    exports.mkdir()
    for fmt, name in (("obj", "object.obj"), ("gltf", "object.glb"), ("mitsuba", "mitsuba")):
        _step("export", f"{fmt} → {exports / name}")
        _, stand_ins = export_materials(
            session / MATERIALS, mesh, fmt, exports / name, regions_path=regions_path
        )
        if stand_ins:
            console.print(f"[yellow]region(s) {', '.join(map(str, stand_ins))}: no fitted material, exported with "
                          "their colour as a stand-in[/]")  # fmt: skip
    console.print(_truth_table(plan, plan_path, scene_path, session))
    console.print(f"report: [bold]{escape(str(report))}[/] — open it in a browser")


def _object(scene_path: Path | None) -> str:
    return DEFAULT_OBJECT if scene_path is None else str(scene_file_object(scene_path).mesh)


def _step(name: str, what: str) -> None:
    console.rule(escape(f"{name}: {what}"))


def _truth_table(plan: PlanFile, plan_path: Path, scene_path: Path | None, session: Path) -> Table:
    """Fitted against true per region; a plan region takes the true material of the scene region whose
    colour is nearest (the default world: one material per plan region)."""
    scene = sim_scene(plan, plan_path, scene_path)
    fitted = {e.id: e for e in read_materials(session / MATERIALS).regions}
    if scene_path is None:
        truth = dict(zip((r.id for r in plan.object.regions), scene.materials, strict=True))
    else:
        scene_regions = scene_file_object(scene_path).region_colours
        truth = {
            r.id: scene.materials[
                int(np.argmin([np.sum((np.array(c) - r.color) ** 2) for c in scene_regions]))
            ]
            for r in plan.object.regions
        }
    t = Table(title="fitted against the simulated truth", title_justify="left")
    for column in ("region", "Rd fitted", "Rd true", "Rd err %", "Rs err %", "n fitted (true)", "n err %"):
        t.add_column(column, justify="right")
    for rid, true in sorted(truth.items()):
        e = fitted.get(rid)
        if e is None:
            t.add_row(str(rid), "not seen", *[""] * 5)
            continue
        rd, true_rd = np.array(e.rd), np.array(true.rd)
        row = [str(rid), _v(rd), _v(true_rd), f"{_err(rd, true_rd):.2f}"]
        if e.specular == "measured":
            assert e.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.n is not None
            row += [f"{_err(np.array(e.rs), np.array(true.rs)):.2f}", f"{e.n:.1f} ({true.n:g})"]
            row.append(f"{100 * abs(e.n - true.n) / true.n:.2f}")
        else:
            row += ["unmeasured", f"— ({true.n:g})", ""]
        t.add_row(*row)
    return t


def _v(a: np.ndarray) -> str:
    return " ".join(f"{x:.3f}" for x in a)


def _err(got: np.ndarray, true: np.ndarray) -> float:
    """|Δ| / |true| in percent (per region, over the three channels)."""
    return 100 * float(np.linalg.norm(got - true) / np.linalg.norm(true))
