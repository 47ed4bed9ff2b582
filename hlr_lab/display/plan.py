"""A plan's coverage (expected samples per region and light) and its summary lines, as ``plan`` and
``demo`` show them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.table import Table

from hlr_lab.display.regions import swatch
from hlr_lab.object.segment import Segmentation
from hlr_lab.planning.planner import PlanResult

MAX_POSE_COLUMNS = 10  # later lights are summed in one "…" column, so that the table fits a terminal


def coverage_table(result: PlanResult, seg: Segmentation) -> Table:
    """One row per region: its colour, the highlight samples each light gives it (in the plan's count
    unit), their total, the diffuse-only samples of all the lights, and whether it is satisfied (if not,
    why)."""
    s = result.settings
    t = Table(
        title=f"coverage ({s.count}; M = {s.min_samples:g} highlight, {s.min_diffuse:g} diffuse-only samples)",
        title_justify="left",
    )
    t.add_column("region", justify="right")
    t.add_column("colour (sRGB)")
    shown = result.lights[:MAX_POSE_COLUMNS]
    for i, light in enumerate(shown):
        t.add_column(f"p{i:03d}\n{light.turntable_deg:g}°", justify="right")
    if len(result.lights) > len(shown):
        t.add_column("…", justify="right")
    t.add_column("total", justify="right")
    t.add_column("diffuse", justify="right")
    t.add_column("satisfied")
    for r in seg.regions:
        cells = [f"{light.expected[r.id]:.0f}" if light.expected[r.id] > 0 else "·" for light in shown]
        if len(result.lights) > len(shown):
            cells.append(f"{sum(light.expected[r.id] for light in result.lights[len(shown) :]):.0f}")
        ok = bool(result.satisfied[r.id])
        mark = "[green]yes[/]" if ok else f"[red]no[/]: {result.uncovered.get(r.id, '')}"
        diffuse = f"{result.diffuse[r.id]:.0f}"
        t.add_row(str(r.id), swatch(r.colour), *cells, f"{result.coverage[r.id]:.0f}", diffuse, mark)
    return t


def optimum_line(result: PlanResult) -> str:
    """ "N lights; lower bound B (LP); optimum proven / not proven within the budget"."""
    o = result.optimum
    proof = "optimum proven" if o.proven else f"optimum not proven within the budget ({o.status})"
    highlights = sum(light.purpose == "highlights" for light in result.lights)
    line = f"{highlights} lights; lower bound {o.lower_bound} (LP {o.lp_value:.2f}); {proof}"
    added = len(result.lights) - highlights
    return line + (f"; +{added} for diffuse-only samples" if added else "")


def plan_summary(result: PlanResult, output: Path) -> list[str]:
    """The lines (rich markup) under the coverage table: lights and views, the sphere, what an analysis
    plan means, the other criterion's count, the regions left short, where the plan went."""
    by = result.lights_by_criterion
    crit = result.settings.criterion
    views = sorted({light.turntable_deg for light in result.lights})
    lines = [
        f"{len(result.lights)} lights over {len(views)} turntable view(s) {', '.join(f'{v:g}°' for v in views)}; "
        f"sphere {result.sphere.radius:.3f} m ({result.sphere.source}); "
        f"{result.reachable:,} of {result.candidates:,} candidate positions reachable"
    ]
    if result.sphere.source == "scale":
        lines.append(
            f"[yellow]an analysis plan[/]: its lights are on a {result.sphere.radius:.3f} m sphere about the object "
            f"(--sphere-scale), not on the gantry's {result.sphere.gantry.arm_radius:.3f} m arm, so acquire "
            "refuses it; plan without --sphere-scale to measure on the rig"
        )
    if result.proxy is not None:
        p = result.proxy
        lines.append(
            f"planned on a ray proxy of the mesh: {len(p.mesh.vertices):,} of its {p.source_vertices:,} vertices, "
            f"clustered in {p.cell_m * 1e3:.2f} mm cells (about a pixel; docs/planning.md)"
        )
    lines.append(optimum_line(result))
    greedy = ", ".join(f"{k} {n}" for k, n in by.items())
    lines.append(f"chosen by: {result.optimum.chosen_by} (the greedy alone: {greedy}; {crit} requested)")
    n_bad = int(np.sum(~result.satisfied))
    if n_bad:
        lines.append(
            f"[yellow]{n_bad} region(s) cannot get their {result.settings.min_samples:g} samples; "
            "see 'uncovered' in the plan[/]"
        )
    lines.append(f"wrote {output}")
    return lines
