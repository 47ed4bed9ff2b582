"""``hlr-lab campaign``: run a night of jobs from a campaign file, and say how it goes."""

from __future__ import annotations

import time
from pathlib import Path

import click
from rich.markup import escape

from hlr_lab.campaign.runner import (
    CalibrateJob,
    campaign_status,
    load_campaign,
    raise_if_unfinished,
    run_campaign,
)
from hlr_lab.cli.common import FILE
from hlr_lab.cli.console import console
from hlr_lab.display.campaign import campaign_table, step_line


@click.group()
def campaign() -> None:
    """Unattended campaigns: a night of jobs (acquire, calibrate) run one after another."""


@campaign.command("run")
@click.argument("campaign_file", type=FILE)
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
    from worlds.plan_world import job_links  # a simulated job's world: CLI only (the composition root)

    c = load_campaign(campaign_file)
    started = time.monotonic()
    with console.status("starting the campaign…") as status:
        results = run_campaign(
            c,
            links_for=job_links,
            calibrate=_calibrate,
            notify=notify,
            progress=lambda step: status.update(escape(step_line(step))),
        )
    console.print(campaign_table(c.file.campaign.name, results))
    console.print(f"{time.monotonic() - started:.0f} s; index: {escape(str(c.folder / 'index.html'))}")
    raise_if_unfinished(results)  # a night with a failed job says so in its exit status


@campaign.command("status")
@click.argument("campaign_file", type=FILE)
def status(campaign_file: Path) -> None:
    """Where the campaign of CAMPAIGN_FILE is: each job's state, the running job's pose, frames and
    retries, the rig time left. Reads the journals only: safe while the campaign runs.

    \b
    Example:
      hlr-lab campaign status night.toml
    """
    for line in campaign_status(load_campaign(campaign_file)):
        console.print(escape(line), soft_wrap=True)


def _calibrate(job: CalibrateJob) -> None:
    """A calibrate job as ``hlr-lab calibrate PROCEDURE`` runs it (photographs beside the output)."""
    from calibration.procedures import calibrate_job
    from hlr_lab.cli.calibrate_cmd import show, targets_for

    calibrate_job(job, targets_for(job.sim, job.true_rig, job.speed_factor), done=show)
