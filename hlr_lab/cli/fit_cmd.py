"""``hlr-lab fit``: a session → materials.json (per-region Rd, Rs, n with standard errors) and diagnostics."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import click
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn
from rich.table import Table

from hlr_lab.cli.console import console
from hlr_lab.fitting import DEFAULT_ESTIMATOR, ESTIMATORS, EstimatorName
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.pipeline import fit_into
from hlr_lab.reflectance.session_fit import DIAGNOSTICS, MATERIALS, FitStep


def _theta_c(value: str) -> float | Literal["auto"]:
    if value == "auto":
        return value
    try:
        degrees = float(value)
    except ValueError:
        raise click.BadParameter("a number of degrees or 'auto'") from None
    if not 0 < degrees < 90:
        raise click.BadParameter("θc lies between 0 and 90 degrees")
    return degrees


@click.command("fit")
@click.argument("session", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--theta-c",
    "theta_c",
    default="auto",
    show_default=True,
    callback=lambda _c, _p, v: _theta_c(v),
    help="Highlight cone half-angle θc in degrees, or 'auto' (chosen per region from the data).",
)
@click.option(
    "--method",
    type=click.Choice(list(ESTIMATORS)),
    default=DEFAULT_ESTIMATOR,
    show_default=True,
    help="The estimator: " + "; ".join(f"{k}: {e.summary}" for k, e in ESTIMATORS.items()) + ".",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    help="materials.json to write (default: SESSION/materials.json); diagnostics go beside it.",
)
@click.option(
    "--allow-incomplete",
    is_flag=True,
    help="Fit although planned frames are missing (a stopped run, damaged journal lines); materials.json "
    "records what was missing.",
)
@click.option(
    "--no-lamp-correction",
    is_flag=True,
    help="Ignore the lamp's output the run measured (acquire --lamp-every): every pose under the rig "
    "file's power, to see what the correction is worth.",
)
def fit(
    session: Path,
    theta_c,
    method: EstimatorName,
    output: Path | None,
    allow_incomplete: bool,
    no_lamp_correction,
) -> None:
    """Fit per-region Phong materials (Rd, Rs, n, each with its standard error) to a session's frames.

    Each pose's bracket is merged into linear radiance (no clipped or noise-dominated value used, dark
    frames subtracted), every pixel gets its geometry from the calibrated camera, the measured turntable
    angle and the measured lamp position, and lit, visible, non-grazing pixels away from silhouettes and
    region borders are pooled per region over all poses. A region without enough highlight pixels gets
    its diffuse colour and "specular": "unmeasured" with the reason.

    Every frame is checked against its journal line (checksums, what its sidecar says); a damaged
    journal line or a frame that does not check out is named and left out, and a session that lacks
    planned frames is refused unless --allow-incomplete. When the run watched its lamp (acquire
    --lamp-every), each pose's light is the rig file's power times the output measured at its time.

    \b
    Examples:
      hlr-lab fit plan-session
      hlr-lab fit sessions/bunny-1 --theta-c 10 --method paper -o bunny-materials.json
      hlr-lab fit sessions/stopped-run --allow-incomplete
    """
    output = output or session / MATERIALS
    columns = (
        TextColumn("{task.fields[stage]:8}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.description}"),
    )
    with Progress(*columns, console=console, transient=True) as bar:
        tasks: dict[str, TaskID] = {}

        def show(step: FitStep) -> None:
            if step.stage not in tasks:
                tasks[step.stage] = bar.add_task("", total=step.total, stage=step.stage)
            for stage, task in tasks.items():  # an earlier stage is complete once a later one starts
                if stage != step.stage:
                    bar.update(task, completed=bar.tasks[task].total)
            bar.update(tasks[step.stage], completed=step.index, description=escape(step.label))

        result = fit_into(session, output, theta_c_deg=theta_c, method=method, allow_incomplete=allow_incomplete,
                          correct_lamp=not no_lamp_correction, progress=show, on_gaps=_say_gaps)  # fmt: skip
    console.print(materials_table(result.materials))
    for d in result.diagnostics["regions"]:
        if "note" in d:
            console.print(f"[yellow]region {d['id']}: {escape(d['note'])}[/] (no entry written)")
    console.print(f"wrote {escape(str(output))} and {escape(str(output.with_name(DIAGNOSTICS)))}")


def _say_gaps(notes: list[str], missing: int) -> None:
    for note in notes:
        console.print(f"[yellow]not used:[/] {escape(note)}", soft_wrap=True)
    if missing:
        console.print(
            f"[yellow]incomplete:[/] {missing} planned frame(s) missing; fitting what is there (recorded in "
            "materials.json)",
            soft_wrap=True,
        )


def materials_table(materials: MaterialsFile) -> Table:
    t = Table(title="fitted materials (± standard error)", title_justify="left")
    for column in ("region", "Rd (linear RGB)", "Rs", "n", "θc", "pixels diffuse / highlight"):
        t.add_column(column, justify="right")
    for e in materials.regions:
        rd = " ".join(f"{v:.4f}±{s:.4f}" for v, s in zip(e.rd, e.rd_se, strict=True))
        if e.specular == "measured":
            assert e.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.n is not None
            rs = " ".join(f"{v:.4f}" for v in e.rs)
            n = f"{e.n:.1f}±{e.n_se:.1f}"
        else:
            rs, n = "unmeasured", escape(e.reason or "")
        t.add_row(str(e.id), rd, rs, n, f"{e.theta_c_deg:.1f}°", f"{e.pixels.diffuse} / {e.pixels.highlight}")
    return t
