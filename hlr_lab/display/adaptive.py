"""What an adaptive run measured and decided: each region's θc against the plan's, and the poses it took."""

from __future__ import annotations

from rich.markup import escape
from rich.table import Table

from hlr_lab.adaptive.run import AdaptiveOutcome
from hlr_lab.adaptive.theta_c import plan_cones


def cones_table(outcome: AdaptiveOutcome, prior_deg: dict[int, float]) -> Table:
    """One row per region: the plan's θc (``prior_deg``: region id → degrees), the θc measured on the
    photographs the last re-plan was made from (the pilot's for the first), the θc that re-plan counted the
    region's samples in, the n fitted, and where the measured θc came from (why, when not measured or held)."""
    r = outcome.replanned.round
    t = Table(
        title="θc measured on the pilot" if r == 1 else f"θc measured (re-plan {r})", title_justify="left"
    )
    for column in ("region", "planned θc", "measured θc", "re-planned with", "n fitted"):
        t.add_column(column, justify="right")
    t.add_column("from")
    used = plan_cones(outcome.replanned.plan)
    for c in outcome.replanned.cones:
        why = c.source if c.reason is None else f"{c.source}: {c.reason}"
        n = "—" if c.n is None else f"{c.n:.1f}"
        t.add_row(str(c.region), f"{prior_deg.get(c.region, float('nan')):.1f}°", f"{c.theta_c_deg:.1f}°",
                  f"{used.get(c.region, float('nan')):.1f}°", n, escape(why))  # fmt: skip
    return t


def adaptive_lines(outcome: AdaptiveOutcome) -> list[str]:
    """The poses the run took against the plan's, and the regions the re-plan leaves short."""
    r, rounds = outcome.replanned, outcome.added_per_round
    added = outcome.photographed_poses - len(outcome.pilot)
    made = f"the plan as made: {outcome.planned_poses}"
    by = f"{added} the re-plan added ({made})"
    if len(rounds) > 1:
        by = f"{added} added by {len(rounds)} re-plans ({' + '.join(map(str, rounds))}; {made})"
    lines = [f"photographed {outcome.photographed_poses} poses: the pilot's {len(outcome.pilot)} and {by}"]
    if r.plan_as_made is not None:
        lines.append(f"the re-plan is the plan as made: {escape(r.plan_as_made)}")
    lines += [f"[yellow]region {k}: {escape(why)}[/]" for k, why in sorted(r.short.items())]
    return lines


def needs_table(outcome: AdaptiveOutcome) -> Table | None:
    """With a precision asked: one row per region, the largest relative standard errors of Rs/n and of Rd
    that the last re-plan was made from, and the highlight and diffuse-only samples it asked for them (None
    without one)."""
    needs, precision = outcome.replanned.needs, outcome.precision_pct
    if needs is None or precision is None:
        return None
    r = outcome.replanned.round
    before = (
        "the pilot's" if r == 1 else f"all {outcome.photographed_poses - len(outcome.replanned.added)} poses'"
    )
    title = f"samples for ±{precision:g} % (re-plan {r}, from {before} standard errors)"
    t = Table(title=title, title_justify="left")
    for column in (
        "region",
        "Rs, n SE",
        "highlight samples",
        "Rd SE",
        "diffuse-only samples",
    ):
        t.add_column(column, justify="right")
    t.add_column("note")

    def pct(x: float | None) -> str:
        return "—" if x is None else f"{x:.2f} %"

    coverage = outcome.replanned.plan.coverage
    for n in needs:
        c = coverage.get(str(n.region))
        highlight = "—" if c is None or c.needed is None else f"{c.needed:.0f}"
        diffuse = "—" if c is None or c.diffuse_needed is None else f"{c.diffuse_needed:.0f}"
        t.add_row(str(n.region), pct(n.highlight_se_pct), highlight, pct(n.diffuse_se_pct), diffuse,
                  escape(n.reason or ""))  # fmt: skip
    return t
