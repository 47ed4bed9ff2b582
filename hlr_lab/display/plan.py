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
    """One row per region: its colour, the samples each light gives it (in the plan's count unit), the
    total, and whether it is satisfied (if not, why)."""
    unit = result.settings.count
    t = Table(title=f"coverage ({unit}; M = {result.settings.min_samples:g})", title_justify="left")
    t.add_column("region", justify="right")
    t.add_column("colour (sRGB)")
    shown = result.lights[:MAX_POSE_COLUMNS]
    for i, light in enumerate(shown):
        t.add_column(f"p{i:03d}\n{light.turntable_deg:g}°", justify="right")
    if len(result.lights) > len(shown):
        t.add_column("…", justify="right")
    t.add_column("total", justify="right")
    t.add_column("satisfied")
    for r in seg.regions:
        cells = [f"{light.expected[r.id]:.0f}" if light.expected[r.id] > 0 else "·" for light in shown]
        if len(result.lights) > len(shown):
            cells.append(f"{sum(light.expected[r.id] for light in result.lights[len(shown) :]):.0f}")
        ok = bool(result.satisfied[r.id])
        mark = "[green]yes[/]" if ok else f"[red]no[/]: {result.uncovered.get(r.id, '')}"
        t.add_row(str(r.id), swatch(r.colour), *cells, f"{result.coverage[r.id]:.0f}", mark)
    return t


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
    other = [k for k in by if k != crit]
    if other:
        lines.append(f"the {other[0]} count would need {by[other[0]]} lights (this plan: {crit}, {by[crit]})")
    n_bad = int(np.sum(~result.satisfied))
    if n_bad:
        lines.append(
            f"[yellow]{n_bad} region(s) cannot get their {result.settings.min_samples:g} samples; "
            "see 'uncovered' in the plan[/]"
        )
    lines.append(f"wrote {output}")
    return lines
