"""``hlr-lab campaign``: run a night of jobs from a campaign file, and say how it goes."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from hlr_lab.campaign.runner import (
    AcquireJob,
    CalibrateJob,
    CampaignStep,
    campaign_status,
    load_campaign,
    run_campaign,
)
from hlr_lab.cli.console import console
from hlr_lab.errors import HlrLabError
from hlr_lab.instrument.devices import Links


@click.group()
def campaign() -> None:
    """Unattended campaigns: a night of jobs (acquire, calibrate) run one after another."""


@campaign.command("run")
@click.argument("campaign_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--notify",
    "notify",
    metavar="CMD",
    help="A shell command run with a JSON summary on its stdin after every job and at the end or stop "
    "(e.g. a mail or chat command); at most 30 s, and a failing one does not stop the night.",
)
def run(campaign_file: Path, notify: str | None) -> None:
    """Run every job of CAMPAIGN_FILE in order: acquire jobs are run (resumable as acquire is), fitted and
    reported; calibrate jobs write their calibrated rig file. Before anything moves, the whole night's
    frames are checked against the free disk space. A job stopped by a device fault is run once more (a
    new connection; the session resumes), then skipped, and the night goes on — unless the rig could not
    be confirmed safe or an axis moved by itself: then everything stops. NAME-campaign/ beside the file
    gets campaign.jsonl and index.html (every job's report and materials). Format: docs/campaigns.md.

    \b
    Examples:
      hlr-lab campaign run night.toml
      hlr-lab campaign run night.toml --notify 'mail -s "hlr-lab" lab@example.org'
      hlr-lab campaign status night.toml        # from another terminal, while it runs
    """
    c = load_campaign(campaign_file)
    started = time.monotonic()
    with console.status("starting the campaign…") as status:

        def show(step: CampaignStep) -> None:
            status.update(
                escape(
                    f"job {step.index + 1}/{step.total} {step.job}: {step.what} — about "
                    f"{step.eta_s / 60:.0f} min of rig time left"
                )
            )

        results = run_campaign(c, links_for=_links, calibrate=_calibrate, notify=notify, progress=show)
    t = Table(title=f"campaign {escape(c.file.campaign.name)}", title_justify="left")
    for column in ("job", "status", "attempts", "detail"):
        t.add_column(column)
    for r in results:
        t.add_row(escape(r.name), r.status, str(r.attempts), escape(r.detail))
    console.print(t)
    console.print(f"{time.monotonic() - started:.0f} s; index: {escape(str(c.folder / 'index.html'))}")
    unfinished = [r for r in results if r.status != "done"]
    if unfinished:  # a night with a failed job says so in its exit status
        names = ", ".join(f"{r.name} ({r.status})" for r in unfinished)
        raise HlrLabError(
            f"{len(unfinished)} of {len(results)} jobs did not complete: {names}; see the table above"
        )


@campaign.command("status")
@click.argument("campaign_file", type=click.Path(dir_okay=False, path_type=Path))
def status(campaign_file: Path) -> None:
    """Where the campaign of CAMPAIGN_FILE is: each job's state, the running job's pose, frames and
    retries, the rig time left. Reads the journals only: safe while the campaign runs.

    \b
    Example:
      hlr-lab campaign status night.toml
    """
    for line in campaign_status(load_campaign(campaign_file)):
        console.print(escape(line), soft_wrap=True)


def _links(job: AcquireJob, stack: contextlib.ExitStack) -> Links:
    """The rig file's links, or a simulated world for the job (kept open for its attempts)."""
    if not job.sim:
        return Links()
    from hlr_lab.campaign.runner import job_rig
    from hlr_lab.formats.plan import read_plan
    from worlds.plan_world import sim_links

    return sim_links(
        stack, job_rig(job), read_plan(job.plan), job.plan, job.scene, job.true_rig, job.speed_factor
    )


def _calibrate(job: CalibrateJob) -> None:
    """A calibrate job as ``hlr-lab calibrate PROCEDURE`` runs it (photographs beside the output)."""
    from calibration.procedures import Settings, calibrate_all, run_procedure
    from hlr_lab.cli.calibrate_cmd import show, targets_for
    from hlr_lab.cli.common import believed_rig

    rig = believed_rig(job.rig, job.sim, job.true_rig)
    folder = job.output.parent / "calibration" / f"{time.strftime('%Y-%m-%d-%H%M%S')}-{job.name}"
    targets = targets_for(job.sim, job.true_rig, job.speed_factor)
    settings = Settings(warm_up_min=job.warm_up_min, warm_up_within=job.warm_up_within)
    if job.procedure == "all":
        calibrate_all(rig, folder, job.output, targets, settings, done=show)
    else:
        show(run_procedure(job.procedure, rig, folder, job.output, targets, settings))
