"""``hlr-lab fit``: a session → materials.json (per-region Rd, Rs, n with standard errors) and diagnostics."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import click
from rich.markup import escape

from hlr_lab.cli.common import FILE, FOLDER
from hlr_lab.cli.console import console
from hlr_lab.display.materials import fit_notes, materials_table, stage_progress
from hlr_lab.fitting import DEFAULT_ESTIMATOR, ESTIMATORS, EstimatorName
from hlr_lab.pipeline import fit_into
from hlr_lab.reflectance.session_fit import DIAGNOSTICS, MATERIALS, RADIANCE


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
@click.argument("session", type=FOLDER)
@click.option(
    "--theta-c",
    "theta_c",
    default="auto",
    callback=lambda _c, _p, v: _theta_c(v),
    help="Highlight cone half-angle θc in degrees, or 'auto' (chosen per region from the data).",
)
@click.option(
    "--method",
    type=click.Choice(list(ESTIMATORS)),
    default=DEFAULT_ESTIMATOR,
    help="The estimator: " + "; ".join(f"{k}: {e.summary}" for k, e in ESTIMATORS.items()) + ".",
)
@click.option(
    "-o",
    "--output",
    type=FILE,
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
@click.option(
    "--no-systematic",
    is_flag=True,
    help="Leave out the systematic uncertainties (rd_sys, rs_sys, n_sys: what the rig file's calibration "
    "leaves uncertain, propagated to first order); saves their time (docs/fitting.md).",
)
@click.option(
    "--radiance",
    is_flag=True,
    help="Also write each pose's merged linear radiance as OpenEXR (radiance/POSE.exr beside materials.json: "
    "R, G, B float32, masks of the usable pixels and of those the fit used, the pose's light and camera "
    "in the header; docs/formats.md).",
)
def fit(session: Path, theta_c: float | Literal["auto"], method: EstimatorName, output: Path | None,
        allow_incomplete: bool, no_lamp_correction: bool, no_systematic: bool, radiance: bool) -> None:  # fmt: skip
    """Fit per-region Phong materials (Rd, Rs, n, each with its standard error) to a session's frames.

    Each pose's bracket is merged into linear radiance (no clipped or noise-dominated value used, dark
    frames subtracted), every pixel gets its geometry from the calibrated camera, the measured turntable
    angle and the measured lamp position, and lit, visible, non-grazing pixels away from silhouettes and
    region borders are pooled per region over all poses. A region without enough highlight pixels gets
    its diffuse colour and "specular": "unmeasured" with the reason. Each number gets a statistical
    standard error (the pixels' noise) and a systematic one (the rig file's calibration records, or a
    stated conservative default for a rig never calibrated).

    Every frame is checked against its journal line (checksums, what its sidecar says); a damaged
    journal line or a frame that does not check out is named and left out, and a session that lacks
    planned frames is refused unless --allow-incomplete. When the run watched its lamp (acquire
    --lamp-every), each pose's light is the rig file's power times the output measured at its time.

    \b
    Examples:
      hlr-lab fit plan-session
      hlr-lab fit sessions/bunny-1 --theta-c 10 --method paper -o bunny-materials.json
      hlr-lab fit sessions/stopped-run --allow-incomplete
      hlr-lab fit sessions/quick-look --no-systematic
      hlr-lab fit sessions/bunny-1 --radiance
    """
    output = output or session / MATERIALS
    with stage_progress(console) as show:
        result = fit_into(session, output, theta_c_deg=theta_c, method=method, allow_incomplete=allow_incomplete,
                          correct_lamp=not no_lamp_correction, systematic=not no_systematic, progress=show,
                          on_gaps=_say_gaps, radiance=radiance)  # fmt: skip
    console.print(materials_table(result.materials))
    for line in fit_notes(result):
        console.print(line, soft_wrap=True)
    console.print(f"wrote {escape(str(output))} and {escape(str(output.with_name(DIAGNOSTICS)))}")
    if radiance:
        console.print(f"wrote each pose's radiance as {escape(str(output.with_name(RADIANCE)))}/POSE.exr")


def _say_gaps(notes: list[str], missing: int) -> None:
    for note in notes:
        console.print(f"[yellow]not used:[/] {escape(note)}", soft_wrap=True)
    if missing:
        console.print(
            f"[yellow]incomplete:[/] {missing} planned frame(s) missing; fitting what is there (recorded in "
            "materials.json)",
            soft_wrap=True,
        )
