"""``hlr-lab calibrate camera``: photograph a ChArUco board on a wedge as the turntable turns it, then
find the camera's intrinsics and its pose against the turntable axis (:mod:`calibration.charuco`,
:mod:`calibration.camera_pose`).

The board stands on a wedge on the plate (``[calibration.board]`` in the rig file says which board and
how high its centre stands). The wedge has two faces of different tilt: the board is photographed on
one, the operator turns the wedge to the other (asked once), and it is photographed again, each time
at ``views / 2`` turntable angles spread over ±55° (beyond that the board is seen too obliquely to
detect). The gantry lamp lights it from above the camera's side. Each view is photographed
:data:`FRAMES_PER_VIEW` times and the solve averages them. Every photograph is kept in the output folder
as a session's frames are (16-bit PNG, sidecar, journal), so a solve can be run again from them
(:func:`load_board_frames`) without the rig.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.camera_pose import CameraPose, refine_pose
from calibration.charuco import BoardSpec, CalibrationError, Detection, calibrate_intrinsics, detect
from calibration.exposure import ExposureGoal, exposed
from calibration.images import PhotographFields, journaled_images, photograph_line
from hlr_lab.errors import InputError
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.rig.file import CAMERA_PARAMETERS, Rig
from hlr_lab.session.frames import store_frame
from hlr_lab.session.journal import JOURNAL, Journal

log = logging.getLogger(__name__)
DEFAULT_VIEWS = 24
# Photographs averaged per view. The principal point is the intrinsic a turntable's views determine
# least well (it trades off against the camera's position across the axis): with one photograph per view
# its standard error is ~0.7 px, with four (each corner's noise halved) ~0.35 px, inside the 1 px it
# must meet (docs/calibration.md). A frame costs an exposure; a view costs a turntable move.
FRAMES_PER_VIEW = 4
SWEEP_DEG = 55.0  # the board's turn either way; beyond ~60° its markers are too oblique to decode
LAMP_DEG = (-90.0, 45.0)  # gantry azimuth, elevation: above the camera's side (world −y)
FILL = 0.7  # the brightest paper at this fraction of full scale
SETTLE_S = 60.0


@dataclass(frozen=True)
class BoardFrame:
    """One view of the board: pixels (H, W[, C]; from a capture, the grey mean of the view's photographs),
    the stage's measured steps, which wedge face."""

    pixels: np.ndarray
    turntable_steps: int
    placement: int


@dataclass(frozen=True)
class CameraCalibration:
    """The camera procedure's result: the camera's pose and intrinsics, the board's detections and the
    frames they came from, OpenCV's first calibration's RMS (px)."""

    pose: CameraPose
    detections: list[Detection]
    frames: list[BoardFrame]
    intrinsics_rms_px: float

    def rig_fields(self, rig: Rig, *, board_along_zero: bool = False) -> dict[str, dict]:
        """The ``[camera]`` fields the rig file takes from this calibration; with ``board_along_zero`` (the
        board was mounted along the plate's 0° line) also ``turntable.zero_steps``: the board's azimuth
        in the fitted world is the turntable's zero error (:mod:`calibration.camera_pose`); and
        ``turntable.limits_deg`` narrowed to the stage steps the old limits allowed."""
        p = self.pose
        fields = {
            "camera": {
                "matrix": p.matrix,
                "distortion": p.distortion,
                "position_m": p.position_m,
                "look_at_m": p.look_at_m,
                "up": [0.0, 0.0, 1.0],
                "roll_deg": p.roll_deg,
            }
        }
        if board_along_zero:
            t = rig.turntable_kinematics
            zero = round(t.zero_steps - p.board_azimuth_deg * t.steps_per_degree)
            # the limits narrowed so that no goal lands outside the step range the old ones allowed
            # (the drive's own travel limits were set for it): a zero moved by 48 steps puts +180° at
            # 18 048 steps, past a drive that stops at 18 000
            lo, hi = rig.file.turntable.limits_deg
            ends = sorted((t.steps_for(d) - zero) / t.steps_per_degree for d in (lo, hi))
            limits = [max(lo, np.ceil(ends[0] * 100) / 100), min(hi, np.floor(ends[1] * 100) / 100)]
            fields["turntable"] = {"zero_steps": zero, "limits_deg": limits}
        return fields

    def record(self, images: Path) -> dict:
        """The ``[calibration.camera]`` provenance: the images used and the residuals."""
        return {
            "images": str(images.resolve()),
            "views": len(self.frames),
            "views_used": int(sum(len(d.ids) >= 6 for d in self.detections)),
            "rms_px": round(self.pose.rms_px, 4),
            "intrinsics_only_rms_px": round(self.intrinsics_rms_px, 4),
            "worst_view_rms_px": round(float(self.pose.per_view_rms_px.max()), 4),
            "board_azimuth_deg": round(self.pose.board_azimuth_deg, 4),
            "focal_se_px": [round(float(v), 3) for v in self.pose.intrinsics_se_px[:2]],
            "principal_point_se_px": [round(float(v), 3) for v in self.pose.intrinsics_se_px[2:]],
            # for the fit's systematic uncertainty (docs/fitting.md): the pose's and intrinsics' together
            "covariance_of": list(CAMERA_PARAMETERS),
            "covariance": [[float(f"{v:.4g}") for v in row] for row in self.pose.covariance],
        }


def board_spec(rig: Rig) -> tuple[BoardSpec, float]:
    """The rig file's board, and the height of its centre above the plate; refused when missing."""
    board = rig.file.calibration.board
    if board is None:
        raise InputError(
            "no [calibration.board]: describe the ChArUco board (squares, square_m, marker_m, dictionary, "
            "centre_height_m) — see docs/calibration.md",
            path=rig.source,
            field="calibration.board",
        )
    across, down = board.squares
    return BoardSpec((across, down), board.square_m, board.marker_m, board.dictionary), board.centre_height_m


def board_angles(views: int) -> list[tuple[int, float]]:
    """(placement, turntable degrees) of each view: half on each wedge face, spread over ±55°."""
    if views < 2 * 8:
        raise InputError(
            f"{views} views are too few: at least 16 (8 on each face of the wedge)", field="--views"
        )
    per_face = views // 2
    angles = np.linspace(-SWEEP_DEG, SWEEP_DEG, per_face)
    return [(face, float(a)) for face in (0, 1) for a in angles]


def capture_board_frames(
    instruments: Instruments,
    rig: Rig,
    out: Path,
    *,
    views: int = DEFAULT_VIEWS,
    turn_the_wedge: Callable[[int], None],
    progress: Callable[[int, int, str], None] = lambda i, n, what: None,
) -> None:
    """Photograph the board at every (placement, angle) into ``out`` (frames, sidecars, journal).
    ``turn_the_wedge(placement)`` is called before each placement's first view (the operator puts the
    board on that face of the wedge)."""
    plan = board_angles(views)
    g, t = rig.gantry.kinematics, rig.turntable_kinematics
    lamp_ticks = g.ticks_for(*LAMP_DEG)
    exposure = rig.exposure_bracket_s[0]
    with Journal(out / JOURNAL) as journal:
        journal.append({"event": "run_start", "at": time.time(), "procedure": "calibrate camera"})
        instruments.gantry.move_to(lamp_ticks)
        instruments.gantry.wait_settled(SETTLE_S)
        for i, (face, angle) in enumerate(plan):
            if i == 0 or plan[i - 1][0] != face:
                instruments.lamp.set(False)
                turn_the_wedge(face)
                instruments.lamp.set(True)
            progress(i, len(plan), f"wedge face {face + 1}, turntable {angle:+.1f}°")
            instruments.turntable.move_to((t.steps_for(angle),))
            (steps,) = instruments.turntable.wait_settled(SETTLE_S)
            frame = exposed(instruments.camera, exposure, BRIGHTEST_PAPER)
            exposure = frame.exposure_s
            for k in range(FRAMES_PER_VIEW):  # the first is the exposure's accepted frame
                frame = frame if k == 0 else instruments.camera.capture()
                fields = PhotographFields(
                    pose=f"v{i:02d}", exposure_index=k, dark=False, exposure_s=frame.exposure_s
                )
                sidecar = {**fields, "turntable_steps": int(steps), "placement": face, "gain_db": frame.gain_db,
                           "bits": frame.bits, "lamp_ticks": list(lamp_ticks)}  # fmt: skip
                stored = store_frame(out, f"v{i:02d}_{k}", frame.pixels, sidecar)
                journal.append(photograph_line(stored, **fields))
        instruments.lamp.set(False)
        journal.append({"event": "run_end", "at": time.time(), "frames_taken": len(plan) * FRAMES_PER_VIEW})


BRIGHTEST_PAPER = ExposureGoal(lambda pixels: np.percentile(pixels, 99.9), FILL, (0.4, 0.9), tries=3)


def load_board_frames(folder: Path) -> list[BoardFrame]:
    """One frame per view from the photographs a capture left in ``folder`` (checked against their journal
    lines), in the order they were taken: the mean of the view's photographs, grey (H, W) float32 — what
    the corner detection looks at, a view's worth of memory whatever the number of photographs."""
    sums: dict[str, np.ndarray] = {}
    counts: dict[str, int] = {}
    where: dict[str, tuple[int, int]] = {}  # per view: the stage's steps and the wedge face
    for s, pixels in journaled_images(folder, "calibrate camera", ("pose", "turntable_steps", "placement")):
        pose, at = s["pose"], (int(s["turntable_steps"]), int(s["placement"]))
        if where.setdefault(pose, at) != at:
            raise InputError(
                f"view {pose}'s photographs were taken at different turntable steps or wedge faces; take the "
                "photographs again",
                path=folder,
            )
        grey = pixels.mean(axis=2, dtype=np.float32) if pixels.ndim == 3 else pixels.astype(np.float32)
        sums[pose] = sums[pose] + grey if pose in sums else grey
        counts[pose] = counts.get(pose, 0) + 1
    if not sums:
        raise InputError("the folder has no calibration images", path=folder)
    return [BoardFrame(sums[p] / counts[p], *where[p]) for p in sums]


def solve_camera(frames: list[BoardFrame], rig: Rig) -> CameraCalibration:
    """Intrinsics, then the joint fit of camera pose, board placements and intrinsics."""
    spec, centre_height = board_spec(rig)
    detections = [detect(f.pixels, spec) for f in frames]
    size = (frames[0].pixels.shape[1], frames[0].pixels.shape[0])
    if size != (rig.camera.width, rig.camera.height):
        raise CalibrationError(
            f"the images are {size[0]}×{size[1]}, the rig file says {rig.camera.width}×{rig.camera.height}: "
            "correct camera.width and camera.height"
        )
    intrinsics = calibrate_intrinsics(detections, spec, size)
    turntable_deg = np.array([rig.turntable_kinematics.degrees_for(f.turntable_steps) for f in frames])
    pose = refine_pose(
        detections,
        turntable_deg,
        spec,
        intrinsics,
        rig.camera.rotation,
        rig.camera.translation,
        centre_height,
        placements=[f.placement for f in frames],
    )
    return CameraCalibration(pose, detections, frames, intrinsics.rms_px)
