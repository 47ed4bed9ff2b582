"""``hlr-lab report``: the fitted session as one self-contained HTML page."""

from __future__ import annotations

from pathlib import Path

import click
from rich.markup import escape

from hlr_lab.cli.common import FILE, FOLDER
from hlr_lab.cli.console import console
from hlr_lab.pipeline import report_into


@click.command("report")
@click.argument("session", type=FOLDER)
@click.option("-o", "--output", type=FILE, help="HTML file to write (default: SESSION/report.html).")
def report(session: Path, output: Path | None) -> None:
    """Write an HTML report of a fitted session: materials ± standard errors, the β–Is curves with the
    fitted lobes, each pose's photograph beside the fitted materials rendered back (with an error map and
    PSNR), the plan and the run summary. Images are embedded: the file opens offline, alone.

    \b
    Examples:
      hlr-lab fit plan-session && hlr-lab report plan-session
      hlr-lab report sessions/bunny-1 -o bunny-report.html
    """
    with console.status("building the report…") as status:
        output, figures, size = report_into(
            session, output, progress=lambda what: status.update(escape(what))
        )
    for pose, psnr in figures.psnr_db.items():
        console.print(f"{escape(pose)}: captured vs fitted materials rendered back, PSNR {psnr:.1f} dB")
    console.print(f"wrote {escape(str(output))} ({size / 1e6:.1f} MB)")
