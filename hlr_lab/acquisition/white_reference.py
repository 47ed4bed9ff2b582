"""The lamp measured in every pose's own frames, on a white reference lying beside the object during the run
(docs/sessions.md, "The lamp").

A flat Lambertian square of known reflectance R (per channel) lies on the plate beside the object
(``[calibration.white_reference] run_place_m``) and turns with it. A point of it, the lamp at distance d
and at angle θ from its normal, reads DN − black = k · g · t · R · cos θ / d² in a frame of exposure t
and gain g, where k = S · Φ (sensitivity × the lamp's output) is the same everywhere on it. Each pose's
k over the rig file's S · Φ is the lamp's output then, in the fit's terms — measured where the poses
are, without going back to a reference pose, and absolute: whatever state the lamp was in when
``calibrate radiometric`` measured S · Φ, the fit's light is the S · Φ of the pose's own moment.

The pixels that count in a pose are those whose centres see the reference's middle (in the frame,
outside the object's window: the object may hide it; :mod:`hlr_lab.geometry.silhouette`) at a point the lamp
lights (outside the convex hull of the object's shadow on the plate: conservative, as the window is) at
cos θ ≥ :data:`MIN_COS` (grazing light is where a small error of the lamp's place weighs most). They are
read in the frame of the pose's bracket that gathered most light with none of them near clipping
(:func:`brightness`). A pose where fewer than :data:`MIN_SAMPLES` count gives no measurement; ``fit``
interpolates between the poses that do.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from drivers.protocols import RawFrame
from hlr_lab.errors import InputError
from hlr_lab.files import as_pair
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.rig.file import Rig
from hlr_lab.session.events import Axes
from hlr_lab.session.lamp import WELL_EXPOSED

MIDDLE = 0.6  # of the reference's side: what is measured (its edges left out, as calibrate radiometric does)
MIN_COS = 0.3
MIN_SAMPLES = 40  # pixels seen and lit, for a measurement
MIN_SIGNAL = 0.05  # of full scale: the least mean signal measured
SHADOW_MARGIN_M = 0.002  # ~8 pixels' footprint on the plate at the simulated rig's distance


@dataclass(frozen=True)
class Sight:
    """Where the reference is measured in one pose: pixels (M, 2) as (row, column), the points of the
    reference their centres see (M, 3; turntable frame, m) and those points' irradiance factor cos θ / d²
    (M,), m⁻²."""

    rows_cols: np.ndarray
    points: np.ndarray
    irradiance: np.ndarray


@dataclass(frozen=True)
class Reading:
    """The lamp's brightness on the reference (k, DN per s at unit gain, reflectance and cos θ / d²) in
    the frame that showed it best, and when that frame arrived (Unix time)."""

    brightness: float
    at: float


class RunReference:
    """The white reference beside the object, seen by ``camera`` (world frame) around ``vertices`` (V, 3),
    the object in the turntable frame (m); ``window``: turntable angle (°) → (H, W) bool, where the object
    may hide it (:func:`hlr_lab.geometry.silhouette.object_window`, as acquisition computes it). ``place_m``: its
    centre on the plate at turntable 0°; ``size_m`` its side, ``height_m`` its face above the plate,
    ``reflectance`` (3,) per channel."""

    def __init__(
        self,
        camera: Camera,
        vertices: np.ndarray,
        *,
        window: Callable[[float], np.ndarray],
        place_m: tuple[float, float],
        size_m: float,
        height_m: float,
        reflectance: np.ndarray,
    ):
        self.camera, self.height, self.window = camera, height_m, window
        self.reflectance = np.asarray(reflectance, np.float64)
        # the object's convex hull: its shadow holds the object's own (a handful of points)
        v = np.asarray(vertices, np.float64)
        try:
            self.hull = v[ConvexHull(v).vertices]
        except QhullError:  # flat or too few points: all of them
            self.hull = v
        half = MIDDLE * size_m / 2
        self.low = np.array(place_m, np.float64) - half  # the measured middle: a square, (x, y) corners
        self.high = np.array(place_m, np.float64) + half
        corners = [(self.low[0], self.low[1]), (self.high[0], self.low[1]), (self.high[0], self.high[1]),
                   (self.low[0], self.high[1])]  # fmt: skip
        self.corners = np.column_stack([np.array(corners), np.full(4, height_m)])  # (4, 3)

    def sight(self, turntable_deg: float, lamp_m: np.ndarray) -> Sight | None:
        """The pixels measured with the turntable at ``turntable_deg`` and the lamp at ``lamp_m`` (world,
        m): those whose centres see the reference's middle, outside the object's window, lit; each with
        the point its centre sees (so its irradiance is the pixel's own, not a neighbour's: a lamp low
        beside the reference changes cos θ / d² by ~0.15 % a pixel). None when the lamp is not above the
        whole object (its shadow on the plate is then unbounded)."""
        turn = rotation_z(np.radians(turntable_deg))
        lamp = turn[:3, :3].T @ np.asarray(lamp_m, np.float64)  # into the turntable frame
        if lamp[2] <= self.hull[:, 2].max() + 1e-3:
            return None
        seen_from = self.camera.in_frame(turn)
        uv, _ = seen_from.project(self.corners)
        mask = np.zeros((self.camera.height, self.camera.width), np.uint8)
        if np.isfinite(uv).all():
            limit = 16 * max(self.camera.width, self.camera.height)  # far-off corners kept inside int32
            cv2.fillConvexPoly(mask, np.round(np.clip(uv, -limit, limit)).astype(np.int32), 1)
        mask = mask.astype(bool) & ~self.window(turntable_deg)
        rows, cols = np.nonzero(mask)
        if len(rows) == 0:  # hidden, or out of the frame
            return Sight(np.zeros((0, 2), int), np.zeros((0, 3)), np.zeros(0))
        origins, rays = seen_from.pixel_rays(np.column_stack([cols, rows]).astype(np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            along = (self.height - origins[:, 2]) / rays[:, 2]
        points = origins + along[:, None] * rays  # (M, 3): what each pixel's centre sees on the plane
        to_lamp = lamp - points
        d2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
        cos = to_lamp[:, 2] / np.sqrt(d2)  # the reference faces up
        inside = np.all((points[:, :2] >= self.low) & (points[:, :2] <= self.high), axis=1) & (along > 0)
        keep = inside & (cos >= MIN_COS)
        keep[keep] = ~self._shadowed(lamp, points[keep])
        return Sight(np.column_stack([rows, cols])[keep], points[keep], (cos / d2)[keep])

    def _shadowed(self, lamp: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(M,) bool: ``points`` (M, 3) inside the convex hull of the object's shadow on the reference's
        plane, each of its edges moved out by :data:`SHADOW_MARGIN_M` (a pixel whose centre is lit may
        still hold some of the shadow's edge)."""
        if len(points) == 0:
            return np.zeros(0, bool)
        s = (self.height - lamp[2]) / (self.hull[:, 2] - lamp[2])  # > 1: every hull point lies below the lamp
        shadow = lamp[:2] + s[:, None] * (self.hull[:, :2] - lamp[:2])
        try:
            edges = ConvexHull(shadow).equations  # (E, 3): unit outward normal, offset; inside: n · p + d ≤ 0
        except QhullError:  # a degenerate outline (a flat object seen edge-on): count it all as shadow
            return np.ones(len(points), bool)
        return np.all(points[:, :2] @ edges[:, :2].T + edges[:, 2] <= SHADOW_MARGIN_M, axis=1)


def brightness(
    frames: list[RawFrame], sight: Sight, reflectance: np.ndarray, black_level_dn: float
) -> Reading | None:
    """k = S · Φ (DN per s at unit gain, reflectance and irradiance factor): Σ (DN − black) / Σ (t · g · R ·
    cos θ / d²) over every value at ``sight`` in the frame of the pose that gathered most light without any
    of them above :data:`hlr_lab.session.lamp.WELL_EXPOSED`'s top. All its values, none picked by its own
    level: keeping only values above a threshold keeps those that noise pushed up (0.8 % too bright on a
    reference lit to just above it). None with fewer than :data:`MIN_SAMPLES` points, or when that frame's
    mean signal is below :data:`MIN_SIGNAL` of full scale (the black level's error would weigh)."""
    if len(sight.irradiance) < MIN_SAMPLES:
        return None
    top = (1 << frames[0].bits) - 1  # a pose's bracket: one camera, one bit depth
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
    (``turntable_steps``, ``gantry_ticks``) and a pose's lit frames: a :class:`Reading`, or None where the
    reference cannot be measured. ``expected``: the brightness the rig file predicts (``[sensor]
    sensitivity`` × ``[light] power``): a reading over it is the lamp's output in the fit's terms,
    absolute."""

    def __init__(self, rig: Rig, reference: RunReference):
        self.rig, self.reference = rig, reference
        self.expected = rig.file.sensor.sensitivity * rig.file.light.power

    def __call__(self, measured: Axes, frames: list[RawFrame]) -> Reading | None:
        rig = self.rig
        azimuth, elevation = measured["gantry_ticks"]
        sight = self.reference.sight(
            rig.turntable_kinematics.degrees_for(measured["turntable_steps"]),
            rig.gantry.kinematics.light_position((azimuth, elevation)),
        )
        if sight is None:
            return None
        return brightness(frames, sight, self.reference.reflectance, rig.file.sensor.black_level_dn)


def reference_meter(
    rig: Rig, vertices: np.ndarray, window: Callable[[float], np.ndarray]
) -> ReferenceMeter | None:
    """The lamp's meter on the white reference beside the object, or None when the rig file does not put
    one there. ``vertices`` (V, 3): the object in the turntable frame (m); ``window``: as
    :class:`RunReference` takes it."""
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
    reference = RunReference(rig.camera, vertices, window=window, place_m=as_pair(w.run_place_m), size_m=w.size_m,
                             height_m=w.thickness_m, reflectance=np.asarray(w.reflectance))  # fmt: skip
    return ReferenceMeter(rig, reference)
