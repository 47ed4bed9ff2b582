"""The calibration procedures as one table: photograph (unless solving again from earlier photographs),
solve, write the calibrated copy of the rig file. ``hlr-lab calibrate``, campaigns and ``hlr-lab bench
calibration`` all run them through :func:`run_procedure` and :func:`calibrate_all`.

Where a procedure's target stands is not this module's business: a :class:`Targets` gives the links to
reach the rig with the target in place — the operator's rig once they have put it down (the command
line asks them), or a simulated world with the target where the rig file says (:mod:`worlds.targets`).
Conventions and figures: docs/calibration.md.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

from calibration.camera_procedure import (
    CameraCalibration,
    board_spec,
    capture_board_frames,
    load_board_frames,
    solve_camera,
)
from calibration.gantry_procedure import (
    GantryCalibration,
    ball_spec,
    capture_ball_frames,
    load_ball_frames,
    solve_gantry,
)
from calibration.radiometric_procedure import (
    RadiometricCalibration,
    capture_radiometric_frames,
    load_radiometric_frames,
    reference_pixels,
    solve_radiometric,
    white_spec,
)
from calibration.summary import camera_summary, gantry_summary
from hlr_lab.campaign.runner import CalibrateJob, job_rig
from hlr_lab.errors import InputError
from hlr_lab.instrument.control import open_rig
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.rig.calibrated import write_calibrated_rig
from hlr_lab.rig.file import RIG_FORMAT, Rig, rig_source_path
from hlr_lab.session.lamp import LampWatch, WarmUp
from hlr_lab.session.outputs import check_outputs

ProcedureName = Literal["camera", "gantry", "radiometric"]
Progress = Callable[[str], None]
# what a procedure drives, given the devices as opened: the same by default; a benchmark's clocks around them
Instrumented = Callable[[ProcedureName, Instruments], Instruments]


def _as_opened(procedure: ProcedureName, instruments: Instruments) -> Instruments:
    return instruments


class Targets(Protocol):
    """Where each procedure's target is, as links to the rig that sees it (kept open by ``stack``)."""

    def board(self, stack: contextlib.ExitStack, rig: Rig) -> tuple[Links, Callable[[int], None]]:
        """The links with the ChArUco board on the wedge's first face, and what turning the wedge to face
        ``i`` (0 or 1) means."""
        ...

    def mirror_ball(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        """The links with the mirror ball where ``[calibration.mirror_ball]`` puts it."""
        ...

    def white_reference(self, stack: contextlib.ExitStack, rig: Rig) -> Links:
        """The links with the white reference where ``[calibration.white_reference]`` puts it."""
        ...


@dataclass(frozen=True)
class Settings:
    """How much each procedure photographs (the commands' defaults are these)."""

    views: int = 24  # board photographs, half on each face of the wedge
    board_along_zero: bool = False  # the board stood along the plate's 0° line: correct zero_steps too
    poses: int = 30  # lamp poses over the mirror ball
    positions: int = 6  # lamp positions over the white reference
    levels: int = 8  # exposures of the photon transfer
    warm_up_min: float = 0.0  # keep the lamp on (at most this long) until stable, before the white frames
    warm_up_within: float = 0.2  # stable: the lamp changes by less than this many per cent a minute


# how many of each a procedure may be asked for: the ranges of the commands' and the benchmark's options
COUNT_RANGES: dict[str, tuple[int, int]] = {
    "views": (16, 200),  # the solve needs both faces of the wedge well spread
    "poses": (12, 200),  # the gantry's kinematics have 9 parameters
    "positions": (3, 60),  # 1/d² needs three distances
    "levels": (4, 40),  # a photon transfer line needs a few points above the read noise
}


@dataclass(frozen=True)
class Calibrated:
    """One procedure's outcome: the calibrated rig (read back from ``output``), its solve, where the
    photographs are, how the warm-up ended (radiometric with a warm-up; else None), and the summary page
    (None: none for this procedure, or the folder could not take it: ``summary_problem`` says why)."""

    procedure: ProcedureName
    before: Rig
    rig: Rig
    result: CameraCalibration | GantryCalibration | RadiometricCalibration
    images: Path
    output: Path
    warmed: WarmUp | None = None
    summary: Path | None = None
    summary_problem: str | None = None


def check_targets(rig: Rig, procedures: tuple[ProcedureName, ...]) -> None:
    """Refuse, before anything moves, a rig file that does not describe the procedures' targets, or has
    no lamp relay to light them."""
    if procedures and rig.file.lamp is None:
        raise InputError(
            "calibration switches the lamp: add a [lamp] section (its relay: docs/rig.example.toml)",
            path=rig.source,
            field="lamp",
        )
    for name in procedures:
        if name == "camera":
            board_spec(rig)
        elif name == "gantry":
            ball_spec(rig)
        else:
            reference_pixels(rig, white_spec(rig))  # no reference, or one out of view


def default_folder(procedure: str, now: str) -> Path:
    """Where photographs go without ``--out``: calibration/DATE-PROCEDURE in the current folder (never
    beside the rig file, which may be inside an installed package)."""
    return Path("calibration") / f"{now}-{procedure}"


@contextlib.contextmanager
def new_photographs_folder(folder: Path) -> Iterator[Path]:
    """``folder``, which must be new or empty, created for a procedure's photographs; removed again (with
    the parents made for it) when the procedure fails before a photograph is kept."""
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise InputError("the folder is not empty; give a new --out (or --from to solve again)", path=folder)
    made = [p for p in (folder, *folder.parents) if not p.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    except BaseException:
        for p in made:  # deepest first; stop at the first that holds something
            try:
                p.rmdir()
            except OSError:
                break
        raise


def run_procedure(
    procedure: ProcedureName,
    rig: Rig,
    images: Path,
    output: Path,
    targets: Targets,
    settings: Settings = Settings(),
    *,
    solve_only: bool = False,
    progress: Progress = lambda _: None,
    instrumented: Instrumented = _as_opened,
) -> Calibrated:
    """Photograph ``procedure``'s frames into ``images`` (a new folder; unless ``solve_only``: then it
    holds an earlier run's), solve, and write ``output``: ``rig``'s file with the procedure's fields
    replaced and its ``[calibration.PROCEDURE]`` record. The photographs are taken with
    ``instrumented(procedure, the opened devices)``. An ``output`` over the rig file, a photograph solved
    again, a session's own file or a link is refused before anything moves (:func:`check_outputs`)."""
    solved_again = [p for p in images.rglob("*") if p.is_file()] if solve_only else []
    check_outputs([output], [rig_source_path(rig), *solved_again], writes=[RIG_FORMAT])
    if not solve_only:
        with new_photographs_folder(images):
            warmed = _capture(procedure, rig, images, targets, settings, progress, instrumented)
    else:
        warmed = None
    progress("solving…")
    result, fields, write_summary = _solve(procedure, rig, images, settings)
    calibrated = write_calibrated_rig(rig_source_path(rig), output, fields, procedure, result.record(images))
    summary, problem = None, None
    if write_summary is not None:
        try:  # a convenience: photographs on read-only media cost a warning, not the calibration
            summary = write_summary()
        except OSError as exc:
            problem = exc.strerror or str(exc)
    return Calibrated(procedure, rig, calibrated, result, images, output, warmed, summary, problem)


def calibrate_all(
    rig: Rig,
    folder: Path,
    output: Path,
    targets: Targets,
    settings: Settings = Settings(),
    *,
    radiometric: bool = True,
    progress: Progress = lambda _: None,
    done: Callable[[Calibrated], None] = lambda _: None,
    instrumented: Instrumented = _as_opened,
) -> Calibrated:
    """Camera, then the gantry on the file the camera wrote, then (``radiometric``) the radiometry on the
    gantry's: photographs in ``folder``/PROCEDURE, the intermediate files ``folder``/rig-PROCEDURE.toml,
    the last written to ``output`` (it carries every record). ``done`` is called after each procedure;
    ``instrumented`` as for :func:`run_procedure`."""
    order: tuple[ProcedureName, ...] = (
        ("camera", "gantry", "radiometric") if radiometric else ("camera", "gantry")
    )
    # the last procedure writes output minutes after the first moved: refused (over the rig file, an
    # intermediate file, a session's own file) before anything moves
    steps = [folder / f"rig-{name}.toml" for name in order[:-1]]
    check_outputs([output, *steps], [rig_source_path(rig)], writes=[RIG_FORMAT] * (1 + len(steps)))
    outcome: Calibrated | None = None
    with new_photographs_folder(folder):
        for i, name in enumerate(order):
            last = i == len(order) - 1
            outcome = run_procedure(
                name,
                rig,
                folder / name,
                output if last else steps[i],
                targets,
                settings,
                progress=progress,
                instrumented=instrumented,
            )
            done(outcome)
            rig = outcome.rig
    assert outcome is not None  # the order is never empty
    return outcome


def calibrate_job(
    job: CalibrateJob, targets: Targets, *, done: Callable[[Calibrated], None] = lambda _: None
) -> None:
    """A campaign's calibrate job as ``hlr-lab calibrate PROCEDURE`` runs it, on the job's rig file (or the
    built-in rig), its photographs beside the output in calibration/DATE-NAME; ``done`` is called after
    each procedure."""
    rig = job_rig(job)
    folder = job.output.parent / "calibration" / f"{time.strftime('%Y-%m-%d-%H%M%S')}-{job.name}"
    settings = Settings(warm_up_min=job.warm_up_min, warm_up_within=job.warm_up_within)
    if job.procedure == "all":
        calibrate_all(rig, folder, job.output, targets, settings, done=done)
    else:
        done(run_procedure(job.procedure, rig, folder, job.output, targets, settings))


def _capture(
    procedure: ProcedureName,
    rig: Rig,
    images: Path,
    targets: Targets,
    settings: Settings,
    progress: Progress,
    instrumented: Instrumented,
) -> WarmUp | None:
    def step(i: int, n: int, what: str) -> None:
        progress(f"photograph {i + 1}/{n}: {what}")

    with contextlib.ExitStack() as stack:
        if procedure == "camera":
            links, turn = targets.board(stack, rig)
            with open_rig(rig, links) as opened:
                capture_board_frames(
                    instrumented(procedure, opened.instruments),
                    rig,
                    images,
                    views=settings.views,
                    turn_the_wedge=turn,
                    progress=step,
                )
            return None
        if procedure == "gantry":
            with open_rig(rig, targets.mirror_ball(stack, rig)) as opened:
                capture_ball_frames(
                    instrumented(procedure, opened.instruments),
                    rig,
                    images,
                    poses=settings.poses,
                    progress=step,
                )
            return None
        warm = LampWatch(warm_up_s=60 * settings.warm_up_min, stable_per_min=settings.warm_up_within / 100)
        with open_rig(rig, targets.white_reference(stack, rig)) as opened:
            return capture_radiometric_frames(
                instrumented(procedure, opened.instruments),
                rig,
                images,
                positions=settings.positions,
                levels=settings.levels,
                warm=warm,
                progress=step,
            )


def _solve(
    procedure: ProcedureName, rig: Rig, images: Path, settings: Settings
) -> tuple[Any, dict[str, dict], Callable[[], Path] | None]:
    """The solve, the rig-file fields it gives, and how to write its summary page (None: it has none)."""
    if procedure == "camera":
        camera = solve_camera(load_board_frames(images), rig)
        fields = camera.rig_fields(rig, board_along_zero=settings.board_along_zero)
        return camera, fields, lambda: camera_summary(camera, rig, images)
    if procedure == "gantry":
        frames = load_ball_frames(images)
        gantry = solve_gantry(frames, rig)
        return gantry, gantry.rig_fields(rig), lambda: gantry_summary(gantry, frames, rig, images)
    radiometric = solve_radiometric(load_radiometric_frames(images), rig)
    return radiometric, radiometric.rig_fields(), None
