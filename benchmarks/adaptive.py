"""``hlr-lab bench adaptive``: does measuring θc on a pilot (``acquire --adaptive``) photograph less, or
better, than the plan made for the default θc?

Each case is an object whose regions take the case's lobes in turn (n and a grey Rs; seeded Rd), planned
once with the default θc; then photographed twice in the same simulated world (same noise seed): the plan
as made (``acquire``), and adaptively (``acquire --adaptive``). Both sessions are fitted; every parameter
is compared with the truth (:func:`benchmarks.materials.scene_result`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from benchmarks.materials import (
    BENCH_OBJECTS,
    PARAMETERS,
    ParameterResult,
    SceneResult,
    bench_mesh,
    scene_result,
)
from hlr_lab.adaptive.run import acquire_adaptive
from hlr_lab.files import as_triple, atomic_write_text
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, fit_into, plan_object
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.file import Rig
from sim.render.scene import Material
from sim.rig import SimRig
from worlds.plan_world import sim_scene, world_geometry, world_links

# (n, Rs) per case, given to the regions in turn: the three lobes alone and together, and a lobe
# narrower than the default 5° cone (dim and sharp: its θc comes out under 5°)
CASES: dict[str, tuple[tuple[float, float], ...]] = {
    "n 8": ((8.0, 0.25),),
    "n 40": ((40.0, 0.25),),
    "n 400": ((400.0, 0.25),),
    "n 8/40/400": ((8.0, 0.25), (40.0, 0.25), (400.0, 0.25)),
    "narrow": ((1500.0, 0.05),),
}


@dataclass(frozen=True)
class RunFigures:
    """One way of photographing a case: the poses photographed, the worst |error| per parameter (%,
    over every region and channel), the regions without a measured specular, its θc per region, the
    worst |error| in stated standard errors (over every parameter: whether the errors are the noise), and
    the largest stated standard error per parameter (%): the accuracy the photographs give, which one
    draw's errors only sample (the same poses photographed in another order, with other noise, gave the
    n 400 case Rs errors of 0.22 and 0.38 %)."""

    poses: int
    worst_pct: dict[str, float]
    unmeasured: list[int]
    theta_c_deg: dict[int, float]
    worst_z: float
    worst_se_pct: dict[str, float]


@dataclass(frozen=True)
class CaseFigures:
    """A case: the plan as made, and adaptively (its pilot's poses and those the re-plans added)."""

    case: str
    object: str
    planned: RunFigures
    adaptive: RunFigures
    pilot: int
    added: int
    short: dict[int, str]


def case_lobes(case: str, regions: int, rng: np.random.Generator) -> list[Material]:
    """The case's lobes given to ``regions`` regions in turn, each with a seeded Rd (0.05–0.6 per
    channel) that leaves room for its Rs."""
    lobes = CASES[case]
    rd = rng.uniform(0.05, 0.6, (regions, 3)).round(4)
    return [
        Material(as_triple([float(x) for x in d]), (rs, rs, rs), n)
        for d, (n, rs) in zip(rd, (lobes[k % len(lobes)] for k in range(regions)), strict=True)
    ]


def run_case(folder: Path, case: str, name: str, rig: Rig, *, assets: Path | None, settings: PlanSettings,
             seed: int, precision_pct: float | None = None, speed_factor: float = 1000.0) -> CaseFigures:  # fmt: skip
    """``case`` on the object ``name`` (:data:`benchmarks.materials.BENCH_OBJECTS`), in ``folder`` (new):
    the plan, its truth, and the two sessions (``planned``, ``adaptive``: for ``precision_pct`` if given)."""
    folder.mkdir(parents=True)
    obj = BENCH_OBJECTS[name]
    mesh, spec = bench_mesh(name, assets, folder, seed=seed)
    plan, _ = plan_object(mesh, segment(mesh), rig, settings, mesh_spec=spec, plan_folder=folder, up=obj.up,
                          scale=obj.scale)  # fmt: skip
    plan_path = folder / "plan.json"
    write_plan(plan_path, plan)
    plan = read_plan(plan_path)
    ids = [r.id for r in plan.object.regions]
    truth = case_lobes(case, len(ids), np.random.default_rng(seed))
    atomic_write_text(
        folder / "truth.json", json.dumps({str(i): asdict(m) for i, m in zip(ids, truth, strict=True)})
    )
    world = replace(sim_scene(plan, plan_path, None), materials=truth)
    by_id = dict(zip(ids, truth, strict=True))
    runs: dict[str, RunFigures] = {}
    adaptive = None
    for how in ("planned", "adaptive"):
        session = folder / how
        with SimRig(scene=world, speed_factor=speed_factor, seed=seed, **world_geometry(rig, None)) as sim:
            if how == "planned":
                acquire_plan(plan_path, rig, session, links=world_links(sim))
                poses = len(plan.poses)
            else:
                adaptive = acquire_adaptive(plan_path, rig, session, links=world_links(sim),
                                            precision_pct=precision_pct)  # fmt: skip
                poses = adaptive.photographed_poses
        fitted = fit_into(session).materials
        result = scene_result(0, name, fitted, by_id)
        runs[how] = RunFigures(poses, _worst(result), result.unmeasured,
                               {e.id: round(e.theta_c_deg, 2) for e in fitted.regions},
                               max((x.z for x in result.parameters), default=float("nan")),
                               _worst(result, lambda x: 100.0 * x.se / abs(x.true)))  # fmt: skip
    assert adaptive is not None
    return CaseFigures(case, name, runs["planned"], runs["adaptive"], len(adaptive.pilot),
                       adaptive.photographed_poses - len(adaptive.pilot), adaptive.replanned.short)  # fmt: skip


def _worst(
    result: SceneResult, of: Callable[[ParameterResult], float] = lambda x: abs(x.error_pct)
) -> dict[str, float]:
    """The largest of ``of`` (|error| % by default) per parameter, over every region and channel."""
    return {
        p: max((of(x) for x in result.parameters if x.parameter == p), default=float("nan"))
        for p in PARAMETERS
    }


def adaptive_bench(folder: Path, rig: Rig, *, cases: tuple[str, ...], objects: tuple[str, ...],
                   assets: Path | None, settings: PlanSettings, seed: int = 0, precision_pct: float | None = None,
                   progress: Callable[[str], None] = lambda _: None,
                   done: Callable[[CaseFigures], None] = lambda _: None) -> list[CaseFigures]:  # fmt: skip
    """Every case on every object; ``done`` hears each as it ends."""
    results = []
    for name in objects:
        for k, case in enumerate(cases):
            progress(f"{name}, {case}: the plan as made, then adaptively…")
            slug = case.replace(" ", "").replace("/", "-")
            results.append(run_case(folder / f"{name}-{slug}", case, name, rig, assets=assets, settings=settings,
                                    seed=seed + k, precision_pct=precision_pct))  # fmt: skip
            done(results[-1])
    return results


def header() -> list[str]:
    """The table's head: what each column is."""
    return [
        "worst |error| % over the regions (Rd, Rs per channel); poses photographed; adaptive: pilot + added",
        f"{'case':12} {'object':7} {'planned: poses   Rd    Rs     n':34} {'adaptive: poses      Rd    Rs     n':38}",
    ]


def case_line(f: CaseFigures) -> str:
    """One case: the plan as made beside the adaptive run, and what the adaptive run measured or left."""

    def cells(r: RunFigures) -> str:
        return "  ".join(f"{r.worst_pct[p]:5.2f}" for p in PARAMETERS)

    line = (f"{f.case:12} {f.object:7} {f.planned.poses:14d}  {cells(f.planned)}   "
            f"{f.adaptive.poses:6d} ({f.pilot}+{f.added})  {cells(f.adaptive)}")  # fmt: skip
    theta = sorted(set(f.adaptive.theta_c_deg.values()))
    line += f"; fitted θc {theta[0]:.1f}–{theta[-1]:.1f}°" if theta else ""
    line += f"; worst |error|/σ {f.planned.worst_z:.1f} and {f.adaptive.worst_z:.1f}"
    line += "; largest stated σ Rd/Rs/n % " + " and ".join(
        "/".join(f"{r.worst_se_pct[p]:.2f}" for p in PARAMETERS) for r in (f.planned, f.adaptive)
    )
    for how, r in (("planned", f.planned), ("adaptive", f.adaptive)):
        if r.unmeasured:
            line += f"; {how}: specular unmeasured in {r.unmeasured}"
    if f.short:
        line += f"; re-plan short: {f.short}"
    return line
