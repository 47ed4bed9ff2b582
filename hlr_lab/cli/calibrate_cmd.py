"""``hlr-lab calibrate``: measure the rig, and write a calibrated copy of its rig file. The procedures are
:mod:`calibration.procedures`'; this module parses options, puts the targets in place and prints."""

from __future__ import annotations

import time
from pathlib import Path

import click
from rich.markup import escape

from calibration.operator import OperatorTargets
from calibration.procedures import (
    COUNT_RANGES,
    Calibrated,
    ProcedureName,
    Settings,
    Targets,
    calibrate_all,
    check_targets,
    default_folder,
    run_procedure,
)
from calibration.tables import after_table, before_table, table
from hlr_lab.cli.common import (
    FILE,
    FOLDER,
    believed_rig,
    output_option,
    rig_options,
    speed_factor_option,
    warm_up_options,
)
from hlr_lab.cli.console import console

DEFAULT = Settings()
board_along_zero_option = click.option(
    "--board-along-zero",
    is_flag=True,
    help="The board was mounted along the plate's 0° line: also correct turntable.zero_steps.",
)


def count_option(field: str, help: str):
    """``--FIELD``: how many photographs, poses, positions or exposures a procedure takes (its range in
    :data:`calibration.procedures.COUNT_RANGES`, its default :class:`Settings`')."""
    lo, hi = COUNT_RANGES[field]
    return click.option(f"--{field}", type=click.IntRange(lo, hi), default=getattr(DEFAULT, field), help=help)


def photograph_options(replaced: str):
    """``--out``, ``--from`` and ``-o`` of a procedure whose calibrated file has ``replaced`` replaced."""

    def decorate(f):
        written = f"The calibrated rig file to write (the input's copy, {replaced} replaced)."
        f = click.option("-o", "--output", type=FILE, required=True, help=written)(f)
        f = click.option(
            "--from",
            "from_dir",
            type=click.Path(file_okay=False, exists=True, path_type=Path),
            help="Solve again from the photographs of an earlier run (no rig needed).",
        )(f)
        return click.option(
            "--out",
            "out",
            type=FOLDER,
            help="Folder for the photographs (a new one; default: calibration/DATE-PROCEDURE "
            "in the current folder).",
        )(f)

    return decorate


def targets_for(sim: bool, true_rig: str | None, speed_factor: float) -> Targets:
    """The operator's targets (asked for at the terminal), or with ``sim`` a simulated world's."""
    if not sim:
        return OperatorTargets(lambda question: click.confirm(question, abort=True, err=True))
    from worlds.targets import SimulatedTargets  # the simulator is reached only from the command line

    return SimulatedTargets(true_rig, speed_factor)


def _run(
    procedure: ProcedureName, rig_path, sim, true_rig, out, from_dir, output, speed_factor, **counts
) -> None:
    settings = Settings(**counts)  # the options are named as Settings' fields
    rig = believed_rig(rig_path, sim, true_rig)
    check_targets(rig, (procedure,))  # a rig file without the target is refused before anything moves
    images = from_dir or out or default_folder(procedure, time.strftime("%Y-%m-%d-%H%M%S"))
    with console.status(f"calibrating the {procedure}…") as status:
        outcome = run_procedure(
            procedure,
            rig,
            images,
            output,
            targets_for(sim, true_rig, speed_factor),
            settings,
            solve_only=from_dir is not None,
            progress=lambda what: status.update(escape(what)),
        )
    show(outcome)


def show(c: Calibrated) -> None:
    """Print ``c``'s table, its warnings, and where everything went."""
    console.print(*before_table(c), table(c), *after_table(c), sep="\n")


@click.group()
def calibrate() -> None:
    """Measure the rig (camera, gantry, radiometric, or all) and write a calibrated copy of its rig file."""


@calibrate.command("camera")
@rig_options("Calibrate the simulated rig (a simulated board on a wedge).")
@count_option(
    "views",
    "Photographs: half on each face of the wedge, spread over ±55° of turntable.",
)
@board_along_zero_option
@photograph_options("camera fields")
@speed_factor_option("With --sim: simulated")
def camera(**options) -> None:
    """Calibrate the camera: intrinsics, distortion and its pose against the turntable axis.

    A ChArUco board ([calibration.board] in the rig file) stands on a wedge on the turntable; the
    turntable turns it through --views angles, half on each face of the wedge (you are asked once to turn
    the wedge over), lit by the gantry lamp. Every photograph is kept in --out; the solve (OpenCV's
    calibration, then one least-squares fit of camera pose, board placements and intrinsics) can be run
    again from them with --from. The result is written to -o: a copy of the rig file with the camera's
    matrix, distortion, position_m, look_at_m and roll_deg replaced and a [calibration.camera] record.
    The camera keeps the azimuth about the turntable axis the rig file gives it (no photograph of the
    turntable can tell it from the turntable's zero); with --board-along-zero the board's measured
    azimuth corrects turntable.zero_steps. Details: docs/calibration.md.

    \b
    Examples:
      hlr-lab calibrate camera --rig rig.toml -o rig-calibrated.toml
      hlr-lab calibrate camera --sim --true-rig builtin:bench-offsets -o calibrated.toml
      hlr-lab calibrate camera --rig rig.toml --from calibration/2026-11-30-0930 -o rig-calibrated.toml
    """
    _run("camera", **options)


@calibrate.command("gantry")
@rig_options("Calibrate the simulated rig (a simulated mirror ball).")
@count_option("poses", "Lamp poses, each photographed with the ball at two turntable angles.")
@photograph_options("gantry fields")
@speed_factor_option("With --sim: simulated")
def gantry(**options) -> None:
    """Calibrate the light gantry from a mirror ball: its centre, arm radius, azimuth axis and zero ticks.

    A polished ball ([calibration.mirror_ball] in the rig file: radius, rough place on the plate) is
    photographed at two turntable angles half a turn apart: once with the lamp above the camera's side
    (its outline against the lit plate gives its centre) and once per lamp pose with a short exposure
    (the lamp's reflection gives the direction of the lamp). The gantry's kinematics are fitted to all
    directions at once. Calibrate the camera first: every ray comes from it. Details: docs/calibration.md.

    \b
    Examples:
      hlr-lab calibrate gantry --rig rig-camera.toml -o rig-calibrated.toml
      hlr-lab calibrate gantry --sim --true-rig builtin:bench-offsets -o calibrated.toml
    """
    _run("gantry", **options)


@calibrate.command("radiometric")
@rig_options("Calibrate the simulated rig (a simulated white reference).")
@count_option("positions", "Lamp positions over the white reference.")
@count_option("levels", "Exposures of the photon transfer.")
@warm_up_options("After the dark frames and before the white reference's")
@photograph_options("[sensor] fields")
@speed_factor_option("With --sim: simulated")
def radiometric(**options) -> None:
    """Calibrate the radiometry: black level, read noise, conversion gain and sensitivity × lamp power.

    Dark frames (the lamp off) at every exposure of the bracket; a white reference of known reflectance
    ([calibration.white_reference]: reflectance per channel, side, place on the plate) photographed in
    pairs at several exposures (photon transfer: conversion gain, and the response checked linear), then
    lit from --positions lamp positions (sensitivity × power, which makes fitted reflectances absolute,
    and a check that the lamp follows 1/d²). Writes [sensor] sensitivity, black_level_dn, read_noise_dn
    and conversion_gain_dn_per_e. Calibrate the camera and the gantry first: every pixel's distance to
    the lamp comes from them. Details: docs/calibration.md.

    \b
    Examples:
      hlr-lab calibrate radiometric --rig rig-calibrated.toml -o rig-calibrated-2.toml
      hlr-lab calibrate radiometric --sim --true-rig builtin:bench-night -o calibrated.toml
    """
    _run("radiometric", **options)


@calibrate.command("all")
@rig_options("Calibrate the simulated rig.")
@count_option("views", "Board photographs.")
@count_option("poses", "Lamp poses.")
@count_option("positions", "Lamp positions over the white reference.")
@click.option("--no-radiometric", is_flag=True, help="Camera and gantry only (no white reference).")
@warm_up_options("After the dark frames and before the white reference's")
@board_along_zero_option
@click.option(
    "--out",
    "out",
    type=FOLDER,
    help="Folder for the photographs and the intermediate rig files (default: calibration/DATE-all "
    "in the current folder).",
)
@output_option("the calibrated rig file")
@speed_factor_option("With --sim: simulated")
def all_(rig_path, sim, true_rig, no_radiometric, out, output, speed_factor, **counts) -> None:
    """Calibrate the camera, then the gantry with it, then the radiometry, into one calibrated rig file.

    The camera procedure (board on a wedge) writes OUT/rig-camera.toml; the gantry procedure (mirror
    ball) runs on that file and writes OUT/rig-gantry.toml; the radiometric procedure (white reference)
    runs on that one and writes -o, which carries all three [calibration] records. Each step needs the
    one before: the gantry's rays come from the camera, every pixel's distance to the lamp from both.

    \b
    Examples:
      hlr-lab calibrate all --rig rig.toml --board-along-zero -o rig-calibrated.toml
      hlr-lab calibrate all --sim --true-rig builtin:bench-night --board-along-zero --warm-up 30 \\
          -o calibrated.toml
    """
    rig = believed_rig(rig_path, sim, true_rig)
    check_targets(rig, ("camera", "gantry") if no_radiometric else ("camera", "gantry", "radiometric"))
    folder = out or default_folder("all", time.strftime("%Y-%m-%d-%H%M%S"))
    settings = Settings(**counts)  # the options are named as Settings' fields
    with console.status("calibrating…") as status:
        calibrate_all(
            rig,
            folder,
            output,
            targets_for(sim, true_rig, speed_factor),
            settings,
            radiometric=not no_radiometric,
            progress=lambda what: status.update(escape(what)),
            done=show,
        )
