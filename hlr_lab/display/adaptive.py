"""What an adaptive run measured and decided: each region's θc against the plan's, and the poses it took."""

from __future__ import annotations

from rich.markup import escape
from rich.table import Table

from hlr_lab.adaptive.run import AdaptiveOutcome


def cones_table(outcome: AdaptiveOutcome, prior_deg: dict[int, float]) -> Table:
    """One row per region: the plan's θc (``prior_deg``: region id → degrees), the θc the re-plan used,
    the pilot's fitted n, and where the θc came from (why, when not measured or held)."""
    t = Table(title="θc measured on the pilot", title_justify="left")
    for column in ("region", "planned θc", "measured θc", "n (pilot)"):
        t.add_column(column, justify="right")
    t.add_column("from")
    for c in outcome.replanned.cones:
        why = c.source if c.reason is None else f"{c.source}: {c.reason}"
        n = "—" if c.n is None else f"{c.n:.1f}"
        t.add_row(str(c.region), f"{prior_deg.get(c.region, float('nan')):.1f}°", f"{c.theta_c_deg:.1f}°", n,
                  escape(why))  # fmt: skip
    return t


def adaptive_lines(outcome: AdaptiveOutcome) -> list[str]:
    """The poses the run took against the plan's, and the regions the re-plan leaves short."""
    r = outcome.replanned
    lines = [
        f"photographed {outcome.photographed_poses} poses: the pilot's {len(outcome.pilot)} and "
        f"{len(r.added)} the re-plan added (the plan as made: {outcome.planned_poses})"
    ]
    lines += [f"[yellow]region {k}: {escape(why)}[/]" for k, why in sorted(r.short.items())]
    return lines
