"""The fitted materials against the simulated world's truth: the one place hlr-lab's results meet the
simulator's ground truth (``hlr-lab demo`` prints it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.plan import PlanFile
from hlr_lab.reflectance.session_fit import MATERIALS
from sim.render.scene import Material
from worlds.plan_world import scene_file_object, sim_scene


def truth_table(plan: PlanFile, plan_path: Path, scene_path: Path | None, session: Path) -> Table:
    """Fitted against true per region, errors in per cent; a plan region takes the true material of the
    scene region whose colour is nearest (the default world: one material per plan region)."""
    fitted = {e.id: e for e in read_materials(session / MATERIALS).regions}
    truth = true_materials(plan, plan_path, scene_path)
    t = Table(title="fitted against the simulated truth", title_justify="left")
    for column in ("region", "Rd fitted", "Rd true", "Rd err %", "Rs err %", "n fitted (true)", "n err %"):
        t.add_column(column, justify="right")
    for rid, true in sorted(truth.items()):
        e = fitted.get(rid)
        if e is None:
            t.add_row(str(rid), "not seen", *[""] * 5)
            continue
        rd, true_rd = np.array(e.rd), np.array(true.rd)
        row = [str(rid), _v(rd), _v(true_rd), f"{relative_error_pct(rd, true_rd):.2f}"]
        if e.specular == "measured":
            assert e.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.n is not None
            row += [f"{relative_error_pct(np.array(e.rs), np.array(true.rs)):.2f}", f"{e.n:.1f} ({true.n:g})"]
            row.append(f"{100 * abs(e.n - true.n) / true.n:.2f}")
        else:
            row += ["unmeasured", f"— ({true.n:g})", ""]
        t.add_row(*row)
    return t


BLACK_RD = 0.01  # a true Rd below this (its norm over the channels) is black: no relative error


def true_materials(plan: PlanFile, plan_path: Path, scene_path: Path | None) -> dict[int, Material]:
    """Each plan region's true material: the scene region's whose colour is nearest (the default world: one
    material per plan region)."""
    scene = sim_scene(plan, plan_path, scene_path)
    if scene_path is None:
        return dict(zip((r.id for r in plan.object.regions), scene.materials, strict=True))
    scene_regions = scene_file_object(scene_path).region_colours
    return {
        r.id: scene.materials[int(np.argmin([np.sum((np.array(c) - r.color) ** 2) for c in scene_regions]))]
        for r in plan.object.regions
    }


def worst_errors_pct(
    plan: PlanFile, plan_path: Path, scene_path: Path | None, session: Path
) -> dict[str, float]:
    """The worst region's error (per cent) of Rd, Rs and n fitted in ``session`` against the truth; NaN for a
    parameter no region measured. A region black in truth (|Rd| < :data:`BLACK_RD`: Spot's pupils, Rd 0) has
    no relative Rd error to speak of and is left out of Rd's."""
    fitted = {e.id: e for e in read_materials(session / MATERIALS).regions}
    worst = {"rd": float("nan"), "rs": float("nan"), "n": float("nan")}
    for rid, true in true_materials(plan, plan_path, scene_path).items():
        e = fitted.get(rid)
        if e is None:
            continue
        black = float(np.linalg.norm(true.rd)) < BLACK_RD
        errors = {} if black else {"rd": relative_error_pct(np.array(e.rd), np.array(true.rd))}
        if e.specular == "measured" and e.rs is not None and e.n is not None:
            errors["rs"] = relative_error_pct(np.array(e.rs), np.array(true.rs))
            errors["n"] = 100 * abs(e.n - true.n) / true.n
        worst.update({k: float(np.nanmax([worst[k], v])) for k, v in errors.items()})
    return worst


def _v(a: NDArray[np.float64]) -> str:
    return " ".join(f"{x:.3f}" for x in a)


def relative_error_pct(got: NDArray[np.float64], true: NDArray[np.float64]) -> float:
    """|got − true| / |true| in per cent, over the three channels. Shapes: (3,), (3,)."""
    return 100 * float(np.linalg.norm(got - true) / np.linalg.norm(true))
