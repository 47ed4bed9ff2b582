"""``hlr-lab calibrate``: measure the rig, and write a calibrated copy of its rig file. The procedures are
:mod:`calibration.procedures`'; this module parses options, puts the targets in place and prints."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from pathlib import Path

import click
from rich.markup import escape
from rich.table import Table

from calibration.procedures import (
    Calibrated,
    ProcedureName,
    Settings,
    Targets,
    calibrate_all,
    check_targets,
    default_folder,
    run_procedure,
)
from calibration.tables import TITLES, rows, warnings
from hlr_lab.cli.common import Finite, believed_rig, rig_options, speed_factor_option
from hlr_lab.cli.console import console
from hlr_lab.instrument.devices import Links
from hlr_lab.rig.file import Rig

DEFAULT = Settings()
board_along_zero_option = click.option(
    "--board-along-zero",
    is_flag=True,
    help="The board was mounted along the plate's 0° line: also correct turntable.zero_steps.",
)


def _count(name: str, lo: int, hi: int, default: int, help: str):
    """A count option of a procedure (how many photographs, poses, positions, exposures)."""
    return click.option(name, type=click.IntRange(lo, hi), default=default, show_default=True, help=help)


def photograph_options(replaced: str):
    """``--out``, ``--from`` and ``-o`` of a procedure whose calibrated file has ``replaced`` replaced."""

    def decorate(f):
        written = f"The calibrated rig file to write (the input's copy, {replaced} replaced)."
        f = click.option(
            "-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True, help=written
        )(f)
        f = click.option(
            "--from",
            "from_dir",
            type=click.Path(file_okay=False, exists=True, path_type=Path),
            help="Solve again from the photographs of an earlier run (no rig needed).",
        )(f)
        return click.option(
            "--out",
            "out",
            type=click.Path(file_okay=False, path_type=Path),
            help="Folder for the photographs (a new one; default: calibration/DATE-PROCEDURE "
            "in the current folder).",
        )(f)

    return decorate


class OperatorTargets:
    """The operator's rig: they are asked to put each target where the rig file says."""

    def board(self, stack: contextlib.ExitStack, rig: Rig) -> tuple[Links, Callable[[int], None]]:
        def ask(face: int) -> None:
            what = (
                "on the wedge's first face"
                if face == 0
                else "on the wedge's other face (turn the wedge over)"
            )
            click.confirm(f"Put the board {what}, facing the camera. Ready?", abort=True, err=True)

        return Links(), ask

    def mirror_ball(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        click.confirm(
            "Put the mirror ball on the plate where the rig file says. Ready?", abort=True, err=True
        )
        return Links()

    def white_reference(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        click.confirm(
            "Put the white reference on the plate where the rig file says. Ready?", abort=True, err=True
        )
        return Links()


def targets_for(sim: bool, true_rig: str | None, speed_factor: float) -> Targets:
    if not sim:
        return OperatorTargets()
    from worlds.targets import SimulatedTargets  # the simulator is reached only from the command line

    return SimulatedTargets(true_rig, speed_factor)


def _run(
    procedure: ProcedureName, rig_path, sim, true_rig, out, from_dir, output, speed_factor, settings: Settings
) -> None:
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
    if c.warmed is not None:
        state = "stable" if c.warmed.stable else "[yellow]NOT stable[/]"
        console.print(
            f"lamp {state} after {c.warmed.minutes:.1f} min of warm-up "
            f"({100 * c.warmed.per_minute:.2f} % per minute)"
        )
    t = Table(title=TITLES[c.procedure], title_justify="left")
    for column in ("", "rig file before", "calibrated"):
        t.add_column(column, justify="right", overflow="fold")
    for row in rows(c):
        t.add_row(*row)
    console.print(t)
    for warning in warnings(c):
        console.print(f"[yellow]{escape(warning)}[/]")
    summary = f"; summary {escape(str(c.summary))}" if c.summary else ""
    if c.summary_problem:
        summary = f"; [yellow]no summary page ({escape(c.summary_problem)})[/]"
    console.print(f"photographs in {escape(str(c.images))}{summary}; wrote {escape(str(c.output))}")


@click.group()
def calibrate() -> None:
    """Measure the rig (camera, gantry, radiometric, or all) and write a calibrated copy of its rig file."""


@calibrate.command("camera")
@rig_options("Calibrate the simulated rig (a simulated board on a wedge).")
@_count(
    "--views",
    16,
    200,
    DEFAULT.views,
    "Photographs: half on each face of the wedge, spread over ±55° of turntable.",
)
@board_along_zero_option
@photograph_options("camera fields")
@speed_factor_option("With --sim: simulated")
def camera(rig_path, sim, true_rig, views, out, from_dir, board_along_zero, output, speed_factor) -> None:
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
    settings = Settings(views=views, board_along_zero=board_along_zero)
    _run("camera", rig_path, sim, true_rig, out, from_dir, output, speed_factor, settings)


@calibrate.command("gantry")
@rig_options("Calibrate the simulated rig (a simulated mirror ball).")
@_count(
    "--poses", 12, 200, DEFAULT.poses, "Lamp poses, each photographed with the ball at two turntable angles."
)
@photograph_options("gantry fields")
@speed_factor_option("With --sim: simulated")
def gantry(rig_path, sim, true_rig, poses, out, from_dir, output, speed_factor) -> None:
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
    _run("gantry", rig_path, sim, true_rig, out, from_dir, output, speed_factor, Settings(poses=poses))


def warm_up_options(f):
    f = click.option(
        "--warm-up-within",
        "warm_up_within",
        type=Finite(min=0.01, max=10),
        default=DEFAULT.warm_up_within,
        show_default=True,
        metavar="PERCENT",
        help="The warm-up ends when the lamp changes by less than this per minute (as for acquire).",
    )(f)
    return click.option(
        "--warm-up",
        "warm_up_min",
        type=Finite(min=0),
        default=DEFAULT.warm_up_min,
        show_default=True,
        metavar="MINUTES",
        help="After the dark frames, keep the lamp on until it is stable "
        "(--warm-up-within), for at most MINUTES (use the same as for acquire).",
    )(f)


@calibrate.command("radiometric")
@rig_options("Calibrate the simulated rig (a simulated white reference).")
@_count("--positions", 3, 60, DEFAULT.positions, "Lamp positions over the white reference.")
@_count("--levels", 4, 40, DEFAULT.levels, "Exposures of the photon transfer.")
@warm_up_options
@photograph_options("[sensor] fields")
@speed_factor_option("With --sim: simulated")
def radiometric(
    rig_path,
    sim,
    true_rig,
    positions,
    levels,
    warm_up_within,
    warm_up_min,
    out,
    from_dir,
    output,
    speed_factor,
) -> None:
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
    settings = Settings(
        positions=positions, levels=levels, warm_up_min=warm_up_min, warm_up_within=warm_up_within
    )
    _run("radiometric", rig_path, sim, true_rig, out, from_dir, output, speed_factor, settings)


@calibrate.command("all")
@rig_options("Calibrate the simulated rig.")
@_count("--views", 16, 200, DEFAULT.views, "Board photographs.")
@_count("--poses", 12, 200, DEFAULT.poses, "Lamp poses.")
@_count("--positions", 3, 60, DEFAULT.positions, "Lamp positions over the white reference.")
@click.option("--no-radiometric", is_flag=True, help="Camera and gantry only (no white reference).")
@warm_up_options
@board_along_zero_option
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder for the photographs and the intermediate rig files (default: calibration/DATE-all "
    "in the current folder).",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="The calibrated rig file to write.",
)
@speed_factor_option("With --sim: simulated")
def all_(
    rig_path,
    sim,
    true_rig,
    views,
    poses,
    positions,
    no_radiometric,
    warm_up_within,
    warm_up_min,
    board_along_zero,
    out,
    output,
    speed_factor,
) -> None:
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
    settings = Settings(
        views=views,
        poses=poses,
        positions=positions,
        board_along_zero=board_along_zero,
        warm_up_min=warm_up_min,
        warm_up_within=warm_up_within,
    )
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
