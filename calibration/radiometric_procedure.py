"""``hlr-lab calibrate radiometric``: dark frames, photon transfer and a white reference under the gantry
lamp → ``[sensor]`` black level, read noise, conversion gain and sensitivity (:mod:`calibration.radiometry`).

The white reference (``[calibration.white_reference]``: reflectance per channel, side, place on the
plate) lies flat on the plate, the turntable at 0°. The middle of it (60 % of its side, away from its
edges) is what is measured; each of its pixels gets its point on the reference from the calibrated
camera and, under each lamp position the calibrated gantry gives, its cos θ / d². In order:

1. dark frames: the lamp off, a pair at each exposure of the rig's bracket;
2. (with a warm-up) the lamp kept on above the reference until its output is stable;
3. white: the lamp at ``positions`` places over the reachable range, one frame each near half scale —
   right after the warm-up, as a run that warms up the same way takes its first reference frame — with
   the lamp photographed from above before and after them: S · Φ is the lamp's at the first of those
   (its change in between, interpolated in time, divided out);
4. photon transfer: the lamp above the reference, pairs at ``levels`` exposures from 5 % to 85 % of full
   scale, each pair after a reference frame at one fixed exposure (to see a drifting lamp for what it is).

Needs the camera and gantry calibrated first (the geometry of every pixel comes from them). Photographs
are kept as the other procedures keep theirs, so ``--from`` solves again without the rig.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.charuco import CalibrationError
from calibration.exposure import ExposureGoal, exposed
from calibration.images import PhotographFields, journaled_images, photograph_line
from calibration.radiometry import (
    Dark,
    LampSensitivity,
    PhotonTransfer,
    dark_statistics,
    lamp_sensitivity,
    photon_transfer,
)
from hlr_lab.errors import InputError
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.rig.file import Rig
from hlr_lab.session.frames import store_frame
from hlr_lab.session.journal import JOURNAL, Journal
from hlr_lab.session.lamp import UNWATCHED, LampWatch, WarmUp, short_of_warm, warm_up

PROCEDURE = "calibrate radiometric"
DEFAULT_POSITIONS, DEFAULT_LEVELS = 6, 8
MIDDLE = 0.6  # of the reference's side: what is measured
ABOVE_DEG = (-90.0, 75.0)  # gantry azimuth, elevation of the photon-transfer frames: high, camera's side
SETTLE_S = 60.0
FIELDS = ("kind", "level", "exposure_s", "gain_db", "gantry_ticks", "turntable_steps", "bits", "captured_at")


@dataclass(frozen=True)
class WhiteReference:
    """The white reference of the rig file: reflectance (3,), side and thickness (m), place on the plate (m)."""

    reflectance: np.ndarray  # (3,)
    size_m: float
    place_m: tuple[float, float]
    thickness_m: float
    reflectance_se: float = 0.0  # relative, from its certificate


def white_spec(rig: Rig) -> WhiteReference:
    """The rig file's white reference; :class:`InputError` when it has no ``[calibration.white_reference]``."""
    w = rig.file.calibration.white_reference
    if w is None:
        raise InputError(
            "no [calibration.white_reference]: give its reflectance, size_m and place_m on the plate — see "
            "docs/calibration.md",
            path=rig.source,
            field="calibration.white_reference",
        )
    x, y = w.place_m
    return WhiteReference(np.asarray(w.reflectance, float), w.size_m, (x, y), w.thickness_m, w.reflectance_se)


def reference_pixels(rig: Rig, white: WhiteReference) -> tuple[np.ndarray, np.ndarray]:
    """The middle of the reference as the camera sees it (turntable at its zero): pixel indices (M, 2)
    as (row, column) and their points on the reference (M, 3), world metres. Refuses a reference not
    wholly in view."""
    cam = rig.camera
    half = MIDDLE * white.size_m / 2
    x, y = white.place_m
    corners = np.array(
        [[x - half, y - half], [x + half, y - half], [x + half, y + half], [x - half, y + half]]
    )
    corners3 = np.column_stack([corners, np.full(4, white.thickness_m)])
    uv, _ = cam.project(corners3)
    if (
        not np.isfinite(uv).all()
        or (uv < 0).any()
        or (uv[:, 0] > cam.width - 1).any()
        or (uv[:, 1] > cam.height - 1).any()
    ):
        raise CalibrationError(
            f"the white reference at {list(white.place_m)} m is not wholly in view: put it where the camera "
            "sees it (near the plate's centre) and give its place_m"
        )
    mask = np.zeros((cam.height, cam.width), np.uint8)
    cv2.fillConvexPoly(mask, np.round(uv).astype(np.int32), 1)
    rows, cols = np.nonzero(mask)
    origins, rays = cam.pixel_rays(np.column_stack([cols, rows]).astype(np.float64))
    s = (white.thickness_m - origins[:, 2]) / rays[:, 2]
    return np.column_stack([rows, cols]), origins + s[:, None] * rays


def white_positions(rig: Rig, count: int) -> list[tuple[float, float]]:
    """(azimuth, elevation) degrees for the white frames: three elevations from 40° to the highest
    reachable (≤ 80°) at azimuths spread ±60° about the camera's side (the lamp never between the
    camera and the reference)."""
    g = rig.gantry
    to_camera = rig.camera.centre - g.centre
    cam_az = float(np.degrees(np.arctan2(to_camera[1], to_camera[0])))
    el_hi = min(float(np.degrees(g.elevation_limits[1])), 80.0)
    per_row = max(count // 3, 1)
    positions = []
    for el in np.linspace(40.0, el_hi, 3):
        for az in cam_az + 180.0 + np.linspace(-60.0, 60.0, per_row + 2)[1:-1]:
            positions.append((float((az + 180.0) % 360.0 - 180.0), float(el)))
    return positions[:count]


def capture_radiometric_frames(
    instruments: Instruments,
    rig: Rig,
    out: Path,
    *,
    positions: int = DEFAULT_POSITIONS,
    levels: int = DEFAULT_LEVELS,
    warm: LampWatch = UNWATCHED,
    progress: Callable[[int, int, str], None] = lambda i, n, what: None,
) -> WarmUp | None:
    """Take the three kinds of frames (module docstring) into ``out``; after the dark frames, with
    ``warm.warm_up_s``, keep the lamp on until it is stable (:func:`hlr_lab.session.lamp.warm_up`: S · Φ is
    then the warm lamp's, as a run that warms up the same way will see it). Returns how the warm-up
    ended (None: no warm-up)."""
    white = white_spec(rig)
    rows_cols, _ = reference_pixels(rig, white)
    k, t = rig.gantry.kinematics, rig.turntable_kinematics
    bracket = list(rig.exposure_bracket_s)
    total = 2 * len(bracket) + 3 * levels + positions
    n = 0
    with Journal(out / JOURNAL) as journal:
        journal.append({"event": "run_start", "at": time.time(), "procedure": PROCEDURE})

        def take(kind: str, level: int, exposure_s: float, ticks, steps) -> float:
            nonlocal n
            progress(n, total, f"{kind} frame, {exposure_s * 1e3:.2f} ms")
            instruments.camera.set_exposure(exposure_s)
            frame = instruments.camera.capture()
            fields = PhotographFields(
                pose=f"r{n:03d}", exposure_index=0, dark=kind == "dark", exposure_s=frame.exposure_s
            )
            sidecar = {**fields, "kind": kind, "level": level, "gain_db": frame.gain_db, "bits": frame.bits,
                       "gantry_ticks": list(ticks), "turntable_steps": int(steps), "captured_at": frame.captured_at,
                       "camera": frame.meta}  # fmt: skip
            stored = store_frame(out, f"r{n:03d}", frame.pixels, sidecar)
            journal.append(photograph_line(stored, **fields))
            n += 1
            return float(_mean(frame.pixels, rows_cols))

        instruments.turntable.move_to((t.steps_for(0.0),))
        (steps,) = instruments.turntable.wait_settled(SETTLE_S)
        instruments.gantry.move_to(k.ticks_for(*ABOVE_DEG))
        ticks = instruments.gantry.wait_settled(SETTLE_S)
        instruments.lamp.set(False)
        dark_levels = [
            take("dark", i, exposure, ticks, steps) for i, exposure in enumerate(bracket) for _ in range(2)
        ]
        instruments.lamp.set(True)
        warmed = None
        watch_exposure = _exposure_for(instruments, bracket[0], rows_cols, 0.5)
        if warm.warm_up_s > 0:
            black = float(
                np.mean(dark_levels)
            )  # the dark frames' just taken: the lamp's share alone compared
            warmed = warm_up(lambda: take("warm_up", 0, watch_exposure, ticks, steps) - black, warm, instruments.clock,
                             lambda what: progress(n, total, what))  # fmt: skip
            journal.append(warmed.as_event())
        # the white frames first, right after the warm-up: S · Φ is then the lamp's as a run that warms up
        # the same way finds it at its first reference frame (the photon transfer needs no particular
        # level); the lamp photographed from above before and after them: S · Φ is referred to the first
        above = ticks
        take("lamp", 0, watch_exposure, ticks, steps)
        exposure = bracket[0]
        for i, (az, el) in enumerate(white_positions(rig, positions)):
            instruments.gantry.move_to(k.ticks_for(az, el))
            ticks = instruments.gantry.wait_settled(SETTLE_S)
            exposure = _exposure_for(instruments, exposure, rows_cols, 0.5)
            take("white", i, exposure, ticks, steps)
        instruments.gantry.move_to(above)
        ticks = instruments.gantry.wait_settled(SETTLE_S)
        take("lamp", 1, watch_exposure, ticks, steps)
        longest = _exposure_for(instruments, bracket[0], rows_cols, 0.85)
        reference = 0.3 * longest
        for i, exposure in enumerate(longest * np.geomspace(0.05, 1.0, levels)):
            take("reference", i, reference, ticks, steps)
            for _ in range(2):
                take("flat", i, float(exposure), ticks, steps)
        instruments.lamp.set(False)
        journal.append({"event": "run_end", "at": time.time(), "frames_taken": n})
    return warmed


def _mean(pixels: np.ndarray, rows_cols: np.ndarray) -> float:
    return float(np.asarray(pixels, np.float64)[rows_cols[:, 0], rows_cols[:, 1]].mean())


def _exposure_for(instruments: Instruments, exposure: float, rows_cols: np.ndarray, fill: float) -> float:
    """The exposure that puts the reference's middle near ``fill`` of full scale (a few test frames)."""
    goal = ExposureGoal(
        lambda pixels: _mean(pixels, rows_cols), fill, (0.9 * fill, 1.1 * fill), clipped_at=0.95
    )
    return exposed(instruments.camera, exposure, goal).exposure_s


@dataclass(frozen=True)
class RadiometricFrame:
    """A photograph of the radiometric procedure: its pixels, its kind and level, its exposure (s) and
    gain (dB), where the lamp stood (ticks), the sensor's depth (bits)."""

    pixels: np.ndarray
    kind: str  # "dark", "reference", "flat" or "white"
    level: int  # which exposure (dark: of the bracket; reference and flat: of the transfer; white: position)
    exposure_s: float
    gain_db: float
    gantry_ticks: tuple[int, int]
    bits: int
    captured_at: float  # Unix time


def load_radiometric_frames(folder: Path) -> list[RadiometricFrame]:
    """The photographs a capture left in ``folder`` (checked against their journal lines)."""
    frames = [
        RadiometricFrame(
            pixels,
            s["kind"],
            int(s["level"]),
            float(s["exposure_s"]),
            float(s["gain_db"]),
            tuple(s["gantry_ticks"]),
            int(s["bits"]),
            float(s["captured_at"]),
        )
        for s, pixels in journaled_images(folder, PROCEDURE, FIELDS)
    ]
    if not frames:
        raise InputError("the folder has no calibration images", path=folder)
    return frames


@dataclass(frozen=True)
class RadiometricCalibration:
    """The radiometric procedure's result: dark statistics, photon transfer, the lamp's sensitivity × power,
    and the lamp's drift over the white frames."""

    dark: Dark
    transfer: PhotonTransfer
    lamp: LampSensitivity
    power: float  # the rig file's [light] power, kept: sensitivity = S·Φ / power
    lamp_drift: float = 0.0  # the lamp's change over the white frames (divided out), a fraction
    reflectance_se: float = 0.0  # the white reference's, relative (its certificate's)
    # the lamp's change over the warm-up (its last reading over its first − 1) and how far short of warm it
    # still was (hlr_lab.session.lamp.short_of_warm); None without a warm-up. A run on this rig warms its
    # lamp up and watches it when the two together are large (hlr_lab.session.lamp.lamp_watch_for), and fit
    # states the rest (docs/sessions.md, "The lamp")
    lamp_warm_up: tuple[float, float] | None = None

    @property
    def sensitivity(self) -> float:
        """The rig file's scalar sensitivity: S · Φ over the channels, divided by the file's power."""
        return float(np.mean(self.lamp.sensitivity_times_power) / self.power)

    def rig_fields(self) -> dict[str, dict]:
        return {"sensor": {"sensitivity": self.sensitivity, "black_level_dn": float(np.mean(self.dark.black_level_dn)),
                           "read_noise_dn": self.dark.read_noise_dn,
                           "conversion_gain_dn_per_e": self.transfer.conversion_gain_dn_per_e}}  # fmt: skip

    def record(self, images: Path) -> dict:
        sp = self.lamp.sensitivity_times_power
        return {"images": str(images.resolve()),
                "black_level_per_channel_dn": [round(float(v), 3) for v in self.dark.black_level_dn],
                "sensitivity_times_power_per_channel": [round(float(v), 3) for v in sp],
                "channel_spread": round(float(sp.max() / sp.min() - 1), 5),
                "worst_nonlinearity": round(self.transfer.worst_nonlinearity, 5),
                "inverse_square_residual": round(self.lamp.inverse_square_residual, 5),
                "lamp_drift_over_white_frames": round(self.lamp_drift, 5),
                **({} if self.lamp_warm_up is None else {"lamp_warm_up_change": round(self.lamp_warm_up[0], 5),
                                                          "lamp_short_of_warm": round(self.lamp_warm_up[1], 5)}),
                "follows_inverse_square": self.lamp.follows_inverse_square,
                # what the fit's systematic uncertainty takes (docs/fitting.md, "Systematic uncertainty")
                "sensitivity_se_rel": float(f"{self.lamp.relative_se(self.reflectance_se):.3g}"),
                "black_level_se_dn": float(f"{self.dark.black_level_se_dn:.3g}")}  # fmt: skip


def solve_radiometric(frames: list[RadiometricFrame], rig: Rig) -> RadiometricCalibration:
    """Dark statistics, photon transfer and S · Φ from a capture's frames (module docstring)."""
    white = white_spec(rig)
    rows_cols, points = reference_pixels(rig, white)

    def in_ref(f: RadiometricFrame) -> np.ndarray:
        """(M, C): the reference's middle in a frame."""
        return np.asarray(f.pixels)[rows_cols[:, 0], rows_cols[:, 1]].reshape(len(rows_cols), -1)

    def of(kind: str) -> list[RadiometricFrame]:
        return [f for f in frames if f.kind == kind]

    darks = of("dark")
    dark = dark_statistics([(a.pixels, b.pixels) for a, b in _pairs(darks)])
    top = (1 << frames[0].bits) - 1
    refs = {f.level: f for f in of("reference")}
    flats = _pairs(of("flat"))
    transfer = photon_transfer(
        [(in_ref(a), in_ref(b)) for a, b in flats],
        np.array([a.exposure_s for a, _ in flats]),
        np.array([in_ref(refs[a.level]).mean() for a, _ in flats]),
        dark,
        top,
    )
    whites = of("white")
    if len(whites) < 3:
        raise CalibrationError(
            f"only {len(whites)} white-reference frames (need 3): take the photographs again"
        )
    k = rig.gantry.kinematics
    white_values = [in_ref(f) for f in whites]  # (M, C) each
    geometry = []
    for f, values in zip(whites, white_values, strict=True):
        if values.max() >= top:
            raise CalibrationError(
                "the white reference is saturated in a frame: use a shorter exposure or less light"
            )
        if values.mean() - dark.black_level_dn.mean() < 20 * max(dark.read_noise_dn, 0.5):
            raise CalibrationError(
                "a lit frame of the white reference is as dark as the dark frames: the lamp did not light it "
                "(check the lamp, the room light and the reference's place)"
            )
        to_lamp = k.light_position(f.gantry_ticks) - points
        d2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
        geometry.append((to_lamp[:, 2] / np.sqrt(d2)) / d2)  # cos θ / d²: the reference faces +z
    # the lamp's output during each white frame relative to before the first (from the frames from above)
    watched = sorted(of("lamp"), key=lambda f: f.captured_at)
    relative, output = np.ones(1), 1.0  # a capture without them (none was taken before): a steady lamp
    if watched:
        signal = np.array([in_ref(f).mean() for f in watched]) - dark.black_level_dn.mean()
        relative = signal / signal[0]
        output = np.interp([f.captured_at for f in whites], [f.captured_at for f in watched], relative)
    sensitivity = lamp_sensitivity(
        white_values,
        np.array([f.exposure_s for f in whites]) * output,  # DN ∝ t · Φ(t): the lamp's change as exposure
        np.array([f.gain_db for f in whites]),
        geometry,
        white.reflectance[: white_values[0].shape[1]],
        dark,
    )
    drift = float(relative[-1] - 1)
    return RadiometricCalibration(dark, transfer, sensitivity, rig.file.light.power, drift, white.reflectance_se,
                                  _warm_up_change(of("warm_up"), in_ref, dark))  # fmt: skip


def _warm_up_change(
    warming: list[RadiometricFrame], in_ref: Callable[[RadiometricFrame], np.ndarray], dark: Dark
) -> tuple[float, float] | None:
    """The lamp's change over the warm-up (its last reading over its first − 1) and how far short of warm
    it still was (:func:`~hlr_lab.session.lamp.short_of_warm`), each reading the reference's mean signal
    above the black level (one exposure, one warm-up step apart); None without a warm-up."""
    if len(warming) < 2:
        return None
    ordered = sorted(warming, key=lambda f: f.captured_at)
    levels = np.array([in_ref(f).mean() for f in ordered]) - dark.black_level_dn.mean()
    if levels[0] <= 0:
        return None
    return float(levels[-1] / levels[0] - 1), short_of_warm(levels)


def _pairs(frames: list[RadiometricFrame]) -> list[tuple[RadiometricFrame, RadiometricFrame]]:
    """Consecutive frames of one level, two by two."""
    pairs = []
    for level in sorted({f.level for f in frames}):
        same = [f for f in frames if f.level == level]
        pairs += [(same[i], same[i + 1]) for i in range(0, len(same) - 1, 2)]
    return pairs
