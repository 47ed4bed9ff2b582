"""The lamp measured in every pose's own frames, on a white reference lying beside the object during the run
(docs/sessions.md, "The lamp").

A flat Lambertian square of known reflectance R (per channel) lies on the plate beside the object
(``[calibration.white_reference] run_place_m``) and turns with it. A point of it, the lamp at distance d
and at angle θ from its normal, reads DN − black = k · g · t · R · cos θ / d² in a frame of exposure t
and gain g, where k = S · Φ (sensitivity × the lamp's output) is the same everywhere on it. Each pose's
k over the rig file's S · Φ is the lamp's output then, in the fit's terms — measured where the poses
are, without going back to a reference pose, and absolute: whatever state the lamp was in when
``calibrate radiometric`` measured S · Φ, the fit's light is the S · Φ of the pose's own moment.

The points that count in a pose are those the camera sees (in the frame, outside the object's window:
the object may hide them; :mod:`hlr_lab.silhouette`), that the lamp lights (outside the convex hull of
the object's shadow on the plate: conservative, as the window is), at cos θ ≥ :data:`MIN_COS` (grazing
light is where a small error of the lamp's place weighs most). They are read in the frame of the pose's
bracket that gathered most light with none of them near clipping (:func:`brightness`). A pose where
fewer than :data:`MIN_SAMPLES` count gives no measurement; ``fit`` interpolates between the poses that
do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, Delaunay, QhullError

from hlr_lab.camera import Camera
from hlr_lab.errors import InputError
from hlr_lab.lamp_watch import WELL_EXPOSED
from hlr_lab.rig import Rig
from hlr_lab.silhouette import object_window
from hlr_lab.sphere import rotation_z

MIDDLE = 0.6  # of the reference's side: what is measured (its edges left out, as calibrate radiometric does)
SAMPLES = 24  # points across the measured middle, each way
MIN_COS = 0.3
MIN_SAMPLES = 40  # points seen and lit, for a measurement
MIN_SIGNAL = 0.05  # of full scale: the least mean signal measured
SHADOW_MARGIN_M = 0.002  # ~8 pixels' footprint on the plate at the simulated rig's distance
# an octagon about the circle of that radius: added to the shadow's outline, it grows it by at least that much
_OCTAGON = np.arange(8) * np.pi / 4
_AROUND = SHADOW_MARGIN_M / np.cos(np.pi / 8) * np.column_stack([np.cos(_OCTAGON), np.sin(_OCTAGON)])


@dataclass(frozen=True)
class Sight:
    """Where the reference is measured in one pose: pixels (M, 2) as (row, column) and their points'
    irradiance factor cos θ / d² (M,), m⁻²."""

    rows_cols: np.ndarray
    irradiance: np.ndarray


@dataclass(frozen=True)
class Exposure:
    """One lit frame of a pose: its pixels (H, W[, C]) in DN, exposure (s), analogue gain (dB) and when it
    arrived (Unix time)."""

    pixels: np.ndarray
    exposure_s: float
    gain_db: float
    captured_at: float


@dataclass(frozen=True)
class Reading:
    """The lamp's brightness on the reference (k, DN per s at unit gain, reflectance and cos θ / d²) in
    the frame that showed it best, and when that frame arrived (Unix time)."""

    brightness: float
    at: float


class RunReference:
    """The white reference beside the object, seen by ``camera`` (world frame) around ``vertices`` (V, 3),
    the object in the turntable frame (m). ``place_m``: its centre on the plate at turntable 0°; ``size_m``
    its side, ``height_m`` its face above the plate, ``reflectance`` (3,) per channel."""

    def __init__(
        self,
        camera: Camera,
        vertices: np.ndarray,
        *,
        place_m: tuple[float, float],
        size_m: float,
        height_m: float,
        reflectance: np.ndarray,
    ):
        self.camera = camera
        self.reflectance = np.asarray(reflectance, np.float64)
        # the object's convex hull: its shadow and its window hold the object's own (a handful of points)
        v = np.asarray(vertices, np.float64)
        try:
            self.hull = v[ConvexHull(v).vertices]
        except QhullError:  # flat or too few points: all of them
            self.hull = v
        half = MIDDLE * size_m / 2
        u = np.linspace(-half, half, SAMPLES)
        gx, gy = np.meshgrid(place_m[0] + u, place_m[1] + u)
        self.points = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, height_m)])  # (N, 3)

    def sight(self, turntable_deg: float, lamp_m: np.ndarray) -> Sight | None:
        """The points measured with the turntable at ``turntable_deg`` and the lamp at ``lamp_m`` (world,
        m); None when the lamp is not above the whole object (its shadow on the plate is then unbounded)."""
        turn = rotation_z(np.radians(turntable_deg))
        lamp = turn[:3, :3].T @ np.asarray(lamp_m, np.float64)  # into the turntable frame
        if lamp[2] <= self.hull[:, 2].max() + 1e-3:
            return None
        to_lamp = lamp - self.points
        d2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
        cos = to_lamp[:, 2] / np.sqrt(d2)  # the reference faces up
        keep = (cos >= MIN_COS) & ~self._shadowed(lamp)
        seen_from = self.camera.in_frame(turn)
        uv, _ = seen_from.project(self.points)
        inside = np.isfinite(uv).all(axis=1)
        col, row = np.full(len(uv), -1), np.full(len(uv), -1)
        col[inside], row[inside] = np.round(uv[inside]).astype(int).T
        keep &= (col >= 0) & (col < self.camera.width) & (row >= 0) & (row < self.camera.height)
        where = np.flatnonzero(keep)
        keep[where] = ~object_window(self.camera, self.hull, turntable_deg)[row[where], col[where]]
        return Sight(np.column_stack([row[keep], col[keep]]), (cos / d2)[keep])

    def _shadowed(self, lamp: np.ndarray) -> np.ndarray:
        """(N,) bool: points inside the convex hull of the object's shadow on the reference's plane, grown
        by :data:`SHADOW_MARGIN_M` (a pixel whose centre is lit may still hold some of the shadow's edge)."""
        h = self.points[0, 2]
        s = (h - lamp[2]) / (self.hull[:, 2] - lamp[2])  # > 1: every hull point lies below the lamp
        shadow = lamp[:2] + s[:, None] * (self.hull[:, :2] - lamp[:2])
        shadow = (shadow[:, None, :] + _AROUND[None, :, :]).reshape(-1, 2)  # (8 H, 2)
        try:
            return Delaunay(shadow).find_simplex(self.points[:, :2]) >= 0
        except QhullError:  # a degenerate outline (a flat object seen edge-on): count it all as shadow
            return np.ones(len(self.points), bool)


def brightness(
    frames: list[Exposure], sight: Sight, reflectance: np.ndarray, black_level_dn: float, bits: int
) -> Reading | None:
    """k = S · Φ (DN per s at unit gain, reflectance and irradiance factor): Σ (DN − black) / Σ (t · g · R ·
    cos θ / d²) over every value at ``sight`` in the frame of the pose that gathered most light without any
    of them above :data:`hlr_lab.lamp_watch.WELL_EXPOSED`'s top. All its values, none picked by its own
    level: keeping only values above a threshold keeps those that noise pushed up (0.8 % too bright on a
    reference lit to just above it). None with fewer than :data:`MIN_SAMPLES` points, or when that frame's
    mean signal is below :data:`MIN_SIGNAL` of full scale (the black level's error would weigh)."""
    if len(sight.irradiance) < MIN_SAMPLES:
        return None
    top = (1 << bits) - 1
    ceiling = black_level_dn + WELL_EXPOSED[1] * (top - black_level_dn)
    r, c = sight.rows_cols[:, 0], sight.rows_cols[:, 1]
    best = None
    for frame in frames:
        values = np.asarray(frame.pixels, np.float64)[r, c].reshape(len(r), -1)  # (M, C)
        light = frame.exposure_s * 10 ** (frame.gain_db / 20)
        if values.max() <= ceiling and (best is None or light > best[2]):
            best = (frame, values, light)
    if best is None:
        return None
    frame, values, light = best
    signal = values - black_level_dn
    if signal.mean() < MIN_SIGNAL * (top - black_level_dn):
        return None
    channels = values.shape[1]
    rho = reflectance[:channels] if channels == len(reflectance) else np.full(channels, reflectance.mean())
    scale = light * sight.irradiance[:, None] * rho[None, :]  # (M, C)
    return Reading(float(signal.sum() / scale.sum()), frame.captured_at)


class ReferenceMeter:
    """What acquisition measures the lamp with when ``rig`` puts its white reference beside the object
    during runs (``run_place_m``; :func:`reference_meter`). Called with the axes' measured positions
    (``turntable_steps``, ``gantry_ticks``) and a pose's lit frames (each with ``pixels``, ``exposure_s``,
    ``gain_db``, ``bits``, ``captured_at``): a :class:`Reading`, or None where the reference cannot be
    measured. ``expected``: the brightness the rig file predicts (``[sensor] sensitivity`` × ``[light]
    power``): a reading over it is the lamp's output in the fit's terms, absolute."""

    def __init__(self, rig: Rig, reference: RunReference):
        self.rig, self.reference = rig, reference
        self.expected = rig.file.sensor.sensitivity * rig.file.light.power

    def __call__(self, measured: dict, frames: list) -> Reading | None:
        rig = self.rig
        sight = self.reference.sight(
            rig.turntable_kinematics.degrees_for(measured["turntable_steps"]),
            rig.gantry.kinematics.light_position(tuple(measured["gantry_ticks"])),
        )
        if sight is None:
            return None
        exposures = [Exposure(f.pixels, f.exposure_s, f.gain_db, f.captured_at) for f in frames]
        black = rig.file.sensor.black_level_dn
        return brightness(exposures, sight, self.reference.reflectance, black, frames[0].bits)


def reference_meter(rig: Rig, vertices: np.ndarray) -> ReferenceMeter | None:
    """The lamp's meter on the white reference beside the object, or None when the rig file does not put
    one there. ``vertices`` (V, 3): the object in the turntable frame (m)."""
    w = rig.file.calibration.white_reference
    if w is None or w.run_place_m is None:
        return None
    if rig.file.light.type != "point":
        raise InputError(
            "the white reference beside the object measures a point lamp (its light falls off as 1/d²); with "
            f"a {rig.file.light.type} light remove run_place_m and watch the lamp with --lamp-every",
            path=rig.source,
            field="calibration.white_reference.run_place_m",
        )
    reference = RunReference(rig.camera, vertices, place_m=tuple(w.run_place_m), size_m=w.size_m,
                             height_m=w.thickness_m, reflectance=np.asarray(w.reflectance))  # fmt: skip
    return ReferenceMeter(rig, reference)
