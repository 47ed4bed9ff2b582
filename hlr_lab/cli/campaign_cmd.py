"""``hlr-lab campaign``: run a night of jobs from a campaign file, and say how it goes."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from hlr_lab.campaign import (
    AcquireJob,
    CalibrateJob,
    CampaignStep,
    campaign_status,
    load_campaign,
    run_campaign,
)
from hlr_lab.cli.console import console
from hlr_lab.devices import Links


@click.group()
def campaign() -> None:
    """Unattended campaigns: a night of jobs (acquire, calibrate) run one after another."""


@campaign.command("run")
@click.argument("campaign_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--notify", "notify", metavar="CMD",
              help="A shell command run with a JSON summary on its stdin after every job and at the end or stop "
              "(e.g. a mail or chat command); at most 30 s, and a failing one does not stop the night.")  # fmt: skip
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
            status.update(escape(f"job {step.index + 1}/{step.total} {step.job}: {step.what} — about "
                                 f"{step.eta_s / 60:.0f} min of rig time left"))  # fmt: skip

        results = run_campaign(c, links_for=_links, calibrate=_calibrate, notify=notify, progress=show)
    t = Table(title=f"campaign {escape(c.file.campaign.name)}", title_justify="left")
    for column in ("job", "status", "attempts", "detail"):
        t.add_column(column)
    for r in results:
        t.add_row(escape(r.name), r.status, str(r.attempts), escape(r.detail))
    console.print(t)
    console.print(f"{time.monotonic() - started:.0f} s; index: {escape(str(c.folder / 'index.html'))}")


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
    from hlr_lab.campaign import job_rig
    from hlr_lab.cli.acquire_cmd import sim_links
    from hlr_lab.formats.plan import read_plan

    return sim_links(
        stack, job_rig(job), read_plan(job.plan), job.plan, job.scene, job.true_rig, job.speed_factor
    )


def _calibrate(job: CalibrateJob) -> None:
    """A calibrate job as ``hlr-lab calibrate PROCEDURE`` runs it (photographs beside the output)."""
    from hlr_lab.cli import calibrate_cmd as c
    from hlr_lab.cli.common import believed_rig

    rig = believed_rig(job.rig, job.sim, job.true_rig)
    folder = c._new_folder(
        job.output.parent / "calibration" / f"{time.strftime('%Y-%m-%d-%H%M%S')}-{job.name}"
    )
    args = (job.sim, job.true_rig)
    if job.procedure == "camera":
        c._run_camera(rig, *args, 24, folder, False, False, job.output, job.speed_factor)
    elif job.procedure == "gantry":
        c._run_gantry(rig, *args, 30, folder, False, job.output, job.speed_factor)
    elif job.procedure == "radiometric":
        c._run_radiometric(rig, *args, 6, 8, folder, False, job.output, job.speed_factor, job.warm_up_min,
                           job.warm_up_within)  # fmt: skip
    else:
        c.run_all(
            rig,
            *args,
            folder,
            job.output,
            job.speed_factor,
            warm_up_min=job.warm_up_min,
            warm_up_within=job.warm_up_within,
        )
