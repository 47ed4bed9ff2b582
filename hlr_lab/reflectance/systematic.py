"""What the rig file says of its own uncertainty, as independent one-σ moves of the rig the fit believes
(docs/fitting.md, "Systematic uncertainty").

Every α, β, distance and radiance of the fit follows from the rig file, which calibration measured with
standard errors (the ``[calibration.*]`` records). Each :class:`RigTerm` is one independent, one-σ move
of that belief: the fit's parameters move with it to first order, and the terms' moves add in
quadrature into the systematic uncertainty of each parameter.

- The camera: the calibration's covariance over its pose and intrinsics (``[calibration.camera]
  covariance``), taken apart into the modes in which it moves the object's image and the camera's
  centre (a singular value decomposition; the modes that together carry 99 % of that movement are kept:
  each costs a ray cast of the samples). The principal point and the camera's pose trade off in a
  turntable calibration (either shifts the image), so their standard errors alone would overstate
  what the pair leaves uncertain; the covariance does not.
- The gantry: the mirror-ball fit's covariance over its centre, arm radius, azimuth axis and zero ticks
  (``[calibration.gantry] covariance``), every mode (no ray cast: the lamp alone moves).
- The sensor: sensitivity × lamp power and the black level (``[calibration.radiometric]``
  ``sensitivity_se_rel``, ``black_level_se_dn``).
- The lamp, where the run did not watch it: what the radiometric calibration saw it change while warming
  up, or drift once warm (:func:`lamp_terms`).
- The object's placement, when ``hlr-lab register`` measured it (the plan's ``object.placement``): its
  shift's and its turn's standard errors, six independent terms (each a ray cast of the samples). A
  placement only assumed has no standard error to give: the record says so (:func:`placement_note`).

A calibration without a covariance (written by an older hlr-lab) gives its standard errors as
independent terms. A camera or gantry never calibrated is no small move of a good belief: its drawing
is off by pixels and millimetres, beyond where a first-order move means anything (an 8 px image shift
moves a sharp lobe by more than its width). Its term is then the stated, conservative fraction of each
parameter that such a drawing was measured to cost (:data:`UNCALIBRATED`, docs/calibration.md), and says
so. The sensor's response is linear in its two quantities: uncalibrated, their defaults are moved.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from hlr_lab.formats.plan import PlacementRecord
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.rig.file import CAMERA_PARAMETERS, GANTRY_PARAMETERS, Rig
from hlr_lab.rig.kinematics import GantryKinematics
from hlr_lab.session.lamp import LampFigures

# a rig never calibrated: what the drawing of builtin:bench-offsets cost the fit of builtin:pebble
# (docs/calibration.md, "End to end": worst region 19 % in Rd, 41 % in Rs and n with neither camera nor
# gantry calibrated, 6.9 %, 12 %, 6.2 % with the camera alone), as a fraction of each parameter — the
# camera's share the quadrature difference; and one σ of the sensor's two quantities
UNCALIBRATED = {"camera": {"rd": 0.18, "rs": 0.39, "n": 0.40}, "gantry": {"rd": 0.07, "rs": 0.12, "n": 0.06}}
UNCALIBRATED_SENSITIVITY_REL = 0.10
UNCALIBRATED_BLACK_LEVEL_DN = 2.0
CAMERA_MODES_KEPT = 0.99  # of the object's image movement
_MAX_CAMERA_MODES = 6
_IMAGE_POINTS = 300  # of the object, seen at four turntable angles, to measure the image's movement

Source = Literal["covariance", "standard errors", "uncalibrated", "lamp record"]


@dataclass(frozen=True, eq=False)
class RigTerm:
    """One independent one-σ move of the rig the fit believes: exactly one of ``camera`` (the camera
    moved), ``kinematics`` (the gantry's), ``black_level_dn`` (the black level moved to this),
    ``sensitivity_factor`` (sensitivity × power times this), ``object_moved`` (4, 4: the object lying so
    moved, a rigid move of the turntable frame) or ``fraction`` (a device never calibrated: this share of
    each parameter, keyed "rd", "rs", "n") is set, with ``device`` what it belongs to.

    ``name`` is what it moves, ``size`` the move in words (for the record), ``source`` where its σ came
    from: the calibration's covariance, its standard errors, or the uncalibrated default."""

    name: str
    size: str
    source: Source
    camera: Camera | None = None
    kinematics: GantryKinematics | None = None
    black_level_dn: float | None = None
    sensitivity_factor: float | None = None
    object_moved: np.ndarray | None = None
    fraction: dict[str, float] | None = None
    device: Literal["camera", "gantry", "sensor", "placement"] = "sensor"

    def as_record(self) -> dict:
        return {"name": self.name, "size": self.size, "source": self.source}


def rig_terms(rig: Rig, object_points: np.ndarray) -> list[RigTerm]:
    """The rig's uncertainty as independent one-σ terms (the module's docstring).

    object_points: (M, 3) points of the object in the turntable frame (m; its vertices), where the
    camera's modes are measured.
    """
    return [*camera_terms(rig, object_points), *gantry_terms(rig), *sensor_terms(rig)]


def placement_terms(record: PlacementRecord | None, centre: np.ndarray) -> list[RigTerm]:
    """The measured placement's standard errors as six independent terms: a shift along each axis of the
    turntable frame and a turn about each through the object's ``centre`` (3,; turntable frame, m), as
    ``hlr-lab register`` states them (docs/placement.md). None for a placement assumed or without them."""
    if (
        record is None
        or record.status == "assumed"
        or record.se_shift_mm is None
        or record.se_rotation_deg is None
    ):
        return []
    terms = []
    for axis, name in enumerate("xyz"):
        move = np.eye(4)
        move[axis, 3] = record.se_shift_mm[axis] / 1000
        terms.append(RigTerm(f"placement shift {name}", f"{record.se_shift_mm[axis]:.3g} mm", "standard errors",
                             object_moved=move, device="placement"))  # fmt: skip
    for axis, name in enumerate("xyz"):
        move = np.eye(4)
        move[:3, :3] = Rotation.from_rotvec(
            np.radians(record.se_rotation_deg[axis]) * np.eye(3)[axis]
        ).as_matrix()
        move[:3, 3] = centre - move[:3, :3] @ centre
        terms.append(RigTerm(f"placement turn about {name}", f"{record.se_rotation_deg[axis]:.3g}°", "standard errors",
                             object_moved=move, device="placement"))  # fmt: skip
    return terms


def placement_note(record: PlacementRecord | None) -> str | None:
    """What the systematic part leaves out of the placement, or None when it is in (measured)."""
    if record is not None and record.status != "assumed" and record.se_shift_mm is not None:
        return None
    return ("the object's placement was assumed, not measured: how far it lies from the plan's is not in *_sys "
            "(hlr-lab register measures it: docs/placement.md)")  # fmt: skip


def camera_terms(rig: Rig, object_points: np.ndarray) -> list[RigTerm]:
    """The camera's modes (module docstring): each a one-σ move of its pose and intrinsics together; or,
    never calibrated, the stated fraction."""
    record = rig.file.calibration.camera
    covariance = _camera_covariance({} if record is None else (record.model_extra or {}))
    if covariance is None:
        return [_uncalibrated("camera")]
    matrix, source = covariance
    camera = rig.camera
    factor = _square_root(matrix)  # (14, K): θ = factor · z, z ~ N(0, I)
    if factor.shape[1] == 0:
        return []
    rng = np.random.default_rng(0)
    chosen = rng.choice(len(object_points), min(_IMAGE_POINTS, len(object_points)), replace=False)
    seen = np.concatenate(
        [object_points[chosen] @ rotation_z(a)[:3, :3].T for a in np.radians([0, 90, 180, 270])]
    )
    distance = float(np.linalg.norm(camera.centre - seen.mean(axis=0)))
    focal = float(camera.matrix[0, 0])

    def image(theta: np.ndarray) -> np.ndarray:  # the object's image (px) and the camera's centre (as px)
        moved = moved_camera(camera, theta)
        return np.concatenate(
            [moved.project(seen)[0].ravel(), (moved.centre - camera.centre) * focal / distance]
        )

    # the image's response to each column of the factor (px per σ), by central differences
    response = np.column_stack([(image(1e-3 * f) - image(-1e-3 * f)) / 2e-3 for f in factor.T])
    response = response[np.all(np.isfinite(response), axis=1)]
    _, sizes, modes = np.linalg.svd(response, full_matrices=False)
    share = np.cumsum(sizes**2) / max(float(np.sum(sizes**2)), 1e-300)
    kept = min(int(np.searchsorted(share, CAMERA_MODES_KEPT)) + 1, _MAX_CAMERA_MODES)
    terms = []
    for k in range(kept):
        if sizes[k] <= 0:
            break
        moves = (response @ modes[k])[:-3]  # the image's part
        size = f"moves the object's image {np.sqrt(np.mean(moves**2)):.3g} px rms"
        terms.append(RigTerm(f"camera mode {k + 1}", size, source, camera=moved_camera(camera, factor @ modes[k]),
                             device="camera"))  # fmt: skip
    return terms


def moved_camera(camera: Camera, theta: np.ndarray) -> Camera:
    """``camera`` moved by ``theta`` (14,), in :data:`CAMERA_PARAMETERS`' order and units."""
    turn = cv2.Rodrigues(np.asarray(theta[:3], np.float64))[0]
    k = camera.matrix.copy()
    k[[0, 1, 0, 1], [0, 1, 2, 2]] += theta[6:10]  # fx, fy, cx, cy
    distortion = np.zeros(5)
    d = np.asarray(camera.distortion, np.float64).ravel()
    distortion[: len(d)] = d
    distortion[:4] += theta[10:14]
    return Camera(k, distortion, turn @ camera.rotation, camera.translation + theta[3:6], camera.width,
                  camera.height)  # fmt: skip


def gantry_terms(rig: Rig) -> list[RigTerm]:
    """The gantry's modes: each a one-σ move of its centre, arm, axis and zero ticks together; or, never
    calibrated, the stated fraction."""
    record = rig.file.calibration.gantry
    covariance = _gantry_covariance({} if record is None else (record.model_extra or {}))
    if covariance is None:
        return [_uncalibrated("gantry")]
    matrix, source = covariance
    k = rig.gantry.kinematics
    axis = np.asarray(k.azimuth_axis, float)
    axis = axis / np.linalg.norm(axis)
    terms = []
    for i, x in enumerate(_square_root(matrix).T):
        moved = replace(
            k,
            centre=np.asarray(k.centre, float) + x[0:3],
            arm_radius=k.arm_radius + float(x[3]),
            azimuth_axis=(axis[0] / axis[2] + x[4], axis[1] / axis[2] + x[5], 1.0),
            zero_ticks=(k.zero_ticks[0] + float(x[6]), k.zero_ticks[1] + float(x[7])),
        )
        shift = _lamp_shift_mm(k, moved)
        terms.append(RigTerm(f"gantry mode {i + 1}", f"moves the lamp {shift:.3g} mm (worst pose)", source,
                             kinematics=moved, device="gantry"))  # fmt: skip
    return terms


def sensor_terms(rig: Rig) -> list[RigTerm]:
    """Sensitivity × lamp power and the black level, one term each."""
    record = rig.file.calibration.radiometric
    extra = {} if record is None else (record.model_extra or {})
    relative, black = extra.get("sensitivity_se_rel"), extra.get("black_level_se_dn")
    source: Source = "standard errors"
    if not (
        isinstance(relative, int | float)
        and _number(relative)
        and isinstance(black, int | float)
        and _number(black)
    ):
        relative, black, source = UNCALIBRATED_SENSITIVITY_REL, UNCALIBRATED_BLACK_LEVEL_DN, "uncalibrated"
    sensor = rig.file.sensor
    return [
        RigTerm("sensitivity × power", f"{100 * relative:.3g} %", source, sensitivity_factor=1.0 + relative),
        RigTerm("black level", f"{black:.3g} DN", source, black_level_dn=sensor.black_level_dn + black),
    ]


def lamp_terms(rig: Rig, *, watched: bool, warmed: bool, absolute: bool) -> list[RigTerm]:
    """The lamp's level in the run against the one the radiometric calibration measured sensitivity ×
    power at (the lamp warmed up, still :attr:`~hlr_lab.session.lamp.LampFigures.short_of_warm` below
    warm), one term: none where the run measured it ``absolute`` (a white reference beside the object);
    else the span it may lie in, as one σ (the span is an estimate good to a factor of two:
    :func:`~hlr_lab.session.lamp.short_of_warm`) — from short of warm to warm for a run ``warmed`` up (it
    may have been on for hours), from cold (the calibration's warm-up change below) to warm for one not;
    a ``watched`` run's reference frames measure the lamp relative to its first, not that — and, for a run
    not watched, at least the warm lamp's move over the calibration's white frames. None where the record
    says nothing of the lamp (docs/fitting.md, "Systematic uncertainty")."""
    seen = LampFigures.of(rig)
    if absolute:
        return []
    span = abs(seen.short_of_warm) + (0.0 if warmed else abs(seen.warm_up_change))
    share = max(span, 0.0 if watched else abs(seen.drift))
    if not share:
        return []
    state = "watched" if watched else "warmed up, not watched" if warmed else "neither warmed up nor watched"
    return [
        RigTerm(f"lamp level ({state})", f"{100 * share:.3g} %", "lamp record", sensitivity_factor=1 + share)
    ]


def _uncalibrated(device: Literal["camera", "gantry"]) -> RigTerm:
    f = UNCALIBRATED[device]
    size = f"Rd {100 * f['rd']:g} %, Rs {100 * f['rs']:g} %, n {100 * f['n']:g} % of each value"
    return RigTerm(f"{device} (not calibrated)", size, "uncalibrated", fraction=dict(f), device=device)


# what an older record (no covariance) gives instead: field → the parameters its standard errors are
# of, and the factor to their units
_CAMERA_SES = {"focal_se_px": (("fx_px", "fy_px"), 1.0), "principal_point_se_px": (("cx_px", "cy_px"), 1.0)}
_GANTRY_SES = {
    "arm_radius_se_mm": (("arm_radius_m",), 1e-3),
    "zero_ticks_se": (("zero_az_ticks", "zero_el_ticks"), 1.0),
}


def _camera_covariance(record: dict) -> tuple[np.ndarray, Source] | None:
    """The camera's covariance (14, 14) from its calibration record, and whence; None: no record."""
    return _covariance(record, CAMERA_PARAMETERS, _CAMERA_SES)


def _gantry_covariance(record: dict) -> tuple[np.ndarray, Source] | None:
    """The gantry's covariance (8, 8) from its calibration record, and whence; None: no record."""
    return _covariance(record, GANTRY_PARAMETERS, _GANTRY_SES)


def _covariance(
    record: dict, names: tuple[str, ...], standard_errors: dict[str, tuple[tuple[str, ...], float]]
) -> tuple[np.ndarray, Source] | None:
    """The record's covariance over ``names``; else a diagonal one from its ``standard_errors`` fields
    (each a number or a list, one per parameter it names); None when it has neither."""
    given = _named_covariance(record, names)
    if given is not None:
        return given, "covariance"
    se = np.zeros(len(names))
    for key, (params, factor) in standard_errors.items():
        value = record.get(key)
        values = value if isinstance(value, list) else [value]
        if len(values) != len(params) or not all(_number(v) for v in values):
            return None
        se[[names.index(p) for p in params]] = factor * np.asarray(values, np.float64)
    return np.diag(se**2), "standard errors"


def _named_covariance(record: dict, names: tuple[str, ...]) -> np.ndarray | None:
    """The record's ``covariance`` reordered to ``names`` (its ``covariance_of`` names the rows), or None
    when it has none or it is malformed (then the standard errors serve)."""
    rows, order = record.get("covariance"), record.get("covariance_of")
    if not (isinstance(rows, list) and isinstance(order, list) and set(names) <= set(order)):
        return None
    try:
        m = np.asarray(rows, np.float64)
    except (TypeError, ValueError):
        return None
    if m.shape != (len(order), len(order)) or not np.all(np.isfinite(m)):
        return None
    at = [order.index(n) for n in names]
    return m[np.ix_(at, at)]


def _square_root(covariance: np.ndarray) -> np.ndarray:
    """(P, K) F with F Fᵀ = ``covariance`` (P, P), its non-zero directions only (a gauge freedom of the
    calibration, or an unmeasured parameter, gives none)."""
    sym = (covariance + covariance.T) / 2
    values, vectors = np.linalg.eigh(sym)
    keep = values > 1e-12 * max(float(values.max()), 1e-300)
    return vectors[:, keep] * np.sqrt(values[keep])


def _lamp_shift_mm(before: GantryKinematics, after: GantryKinematics) -> float:
    """How far the lamp moves between two kinematics at the same servo readings, worst over a grid of
    gantry angles (mm)."""
    az, el = np.meshgrid(np.arange(-180.0, 181.0, 30.0), np.arange(0.0, 91.0, 15.0))
    per_deg = before.ticks_per_rev / 360.0
    ticks = (before.zero_ticks[0] + before.directions[0] * per_deg * az.ravel(),
             before.zero_ticks[1] + before.directions[1] * per_deg * el.ravel())  # fmt: skip

    def lamps(k: GantryKinematics) -> np.ndarray:
        a, e = np.radians(k.angles_for(ticks))
        return np.asarray(k.centre) + k.arm_radius * k.unit_direction(a, e)

    return 1e3 * float(np.linalg.norm(lamps(after) - lamps(before), axis=1).max())


def _number(v) -> bool:
    return type(v) in (int, float) and np.isfinite(v) and v >= 0
