"""``hlr-lab bench materials``: do the fitted materials, and their standard errors, tell the truth?

Each scene is an object (the built-in pebble, the Stanford bunny painted in 8 patches, Spot with its
texture) given seeded random materials of the range a user measures (n log-uniform 8–500, each Rd channel
log-uniform 0.02–0.9, a grey Rs with Rd + Rs ≤ 1), planned on the rig hlr-lab believes, photographed in a
simulated world built as that rig or as a ``true_rig`` (a bench that differs from its drawing), and fitted.
Every fitted parameter is compared with the truth: its error in per cent, and in standard errors — the
fraction within 1 and 2 stated σ is the uncertainties' coverage (≈ 68 % and ≥ 90 % when they are honest):
the statistical σ alone, and combined with the systematic one (√(se² + sys²)) where the fit gave it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from hlr_lab.adaptive.run import acquire_adaptive
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_text
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.object.mesh import ColouredMesh, load_mesh, write_vertex_coloured_ply
from hlr_lab.object.procedural import paint_patches
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, fit_into, load_object, plan_object
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.file import Rig
from sim.render.scene import Material
from sim.rig import SimRig
from worlds.plan_world import sim_scene, world_geometry, world_links

N_RANGE, RD_RANGE, RS_RANGE = (8.0, 500.0), (0.02, 0.9), (0.05, 0.5)
OBJECTS = ("pebble", "bunny", "spot")
PARAMETERS = ("rd", "rs", "n")


@dataclass(frozen=True)
class BenchObject:
    """How an object of the bench is made and stood on the plate."""

    name: str
    up: str = "z"
    scale: float = 1.0


BENCH_OBJECTS = {
    "pebble": BenchObject("pebble"),
    "bunny": BenchObject("bunny", up="y"),  # stanford-bunny.obj, metres, y up
    "spot": BenchObject("spot", up="y", scale=0.08),  # spot_triangulated.obj: ~1 unit long
}


@dataclass(frozen=True)
class ParameterResult:
    """One fitted parameter against its truth (a channel of Rd or Rs, or n)."""

    scene: int
    object: str
    region: int
    parameter: str  # "rd", "rs" or "n"
    channel: int  # 0–2 (n: 0)
    true: float
    fitted: float
    se: float
    sys: float | None = None  # the systematic σ, where the fit propagated it

    @property
    def error_pct(self) -> float:
        return 100.0 * (self.fitted / self.true - 1.0)

    @property
    def z(self) -> float:
        """The error in statistical standard errors (inf: an error with a zero standard error)."""
        return _in_sigmas(self.fitted - self.true, self.se)

    @property
    def z_combined(self) -> float:
        """The error in combined standard errors √(se² + sys²) (the statistical alone without a sys)."""
        return _in_sigmas(self.fitted - self.true, float(np.hypot(self.se, self.sys or 0.0)))


def _in_sigmas(err: float, sigma: float) -> float:
    return abs(err) / sigma if sigma > 0 else (0.0 if err == 0 else float("inf"))


@dataclass(frozen=True)
class SceneResult:
    scene: int
    object: str
    parameters: list[ParameterResult]
    unmeasured: list[int]  # regions fitted without a specular (Rd only), with their reasons in notes
    unfitted: list[int]  # regions without an entry
    notes: list[str]
    poses: int | None = None  # the poses photographed


def held_out_materials(count: int, rng: np.random.Generator) -> list[Material]:
    """``count`` random materials across the range a user measures: n log-uniform in N_RANGE, each Rd
    channel log-uniform in RD_RANGE, a grey Rs uniform in RS_RANGE but at most 1 − max Rd (energy is
    not created) and at least 0.05."""
    (n_low, n_high), (rd_low, rd_high) = np.log(N_RANGE), np.log(RD_RANGE)
    log_n = rng.uniform(n_low, n_high, count)
    rd = np.exp(rng.uniform(rd_low, rd_high, (count, 3)))
    rs_high = np.clip(1.0 - rd.max(axis=1), RS_RANGE[0], RS_RANGE[1])
    rs = RS_RANGE[0] + rng.uniform(0.0, 1.0, count) * (rs_high - RS_RANGE[0])
    return [
        Material((float(d[0]), float(d[1]), float(d[2])), (float(s), float(s), float(s)), float(np.exp(ln)))
        for d, s, ln in zip(rd.round(4), rs.round(4), log_n, strict=True)
    ]


def bench_mesh(name: str, assets: Path | None, folder: Path, seed: int) -> tuple[ColouredMesh, str]:
    """The object ``name`` (BENCH_OBJECTS) as a coloured mesh and the spec its plan refers to it by: the
    pebble built in; the bunny painted in 8 patches (``seed``: the patches) into ``folder``; Spot with its
    texture. The bunny and Spot come from ``assets`` (a folder with stanford-bunny.obj and spot/)."""
    if name == "pebble":
        return load_object("builtin:pebble"), "builtin:pebble"
    if assets is None:
        raise InputError(f"the {name} needs the test assets: give --assets DIR", field="--assets")
    if name == "bunny":
        painted = paint_patches(load_mesh(assets / "stanford-bunny.obj"), 8, seed=seed).mesh
        path = folder / "bunny8.ply"
        write_vertex_coloured_ply(path, painted)
        return load_object(str(path)), str(path)
    spot = assets / "spot"
    mesh = load_object(str(spot / "spot_triangulated.obj"), spot / "spot_texture.png")
    return mesh, str(spot / "spot_triangulated.obj")


def run_scene(
    folder: Path,
    scene: int,
    name: str,
    believed: Rig,
    *,
    assets: Path | None,
    true_rig: str | None,
    seed: int,
    precision_pct: float | None = None,
    speed_factor: float = 1000.0,
) -> SceneResult:
    """Scene ``scene``: ``name``'s object with held-out materials (seeded by ``seed`` and ``scene``),
    planned on ``believed``, acquired in the world built as ``true_rig`` (default: as ``believed``) —
    adaptively for ``precision_pct`` when given (``acquire --adaptive --precision``) —, fitted; every fitted
    parameter against its truth. ``folder`` (new) keeps the plan and the session."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng([seed, scene])
    obj = BENCH_OBJECTS[name]
    mesh, spec = bench_mesh(name, assets, folder, seed=seed + scene)
    plan, _ = plan_object(mesh, segment(mesh), believed, PlanSettings(), mesh_spec=spec, plan_folder=folder,
                          up=obj.up, scale=obj.scale)  # fmt: skip
    plan_path = folder / "plan.json"
    write_plan(plan_path, plan)
    plan = read_plan(plan_path)
    ids = [r.id for r in plan.object.regions]
    truth = held_out_materials(len(ids), rng)
    world = replace(sim_scene(plan, plan_path, None), materials=truth)
    true_json = json.dumps({str(i): asdict(m) for i, m in zip(ids, truth, strict=True)})
    atomic_write_text(folder / "truth.json", true_json)
    geometry = world_geometry(believed, true_rig)
    with SimRig(scene=world, speed_factor=speed_factor, seed=seed * 1000 + scene, **geometry) as sim:
        if precision_pct is None:
            acquire_plan(plan_path, believed, folder / "session", links=world_links(sim))
            poses = len(plan.poses)
        else:
            poses = acquire_adaptive(plan_path, believed, folder / "session", links=world_links(sim),
                                     precision_pct=precision_pct).photographed_poses  # fmt: skip
    fitted = fit_into(folder / "session").materials
    return replace(scene_result(scene, name, fitted, dict(zip(ids, truth, strict=True))), poses=poses)


def scene_result(scene: int, name: str, fitted: MaterialsFile, truth: dict[int, Material]) -> SceneResult:
    """Every parameter ``fitted`` states against ``truth`` (region id → its true material)."""
    params: list[ParameterResult] = []
    unmeasured, notes = [], []
    for e in fitted.regions:
        t = truth[e.id]
        measured = [("rd", e.rd, e.rd_se, e.rd_sys or [None] * 3, t.rd)]
        if e.rs is not None and e.rs_se is not None and e.n is not None and e.n_se is not None:
            measured += [("rs", e.rs, e.rs_se, e.rs_sys or [None] * 3, t.rs),
                         ("n", [e.n], [e.n_se], [e.n_sys], [t.n])]  # fmt: skip
        else:
            unmeasured.append(e.id)
            notes.append(f"region {e.id} (n {t.n:.0f}): {e.reason}")
        params += [
            ParameterResult(scene, name, e.id, parameter, c, float(tr), float(g), float(s), y)
            for parameter, got, se, sys, true in measured
            for c, (g, s, y, tr) in enumerate(zip(got, se, sys, true, strict=True))
        ]
    unfitted = sorted(set(truth) - {e.id for e in fitted.regions})
    return SceneResult(scene, name, params, unmeasured, unfitted, notes)


def materials_bench(
    folder: Path,
    believed: Rig,
    *,
    scenes: int,
    objects: tuple[str, ...],
    assets: Path | None,
    true_rig: str | None = None,
    seed: int = 0,
    precision_pct: float | None = None,
    progress: Callable[[str], None] = lambda _: None,
    done: Callable[[SceneResult], None] = lambda _: None,
) -> list[SceneResult]:
    """``scenes`` scenes, the objects taken in turn (each as :func:`run_scene`); ``done`` hears each
    scene's result as it ends."""
    results = []
    for k in range(scenes):
        name = objects[k % len(objects)]
        progress(f"scene {k + 1}/{scenes}: {name}…")
        results.append(run_scene(folder / f"scene-{k:03d}-{name}", k, name, believed, assets=assets,
                                 true_rig=true_rig, seed=seed, precision_pct=precision_pct))  # fmt: skip
        done(results[-1])
    return results


def save_results(path: Path, results: list[SceneResult]) -> None:
    """Every scene's parameters against their truths, as JSON (one row per parameter)."""
    rows = [asdict(x) | {"error_pct": x.error_pct, "z": x.z, "z_combined": x.z_combined}
            for r in results for x in r.parameters]  # fmt: skip
    scenes = [{k: v for k, v in asdict(r).items() if k != "parameters"} for r in results]
    atomic_write_text(path, json.dumps({"scenes": scenes, "parameters": rows}, indent=1) + "\n")


def scene_line(r: SceneResult) -> str:
    """One scene: its worst errors (per cent) and how many parameters lie within 2 σ (statistical, and
    combined with the systematic)."""
    cells = []
    for p in PARAMETERS:
        errs = [abs(x.error_pct) for x in r.parameters if x.parameter == p]
        cells.append(f"{p} {max(errs):5.2f} %" if errs else f"{p}   —   ")
    z = np.array([x.z for x in r.parameters])
    zc = np.array([x.z_combined for x in r.parameters])
    line = f"scene {r.scene:3d} {r.object:7}: worst " + ", ".join(cells)
    if r.poses is not None:
        line += f"; {r.poses} poses"
    line += f"; within 2σ {np.mean(z <= 2):4.0%} of {len(z)} (combined {np.mean(zc <= 2):4.0%})"
    if r.unmeasured:
        line += f"; specular unmeasured: {r.unmeasured}"
    if r.unfitted:
        line += f"; not measured (materials.json not_measured): {r.unfitted}"
    return line


def coverage_lines(results: list[SceneResult]) -> list[str]:
    """The table per parameter: count, worst and median error (%), signed median (a bias shows there),
    fraction within 1 σ and 2 σ, median |error|/σ (the statistical σ), and within 1 and 2 combined σ
    (with the systematic)."""
    rows = [x for r in results for x in r.parameters]
    lines = [
        f"{len(results)} scenes, {len(rows)} parameters; targets: within 1σ ≈ 68 %, within 2σ ≥ 90 %",
        "param  count  worst %  median |%|  median %  within 1σ  within 2σ  median |z|  "
        "combined: within 1σ  within 2σ",
    ]
    for p in PARAMETERS:
        sel = [x for x in rows if x.parameter == p]
        if not sel:
            continue
        err = np.array([x.error_pct for x in sel])
        z = np.array([x.z for x in sel])
        zc = np.array([x.z_combined for x in sel])
        lines.append(
            f"{p:5}  {len(sel):5d}  {np.abs(err).max():7.2f}  {np.median(np.abs(err)):10.2f}  "
            f"{np.median(err):+8.2f}  {np.mean(z <= 1):9.0%}  {np.mean(z <= 2):9.0%}  {np.median(z):10.2f}  "
            f"{np.mean(zc <= 1):19.0%}  {np.mean(zc <= 2):9.0%}"
        )
    unmeasured = sum(len(r.unmeasured) for r in results)
    unfitted = sum(len(r.unfitted) for r in results)
    lines.append(f"regions with Rd only: {unmeasured}; regions not measured at all: {unfitted}")
    return lines
