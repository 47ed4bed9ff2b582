"""A night as it goes (its step) and its outcome (each job's status, attempts and detail)."""

from __future__ import annotations

from rich.markup import escape
from rich.table import Table

from hlr_lab.campaign.runner import CampaignStep, JobResult


def campaign_table(name: str, results: list[JobResult]) -> Table:
    """One row per job of campaign ``name``, in the order they ran."""
    t = Table(title=f"campaign {escape(name)}", title_justify="left")
    for column in ("job", "status", "attempts", "detail"):
        t.add_column(column)
    for r in results:
        t.add_row(escape(r.name), r.status, str(r.attempts), escape(r.detail))
    return t


def step_line(step: CampaignStep) -> str:
    """The status line of a running campaign: the job, what it does, the rig time left."""
    return (
        f"job {step.index + 1}/{step.total} {step.job}: {step.what} — about "
        f"{step.eta_s / 60:.0f} min of rig time left"
    )
