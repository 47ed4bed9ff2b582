"""``hlr-lab calibrate gantry``: photograph a mirror ball lit by the gantry lamp at many poses, then fit
the gantry's kinematics (:mod:`calibration.mirror_ball`).

The ball (``[calibration.mirror_ball]``: radius, rough place on the plate) is photographed at two
turntable angles half a turn apart. At each: one long exposure with the lamp above the camera's side
shows its outline against the lit plate (→ its centre), then one short exposure per lamp pose shows the
lamp's reflection unclipped (→ a ray toward the lamp). Lamp poses cover the reachable range on the
camera's side of the ball (from behind it, the highlight sits on the ball's edge). Photographs are kept
as a session's frames are, so ``--from`` solves again without the rig. Needs a calibrated camera.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.charuco import CalibrationError
from calibration.exposure import ExposureGoal, exposed
from calibration.images import PhotographFields, journaled_images, photograph_line
from calibration.mirror_ball import (
    GantryFit,
    Highlights,
    ball_centre,
    ball_centres,
    fit_gantry,
    highlight_px,
    lamp_ray,
)
from hlr_lab.errors import InputError
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.rig.file import GANTRY_PARAMETERS, Rig
from hlr_lab.session.frames import store_frame
from hlr_lab.session.journal import JOURNAL, Journal

DEFAULT_POSES = 30
TURNS_DEG = (-10.0, 170.0)  # half a turn apart, the ball to either side, inside any turntable limits
OUTLINE_LAMP_DEG = (-90.0, 45.0)  # gantry azimuth, elevation for the outline frame: the camera's side
SETTLE_S = 60.0
BALL_FIELDS = ("kind", "turntable_steps", "gantry_ticks", "bits")  # what the solve reads of each sidecar


@dataclass(frozen=True)
class BallFrame:
    """A photograph of the mirror ball: its pixels, what it is for (outline or highlight), and where the
    axes stood (steps, ticks)."""

    pixels: np.ndarray
    kind: str  # "outline" or "highlight"
    turntable_steps: int
    gantry_ticks: tuple[int, int]
    bits: int  # the sensor's depth: full scale is 2^bits − 1


def ball_spec(rig: Rig) -> tuple[float, tuple[float, float]]:
    """The mirror ball of the rig file: its radius (m) and where it rests on the plate (x, y in m);
    :class:`InputError` when the rig file has no ``[calibration.mirror_ball]``."""
    ball = rig.file.calibration.mirror_ball
    if ball is None:
        raise InputError(
            "no [calibration.mirror_ball]: give its radius_m and place_m on the plate — see docs/calibration.md",
            path=rig.source,
            field="calibration.mirror_ball",
        )
    x, y = ball.place_m
    return ball.radius_m, (x, y)


def lamp_poses(rig: Rig, count: int = DEFAULT_POSES) -> list[tuple[float, float]]:
    """(azimuth, elevation) degrees: a grid over the reachable elevations and the azimuths within 100° of
    the camera's (seen from the gantry centre), outside the camera's keep-out cone."""
    g = rig.gantry
    to_camera = rig.camera.centre - g.centre
    cam_az = np.degrees(np.arctan2(to_camera[1], to_camera[0]))
    el_lo, el_hi = np.degrees(g.elevation_limits)
    rows = 3
    per_row = max(count // rows, 2)
    poses = []
    for el in np.linspace(max(el_lo, 5.0), min(el_hi, 70.0), rows):
        for az in cam_az + np.linspace(-100.0, 100.0, per_row + 1):
            az = (az + 180.0) % 360.0 - 180.0
            d = g.kinematics.unit_direction(np.radians(az), np.radians(el))
            if d @ (to_camera / np.linalg.norm(to_camera)) > np.cos(g.camera_keepout):
                continue
            if np.degrees(g.azimuth_limits[0]) <= az <= np.degrees(g.azimuth_limits[1]):
                poses.append((float(az), float(el)))
    return poses[:count]


def capture_ball_frames(
    instruments: Instruments,
    rig: Rig,
    out: Path,
    *,
    poses: int = DEFAULT_POSES,
    place_ball: Callable[[float], None] = lambda _deg: None,
    progress: Callable[[int, int, str], None] = lambda i, n, what: None,
) -> None:
    """Photograph the ball at both turntable angles: an outline frame, then a highlight frame per pose."""
    k, t = rig.gantry.kinematics, rig.turntable_kinematics
    plan = lamp_poses(rig, poses)
    total = len(TURNS_DEG) * (len(plan) + 1)
    # each kind's exposure starts where its last frame's ended: from one pose to the next the highlight's
    # peak changes little, so one frame usually suffices, where starting from the bracket's longest (the
    # highlight clips there) took three or four
    start = dict.fromkeys(GOALS, rig.exposure_bracket_s[0])
    with Journal(out / JOURNAL) as journal:
        journal.append({"event": "run_start", "at": time.time(), "procedure": "calibrate gantry"})
        n = 0
        for turn in TURNS_DEG:
            place_ball(turn)
            instruments.turntable.move_to((t.steps_for(turn),))
            (steps,) = instruments.turntable.wait_settled(SETTLE_S)
            for kind, angles in [("outline", OUTLINE_LAMP_DEG)] + [("highlight", p) for p in plan]:
                progress(n, total, f"turntable {turn:g}°, {kind}, lamp at {angles[0]:.0f}°, {angles[1]:.0f}°")
                instruments.gantry.move_to(k.ticks_for(*angles))
                ticks = instruments.gantry.wait_settled(SETTLE_S)
                instruments.lamp.set(True)
                frame = exposed(instruments.camera, start[kind], GOALS[kind])
                start[kind] = frame.exposure_s
                instruments.lamp.set(False)
                fields = PhotographFields(
                    pose=f"g{n:03d}", exposure_index=0, dark=False, exposure_s=frame.exposure_s
                )
                sidecar = {**fields, "kind": kind, "turntable_steps": int(steps), "gantry_ticks": list(ticks),
                           "gain_db": frame.gain_db, "bits": frame.bits}  # fmt: skip
                stored = store_frame(out, f"g{n:03d}", frame.pixels, sidecar)
                journal.append(photograph_line(stored, **fields))
                n += 1
        journal.append({"event": "run_end", "at": time.time(), "frames_taken": n})


GOALS = {  # outline: the plate behind the ball near 70 % of full scale; highlight: its peak unclipped, near 60 %
    "outline": ExposureGoal(
        lambda pixels: np.percentile(pixels, 90), 0.7, (0.49, 0.91), clipped_factor=1 / 16
    ),
    "highlight": ExposureGoal(lambda pixels: pixels.max(), 0.6, (0.42, 0.78), clipped_factor=1 / 16),
}


def load_ball_frames(folder: Path) -> list[BallFrame]:
    """The photographs a capture left in ``folder`` (checked against their journal lines)."""
    return [
        BallFrame(pixels, s["kind"], int(s["turntable_steps"]), tuple(s["gantry_ticks"]), int(s["bits"]))
        for s, pixels in journaled_images(folder, "calibrate gantry", BALL_FIELDS)
    ]


@dataclass(frozen=True)
class GantryCalibration:
    """The gantry procedure's result: the fit, the highlight rays it fitted, the frame of each ray, and how
    many highlights were refused."""

    fit: GantryFit
    highlights: Highlights  # the rays fitted
    frames_used: tuple[int, ...]  # (N,) the frame each ray came from
    refused: int

    @property
    def rays(self) -> int:
        return len(self.frames_used)

    def rig_fields(self, rig: Rig) -> dict[str, dict]:
        """The ``[gantry]`` fields: centre, arm, axis, zero ticks, and the azimuth limits narrowed to what
        one servo turn holds about the new zero."""
        k = self.fit.kinematics
        per_deg = k.ticks_per_rev / 360.0
        lo, hi = rig.file.gantry.azimuth_limits_deg
        z, sense = k.zero_ticks[0], k.directions[0]
        ends = sorted(((0 - z) / (sense * per_deg), (k.ticks_per_rev - z) / (sense * per_deg)))
        limits = [max(lo, np.ceil(ends[0] * 10) / 10), min(hi, np.floor(ends[1] * 10) / 10)]
        return {"gantry": {"centre_m": k.centre, "arm_radius_m": k.arm_radius, "azimuth_axis": list(k.azimuth_axis),
                           "zero_ticks": list(k.zero_ticks), "azimuth_limits_deg": limits}}  # fmt: skip

    def record(self, images: Path) -> dict:
        se = self.fit.standard_errors
        return {"images": str(images.resolve()), "rays": self.rays, "refused_poses": self.refused,
                "worst_miss_mm": round(float(self.fit.miss_mm.max()), 3),
                "ball_place_m": [round(float(v), 6) for v in self.fit.place_xy_m],
                "arm_radius_se_mm": round(1e3 * se["arm_radius_m"], 3),
                "zero_ticks_se": [round(se["zero_az_ticks"], 2), round(se["zero_el_ticks"], 2)],
                # for the fit's systematic uncertainty (docs/fitting.md)
                "covariance_of": list(GANTRY_PARAMETERS),
                "covariance": [[float(f"{v:.4g}") for v in row] for row in self.fit.covariance]}  # fmt: skip


def solve_gantry(frames: list[BallFrame], rig: Rig) -> GantryCalibration:
    """The gantry's kinematics from a capture's frames: each outline frame places the ball (a start for
    the fit, which places it again from the highlights), each highlight frame gives a pixel."""
    radius, place = ball_spec(rig)
    camera, t = rig.camera, rig.turntable_kinematics
    pixels, turns, ticks, places, used, refused = [], [], [], [], [], 0
    centre = None
    for i, f in enumerate(frames):
        a = np.radians(t.degrees_for(f.turntable_steps))
        expected = ball_centres(np.asarray(place), radius, np.array([a]))[0]
        near = camera.project(expected[None])[0][0]
        if f.kind == "outline":
            centre = ball_centre(f.pixels, camera, radius, near)
            places.append(rotation_z(-a)[:2, :2] @ centre[:2])
            continue
        if centre is None:
            raise CalibrationError("a highlight frame before any outline frame: the images are incomplete")
        try:
            pixel = highlight_px(f.pixels, near, (1 << f.bits) - 1)
            lamp_ray(camera, centre, radius, pixel)  # refuses a highlight on the ball's edge
        except CalibrationError:
            refused += 1
            continue
        pixels.append(pixel)
        turns.append(a)
        ticks.append(f.gantry_ticks)
        used.append(i)
    if len(pixels) < 12:
        raise CalibrationError(
            f"only {len(pixels)} usable highlights (need 12): check the ball and the lamp poses"
        )
    highlights = Highlights(np.array(pixels), np.array(turns), np.array(ticks, float))
    fit = fit_gantry(highlights, camera, radius, rig.gantry.kinematics, np.mean(places, axis=0))
    return GantryCalibration(fit, highlights, tuple(used), refused)
