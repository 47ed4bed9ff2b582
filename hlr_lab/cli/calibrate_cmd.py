"""``hlr-lab calibrate``: measure the rig, and write a calibrated copy of its rig file."""

from __future__ import annotations

import contextlib
import time
from importlib import resources
from pathlib import Path

import click
import numpy as np
from rich.markup import escape
from rich.table import Table

from hlr_lab.cli.common import Finite, believed_rig, rig_options, speed_factor_option
from hlr_lab.cli.console import console
from hlr_lab.devices import Links
from hlr_lab.errors import InputError
from hlr_lab.lamp_watch import LampWatch
from hlr_lab.rig import SIM_RIG, Rig
from hlr_lab.rig_control import open_rig
from hlr_lab.rig_edit import write_calibrated_rig


def photograph_options(replaced: str):
    """``--out``, ``--from`` and ``-o`` of a procedure whose calibrated file has ``replaced`` replaced."""

    def decorate(f):
        written = f"The calibrated rig file to write (the input's copy, {replaced} replaced)."
        f = click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
                         help=written)(f)  # fmt: skip
        f = click.option("--from", "from_dir", type=click.Path(file_okay=False, exists=True, path_type=Path),
                         help="Solve again from the photographs of an earlier run (no rig needed).")(f)  # fmt: skip
        return click.option("--out", "out", type=click.Path(file_okay=False, path_type=Path),
                            help="Folder for the photographs (a new one; default: calibration/DATE-PROCEDURE "
                            "beside the rig file).")(f)  # fmt: skip

    return decorate


def photographs_folder(rig: Rig, out: Path | None, from_dir: Path | None, procedure: str) -> Path:
    """Where a procedure's photographs are: ``--from``'s (read only), else ``--out`` or
    calibration/DATE-PROCEDURE beside the rig file, which must be new (or empty)."""
    default = rig_source_path(rig).parent / "calibration" / time.strftime(f"%Y-%m-%d-%H%M%S-{procedure}")
    return from_dir or _new_folder(out or default)


@click.group()
def calibrate() -> None:
    """Measure the rig (camera, gantry, or all) and write a calibrated copy of its rig file."""


@calibrate.command("camera")
@rig_options("Calibrate the simulated rig (a simulated board on a wedge).")
@click.option("--views", type=click.IntRange(16, 200), default=24, show_default=True,
              help="Photographs: half on each face of the wedge, spread over ±55° of turntable.")  # fmt: skip
@click.option("--board-along-zero", is_flag=True,
              help="The board was mounted along the plate's 0° line: also correct turntable.zero_steps.")  # fmt: skip
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
    from calibration.camera_procedure import board_spec

    rig = believed_rig(rig_path, sim, true_rig)
    board_spec(rig)  # a rig file without a board is refused before anything moves
    images = photographs_folder(rig, out, from_dir, "camera")
    _run_camera(
        rig, sim, true_rig, views, images, from_dir is not None, board_along_zero, output, speed_factor
    )


def _run_camera(rig: Rig, sim, true_rig, views, images: Path, solve_only: bool, board_along_zero, output: Path,
                speed_factor) -> Rig:  # fmt: skip
    """Photograph (unless ``solve_only``) into ``images``, solve, write ``output``; returns its rig."""
    from calibration.camera_procedure import capture_board_frames, load_board_frames, solve_camera
    from calibration.summary import camera_summary

    if not solve_only:
        with contextlib.ExitStack() as stack:
            links, turn = board_world(stack, rig, sim, true_rig, speed_factor)
            with console.status("calibrating the camera…") as status, open_rig(rig, links) as opened:
                capture_board_frames(
                    opened.instruments,
                    rig,
                    images,
                    views=views,
                    turn_the_wedge=turn,
                    progress=lambda i, n, what: status.update(escape(f"photograph {i + 1}/{n}: {what}")),
                )
    with console.status("solving…"):
        result = solve_camera(load_board_frames(images), rig)
    fields = result.rig_fields(rig, board_along_zero=board_along_zero)
    calibrated = write_calibrated_rig(rig_source_path(rig), output, fields, "camera", result.record(images))
    console.print(_table(rig, calibrated, result))
    _say_written(images, output, lambda: camera_summary(result, rig, images))
    return calibrated


def rig_source_path(rig: Rig) -> Path:
    if rig.source == "builtin:sim":
        with resources.as_file(resources.files("hlr_lab.data") / SIM_RIG) as path:
            return Path(path)
    return Path(rig.source)


def board_world(stack, rig: Rig, sim: bool, true_rig, speed_factor):
    """The links to use and what turning the wedge means: the operator, or the simulator."""
    if not sim:

        def ask(face: int) -> None:
            what = (
                "on the wedge's first face"
                if face == 0
                else "on the wedge's other face (turn the wedge over)"
            )
            click.confirm(f"Put the board {what}, facing the camera. Ready?", abort=True, err=True)

        return Links(), ask
    # the simulator is reached only from the command line (the composition root)
    from hlr_lab.cli.sim_world import world_geometry, world_links
    from sim.rig import SimRig
    from sim.targets import Board, Wedge, charuco_scene

    b = rig.file.calibration.board
    board = Board(tuple(b.squares), b.square_m, b.marker_m, b.dictionary)
    faces = [
        Wedge(tilt_deg=20.0, height_m=b.centre_height_m),
        Wedge(tilt_deg=45.0, height_m=b.centre_height_m),
    ]
    world = stack.enter_context(
        SimRig(
            scene=charuco_scene(board, faces[0]),
            speed_factor=speed_factor,
            spp=8,
            **world_geometry(rig, true_rig, runs=False),
        )
    )
    return world_links(world), lambda face: world.show(charuco_scene(board, faces[face]))


def _table(before: Rig, after: Rig, result) -> Table:
    t = Table(title="camera calibration", title_justify="left")
    for column in ("", "rig file before", "calibrated"):
        t.add_column(column, justify="right")
    kb, ka, se = before.camera.matrix, after.camera.matrix, result.pose.intrinsics_se_px
    rows = [
        (
            "fx, fy (px)",
            f"{kb[0, 0]:.1f}, {kb[1, 1]:.1f}",
            f"{ka[0, 0]:.1f} ± {se[0]:.1f}, {ka[1, 1]:.1f} ± {se[1]:.1f}",
        ),
        (
            "cx, cy (px)",
            f"{kb[0, 2]:.2f}, {kb[1, 2]:.2f}",
            f"{ka[0, 2]:.2f} ± {se[2]:.2f}, {ka[1, 2]:.2f} ± {se[3]:.2f}",
        ),
        ("k1, k2", _pair(before.camera.distortion), _pair(after.camera.distortion)),
        ("position (m)", _vec(before.camera.centre), _vec(after.camera.centre)),
        ("moved by", "", f"{1e3 * np.linalg.norm(after.camera.centre - before.camera.centre):.2f} mm"),
        ("view turned by", "", f"{_angle(before.camera.forward, after.camera.forward):.3f}°"),
        ("roll (°)", f"{before.file.camera.roll_deg:.3f}", f"{after.file.camera.roll_deg:.3f}"),
        (
            "turntable zero (steps)",
            str(before.file.turntable.zero_steps),
            str(after.file.turntable.zero_steps),
        ),
        ("board azimuth on the plate", "", f"{result.pose.board_azimuth_deg:.3f}°"),
        (
            "reprojection RMS",
            "",
            f"{result.pose.rms_px:.3f} px (worst view {result.pose.per_view_rms_px.max():.3f})",
        ),
        ("views used", "", f"{sum(len(d.ids) >= 6 for d in result.detections)} of {len(result.frames)}"),
    ]
    for row in rows:
        t.add_row(*row)
    return t


def _pair(d) -> str:
    d = [*d, 0.0, 0.0]
    return f"{d[0]:.4f}, {d[1]:.4f}"


def _vec(v) -> str:
    return ", ".join(f"{x:.4f}" for x in v)


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@calibrate.command("gantry")
@rig_options("Calibrate the simulated rig (a simulated mirror ball).")
@click.option("--poses", type=click.IntRange(12, 200), default=30, show_default=True,
              help="Lamp poses, each photographed with the ball at two turntable angles.")  # fmt: skip
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
    from calibration.gantry_procedure import ball_spec

    rig = believed_rig(rig_path, sim, true_rig)
    ball_spec(rig)  # a rig file without a ball is refused before anything moves
    images = photographs_folder(rig, out, from_dir, "gantry")
    _run_gantry(rig, sim, true_rig, poses, images, from_dir is not None, output, speed_factor)


def _run_gantry(
    rig: Rig, sim, true_rig, poses, images: Path, solve_only: bool, output: Path, speed_factor
) -> Rig:
    """Photograph (unless ``solve_only``) into ``images``, solve, write ``output``; returns its rig."""
    from calibration.gantry_procedure import ball_spec, capture_ball_frames, load_ball_frames, solve_gantry
    from calibration.summary import gantry_summary

    if not solve_only:
        radius, place = ball_spec(rig)
        with contextlib.ExitStack() as stack:
            links = ball_world(stack, rig, sim, true_rig, speed_factor, radius, place)
            with console.status("calibrating the gantry…") as status, open_rig(rig, links) as opened:
                capture_ball_frames(
                    opened.instruments,
                    rig,
                    images,
                    poses=poses,
                    progress=lambda i, n, what: status.update(escape(f"photograph {i + 1}/{n}: {what}")),
                )
    with console.status("solving…"):
        frames = load_ball_frames(images)
        result = solve_gantry(frames, rig)
    calibrated = write_calibrated_rig(
        rig_source_path(rig), output, result.rig_fields(rig), "gantry", result.record(images)
    )
    k0, k1 = rig.gantry.kinematics, calibrated.gantry.kinematics
    t = Table(title="gantry calibration", title_justify="left")
    for column in ("", "rig file before", "calibrated"):
        t.add_column(column, justify="right")
    se = result.fit.standard_errors
    for row in (
        ("centre (m)", _vec(k0.centre), _vec(k1.centre)),
        ("arm radius (m)", f"{k0.arm_radius:.4f}", f"{k1.arm_radius:.4f} ± {se['arm_radius_m']:.4f}"),
        ("zero ticks", f"{k0.zero_ticks[0]}, {k0.zero_ticks[1]}", f"{k1.zero_ticks[0]}, {k1.zero_ticks[1]}"),
        (
            "azimuth axis tilt",
            f"{_angle(k0.frame[:, 2], [0, 0, 1]):.3f}°",
            f"{_angle(k1.frame[:, 2], [0, 0, 1]):.3f}°",
        ),
        ("rays used", "", f"{result.rays} ({result.refused} poses refused: lamp behind the ball)"),
        ("worst lamp miss", "", f"{result.fit.miss_mm.max():.2f} mm"),
    ):
        t.add_row(*row)
    console.print(t)
    _say_written(images, output, lambda: gantry_summary(result, frames, rig, images))
    return calibrated


def _say_written(images: Path, output: Path, write_summary) -> None:
    """Where everything went; the summary page is a convenience: a folder it cannot be written to
    (photographs on read-only media) costs a warning, not the calibration."""
    try:
        summary = f"; summary {escape(str(write_summary()))}"
    except OSError as exc:
        summary = f"; [yellow]no summary page ({escape(exc.strerror or str(exc))})[/]"
    console.print(f"photographs in {escape(str(images))}{summary}; wrote {escape(str(output))}")


@calibrate.command("radiometric")
@rig_options("Calibrate the simulated rig (a simulated white reference).")
@click.option("--positions", type=click.IntRange(3, 60), default=6, show_default=True,
              help="Lamp positions over the white reference.")  # fmt: skip
@click.option("--levels", type=click.IntRange(4, 40), default=8, show_default=True,
              help="Exposures of the photon transfer.")  # fmt: skip
@click.option("--warm-up-within", "warm_up_within", type=Finite(min=0.01, max=10), default=0.2,
              show_default=True, metavar="PERCENT",
              help="The warm-up ends when the lamp changes by less than this per minute (as for acquire).")  # fmt: skip
@click.option("--warm-up", "warm_up_min", type=Finite(min=0), default=0.0, show_default=True,
              metavar="MINUTES", help="After the dark frames, keep the lamp on until it is stable (--warm-up-within), "
              "for at most MINUTES (use the same as for acquire).")  # fmt: skip
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
    from calibration.radiometric_procedure import reference_pixels, white_spec

    rig = believed_rig(rig_path, sim, true_rig)
    reference_pixels(rig, white_spec(rig))  # no reference, or one out of view: refused before anything moves
    images = photographs_folder(rig, out, from_dir, "radiometric")
    _run_radiometric(
        rig,
        sim,
        true_rig,
        positions,
        levels,
        images,
        from_dir is not None,
        output,
        speed_factor,
        warm_up_min,
        warm_up_within,
    )


def _run_radiometric(rig: Rig, sim, true_rig, positions, levels, images: Path, solve_only: bool, output: Path,
                     speed_factor, warm_up_min: float = 0.0, warm_up_within: float = 0.2) -> Rig:  # fmt: skip
    """Photograph (unless ``solve_only``) into ``images``, solve, write ``output``; returns its rig."""
    from calibration.radiometric_procedure import (
        capture_radiometric_frames,
        load_radiometric_frames,
        solve_radiometric,
        white_spec,
    )

    if not solve_only:
        with contextlib.ExitStack() as stack:
            links = white_world(stack, rig, sim, true_rig, speed_factor, white_spec(rig))
            with console.status("calibrating the radiometry…") as status, open_rig(rig, links) as opened:
                warm = LampWatch(warm_up_s=60 * warm_up_min, stable_per_min=warm_up_within / 100)
                warmed = capture_radiometric_frames(
                    opened.instruments, rig, images, positions=positions, levels=levels, warm=warm,
                    progress=lambda i, n, what: status.update(escape(f"photograph {i + 1}/{n}: {what}")),
                )  # fmt: skip
            if warmed is not None:
                state = "stable" if warmed.stable else "[yellow]NOT stable[/]"
                console.print(f"lamp {state} after {warmed.minutes:.1f} min of warm-up "
                              f"({100 * warmed.per_minute:.2f} % per minute)")  # fmt: skip
    with console.status("solving…"):
        result = solve_radiometric(load_radiometric_frames(images), rig)
    calibrated = write_calibrated_rig(
        rig_source_path(rig), output, result.rig_fields(), "radiometric", result.record(images)
    )
    before, after = rig.file.sensor, calibrated.file.sensor
    t = Table(title="radiometric calibration", title_justify="left")
    for column in ("", "rig file before", "calibrated"):
        t.add_column(column, justify="right")
    gain = before.conversion_gain_dn_per_e
    sp = result.lamp.sensitivity_times_power
    for row in (
        ("black level (DN)", f"{before.black_level_dn:.2f}", f"{after.black_level_dn:.2f}"),
        ("read noise (DN)", f"{before.read_noise_dn:.3f}", f"{after.read_noise_dn:.3f}"),
        ("conversion gain (DN/e⁻)", "—" if gain is None else f"{gain:.4f}", f"{after.conversion_gain_dn_per_e:.4f}"),
        ("sensitivity × power", f"{before.sensitivity * rig.file.light.power:.1f}",
         f"{np.mean(sp):.1f} (channels {', '.join(f'{v:.1f}' for v in sp)})"),
        ("worst deviation from linear", "", f"{100 * result.transfer.worst_nonlinearity:.2f} %"),
        ("1/d² residual over the lamp positions", "", f"{100 * result.lamp.inverse_square_residual:.2f} %"),
    ):  # fmt: skip
        t.add_row(*row)
    console.print(t)
    if not result.lamp.follows_inverse_square:
        console.print(
            "[yellow]the lamp does not follow 1/d² within 2 %: it may need a diffuser, or another [light] type[/]"
        )
    console.print(f"photographs in {escape(str(images))}; wrote {escape(str(output))}")
    return calibrated


@calibrate.command("all")
@rig_options("Calibrate the simulated rig.")
@click.option(
    "--views", type=click.IntRange(16, 200), default=24, show_default=True, help="Board photographs."
)
@click.option("--poses", type=click.IntRange(12, 200), default=30, show_default=True, help="Lamp poses.")
@click.option("--positions", type=click.IntRange(3, 60), default=6, show_default=True,
              help="Lamp positions over the white reference.")  # fmt: skip
@click.option("--no-radiometric", is_flag=True, help="Camera and gantry only (no white reference).")
@click.option("--board-along-zero", is_flag=True,
              help="The board was mounted along the plate's 0° line: also correct turntable.zero_steps.")  # fmt: skip
@click.option("--out", "out", type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the photographs and the intermediate rig files (default: calibration/DATE-all).",
              )  # fmt: skip
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The calibrated rig file to write.")  # fmt: skip
@speed_factor_option("With --sim: simulated")
def all_(rig_path, sim, true_rig, views, poses, positions, no_radiometric, board_along_zero, out, output,
         speed_factor) -> None:  # fmt: skip
    """Calibrate the camera, then the gantry with it, then the radiometry, into one calibrated rig file.

    The camera procedure (board on a wedge) writes OUT/rig-camera.toml; the gantry procedure (mirror
    ball) runs on that file and writes OUT/rig-gantry.toml; the radiometric procedure (white reference)
    runs on that one and writes -o, which carries all three [calibration] records. Each step needs the
    one before: the gantry's rays come from the camera, every pixel's distance to the lamp from both.

    \b
    Examples:
      hlr-lab calibrate all --rig rig.toml --board-along-zero -o rig-calibrated.toml
      hlr-lab calibrate all --sim --true-rig builtin:bench-night --board-along-zero -o calibrated.toml
    """
    from calibration.camera_procedure import board_spec
    from calibration.gantry_procedure import ball_spec
    from calibration.radiometric_procedure import white_spec

    rig = believed_rig(rig_path, sim, true_rig)
    board_spec(rig), ball_spec(rig)  # every target described before anything moves
    if not no_radiometric:
        white_spec(rig)
    folder = photographs_folder(rig, out, None, "all")
    run_all(rig, sim, true_rig, folder, output, speed_factor, views=views, poses=poses, positions=positions,
            radiometric=not no_radiometric, board_along_zero=board_along_zero)  # fmt: skip


def run_all(rig: Rig, sim, true_rig, folder: Path, output: Path, speed_factor, *, views: int = 24, poses: int = 30,
            positions: int = 6, radiometric: bool = True, board_along_zero: bool = False,
            warm_up_min: float = 0.0, warm_up_within: float = 0.2) -> Rig:  # fmt: skip
    """Camera, gantry, then (``radiometric``) radiometry, each on the file the one before wrote (in
    ``folder``), the last into ``output``; returns its rig."""
    with_camera = _run_camera(rig, sim, true_rig, views, _new_folder(folder / "camera"), False, board_along_zero,
                              folder / "rig-camera.toml", speed_factor)  # fmt: skip
    gantry_output = folder / "rig-gantry.toml" if radiometric else output
    with_gantry = _run_gantry(with_camera, sim, true_rig, poses, _new_folder(folder / "gantry"), False,
                              gantry_output, speed_factor)  # fmt: skip
    if not radiometric:
        return with_gantry
    return _run_radiometric(with_gantry, sim, true_rig, positions, 8, _new_folder(folder / "radiometric"), False,
                            output, speed_factor, warm_up_min, warm_up_within)  # fmt: skip


def _new_folder(folder: Path) -> Path:
    if folder.exists() and any(folder.iterdir()):
        raise InputError("the folder is not empty; give a new --out (or --from to solve again)", path=folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def ball_world(stack, rig: Rig, sim: bool, true_rig, speed_factor, radius: float, place) -> Links:
    """The links for the gantry procedure: the rig's (once the operator has put the ball down), or a
    simulated world with the ball where the rig file says."""

    def scene():
        from sim.targets import mirror_ball_scene

        return mirror_ball_scene(radius, place)

    return _target_world(stack, rig, sim, true_rig, speed_factor, "the mirror ball", scene, spp=16)


def white_world(stack, rig: Rig, sim: bool, true_rig, speed_factor, white) -> Links:
    """The links for the radiometric procedure: the rig's (once the operator has laid the white
    reference down), or a simulated world with it where the rig file says."""

    def scene():
        from sim.targets import white_reference_scene

        return white_reference_scene(tuple(white.reflectance), white.size_m, white.place_m,
                                     height_m=white.thickness_m)  # fmt: skip

    return _target_world(stack, rig, sim, true_rig, speed_factor, "the white reference", scene, spp=8)


def _target_world(stack, rig: Rig, sim: bool, true_rig, speed_factor, what: str, scene, *, spp: int) -> Links:
    if not sim:
        click.confirm(f"Put {what} on the plate where the rig file says. Ready?", abort=True, err=True)
        return Links()
    # the simulator is reached only from the command line (the composition root)
    from hlr_lab.cli.sim_world import world_geometry, world_links
    from sim.rig import SimRig

    world = stack.enter_context(
        SimRig(scene=scene(), speed_factor=speed_factor, spp=spp, **world_geometry(rig, true_rig, runs=False))
    )
    return world_links(world)
