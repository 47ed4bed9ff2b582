"""``hlr-lab demo``: the whole instrument on the simulated rig in one command — segment, plan, acquire,
fit, report, export — then the fitted materials against the simulated world's truth.

It runs the very commands a user runs (same options, same output), one after the other. It is the one
place that reads the simulator's ground truth, to show the error.
"""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
from rich.markup import escape
from rich.table import Table

from hlr_lab.cli.common import speed_factor_option, true_rig_option
from hlr_lab.cli.console import console
from hlr_lab.cli.sim_world import scene_file_object, sim_scene
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.plan import PlanFile, read_plan
from hlr_lab.reflectance.session_fit import MATERIALS

DEFAULT_OBJECT = "builtin:pebble"
EXIT_UNCOVERED = 3  # plan's status when some region cannot be covered: the demo goes on


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
@true_rig_option
@speed_factor_option("Simulated", default=20.0)
def demo(scene_path: Path | None, out: Path, true_rig: str | None, speed_factor: float) -> None:
    """Run the whole measurement on the simulated rig and compare the result with the truth.

    \b
    Steps (each is the hlr-lab command of the same name):
      segment → plan → acquire (simulated rig) → fit → report → export (OBJ, glTF, Mitsuba)

    \b
    Examples:
      hlr-lab demo
      hlr-lab demo --scene my-object/scene.toml --out demo-2
      hlr-lab demo --true-rig builtin:bench-offsets --out demo-3   # the rig is not its drawing
    """
    if out.exists() and any(out.iterdir()):
        raise InputError("the folder is not empty; give a new --out", path=out, field="--out")
    out.mkdir(parents=True, exist_ok=True)
    mesh = _object(scene_path)
    regions, plan_path, session = out / "regions.json", out / "plan.json", out / "session"
    run = _runner()
    run("segment", "--mesh", mesh, "-o", regions)
    if run("plan", "--mesh", mesh, "--regions", regions, "--sim", "-o", plan_path) == EXIT_UNCOVERED:
        console.print("[yellow]some regions cannot be covered; the demo goes on with the others[/]")
    world = (["--scene", scene_path] if scene_path else []) + (["--true-rig", true_rig] if true_rig else [])
    run("acquire", "--plan", plan_path, "--sim", *world, "--out", session, "--speed-factor", speed_factor)
    run("fit", session)
    run("report", session)
    exports = out / "export"
    exports.mkdir()
    common = [session / MATERIALS, "--mesh", mesh, "--regions", regions]
    run("export", *common, "--format", "obj", "-o", exports / "object.obj")
    run("export", *common, "--format", "gltf", "-o", exports / "object.glb")
    run("export", *common, "--format", "mitsuba", "-o", exports / "mitsuba")
    plan = read_plan(plan_path)
    console.print(_truth_table(plan, plan_path, scene_path, session))
    console.print(f"report: [bold]{escape(str(session / 'report.html'))}[/] — open it in a browser")


def _object(scene_path: Path | None) -> str:
    return DEFAULT_OBJECT if scene_path is None else str(scene_file_object(scene_path).mesh)


def _runner():
    """Run an hlr-lab command in this process, as typed; a failure stops the demo with its error."""
    group = click.get_current_context().find_root().command

    def run(*args) -> int:
        words = [str(a) for a in args]
        console.rule(f"hlr-lab {' '.join(escape(w) for w in words)}")
        code = group.main(args=words, prog_name="hlr-lab", standalone_mode=False) or 0
        if code not in (0, EXIT_UNCOVERED):
            raise InputError(f"hlr-lab {words[0]} ended with status {code}")
        return code

    return run


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
