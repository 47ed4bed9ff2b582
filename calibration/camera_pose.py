"""The camera's pose relative to the turntable, from a board the turntable turns.

Each view ``i`` of a board standing on the turntable at angle θᵢ obeys

    camera ← board  =  C · Rz(θᵢ) · B

with C the world → camera pose (what the rig file's ``position_m``, ``look_at_m`` and ``roll_deg``
say) and B the board → turntable pose (where the wedge put the board), the world being the
turntable's frame (origin on the axis at the plate, z along the axis). One least-squares fit of every
corner's reprojection error over every view refines C, B and the intrinsics together, starting from
OpenCV's per-view calibration and the rig's believed camera.

Two motions of the world leave every image unchanged (C·Rz(φ)·Rz(θ)·Rz(−φ)·B = C·Rz(θ)·B: turns
about the axis commute), so the fit fixes them by convention:

* a turn of the world about z: the camera keeps the azimuth about the turntable axis that the rig
  file gives it (world +x is defined by where the camera stands, as drawn). The board's azimuth on the
  plate comes out of the fit (:attr:`CameraPose.board_azimuth_deg`); with the board mounted along the
  plate's 0° line, its difference from 0 is the error of ``turntable.zero_steps``;
* a shift of the world along z (the camera's height against the board's): the centre of the board's
  first placement is taken to stand ``board_centre_height_m`` above the plate, as the wedge is built.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from calibration.charuco import BoardSpec, CalibrationError, Detection, Intrinsics
from hlr_lab.geometry.sphere import rotation_z


@dataclass(frozen=True)
class CameraPose:
    """The calibrated camera: intrinsics and pose in the turntable's world, as the rig file says them."""

    matrix: np.ndarray  # (3, 3)
    distortion: np.ndarray  # (5,)
    rotation: np.ndarray  # (3, 3) world → camera
    translation: np.ndarray  # (3,) world → camera, m
    board_to_turntable: np.ndarray  # (4, 4) where the wedge put the board (first placement)
    rms_px: float
    per_view_rms_px: np.ndarray  # (U,) over the views used
    residuals_px: dict[int, np.ndarray]  # view index → (N, 2) projected − detected corners, px (views used)
    # (4,) standard errors of fx, fy, cx, cy, px: from the fit's Jacobian and its residuals' spread
    intrinsics_se_px: np.ndarray
    # (14, 14) the covariance of the camera's pose and intrinsics in CAMERA_PARAMETERS' order (the boards'
    # poses marginalised; the turn about the turntable axis no photograph sees has none)
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((14, 14)))

    @property
    def board_azimuth_deg(self) -> float:
        """Azimuth of the board's x axis on the plate (turntable frame), degrees."""
        x = self.board_to_turntable[:3, 0]
        return float(np.degrees(np.arctan2(x[1], x[0])))

    @property
    def position_m(self) -> np.ndarray:
        return -self.rotation.T @ self.translation

    @property
    def look_at_m(self) -> np.ndarray:
        """The point of the optical axis nearest the turntable axis (any point of the axis would do)."""
        c, f = self.position_m, self.rotation[2]
        horizontal = f[:2] @ f[:2]
        s = -(c[:2] @ f[:2]) / horizontal if horizontal > 1e-12 else 1.0
        return c + s * f

    @property
    def roll_deg(self) -> float:
        """The turn about the optical axis that, after looking at :attr:`look_at_m` with world +z up,
        gives this camera's rotation (the rig file's ``roll_deg``, right-handed about +z)."""
        f = self.rotation[2]
        x0 = np.cross(f, [0.0, 0.0, 1.0])
        x0 /= np.linalg.norm(x0)
        y0 = np.cross(f, x0)
        x = self.rotation[0]
        return float(np.degrees(np.arctan2(x @ y0, x @ x0)))


def refine_pose(
    detections: list[Detection],
    turntable_deg: np.ndarray,
    spec: BoardSpec,
    intrinsics: Intrinsics,
    believed_rotation: np.ndarray,
    believed_translation: np.ndarray,
    board_centre_height_m: float,
    placements: list[int] | None = None,
) -> CameraPose:
    """Camera pose, board poses and intrinsics by one least-squares fit (see the module's docstring).

    detections: per view, as :func:`calibration.charuco.detect` found them; turntable_deg (V,) the angle
    of each view (from the stage's measured steps); believed_*: the rig file's camera, the start;
    placements (V,): which placement of the board each view shows (the wedge flipped or moved between
    views: one board pose each; default all 0). The centre of placement 0 stands
    ``board_centre_height_m`` above the plate; the others are free.
    """
    placements = [0] * len(detections) if placements is None else list(placements)
    used = [i for i, d in enumerate(detections) if len(d.ids) >= 4]
    if len(used) < 3:
        raise CalibrationError(
            "the board was seen in fewer than 3 turntable angles: the axis cannot be found"
        )
    objects = [spec.corners_m[detections[i].ids] for i in used]
    pixels = [detections[i].pixels for i in used]
    turns = [rotation_z(np.radians(turntable_deg[i])) for i in used]
    which = [placements[i] for i in used]
    kinds = sorted(set(which))
    if kinds[0] != 0:
        raise CalibrationError("no view shows the board in its first placement, whose height is known")
    camera = np.eye(4)
    camera[:3, :3], camera[:3, 3] = believed_rotation, believed_translation
    centre = spec.corners_m.mean(axis=0)
    boards = []
    # each board from its first view and the believed camera: B = Rz(θ)ᵀ · C⁻¹ · (camera ← board)
    for kind in kinds:
        v = which.index(kind)
        found, rvec, tvec = cv2.solvePnP(objects[v], pixels[v], intrinsics.matrix, intrinsics.distortion)
        if not found:
            raise CalibrationError(f"the board's pose in view {used[v]} could not be solved")
        b = turns[v].T @ np.linalg.inv(camera) @ _pose(rvec, tvec)
        where = b[:3, :3] @ centre + b[:3, 3]
        boards.append(
            np.concatenate([cv2.Rodrigues(b[:3, :3])[0].ravel(), where[:2] if kind == 0 else where])
        )
    k0 = intrinsics.matrix
    start = np.concatenate([
        cv2.Rodrigues(camera[:3, :3])[0].ravel(), camera[:3, 3],
        [k0[0, 0], k0[1, 1], k0[0, 2], k0[1, 2]], intrinsics.distortion[:4], *boards,
    ])  # fmt: skip

    def unpack(p):
        cam = _pose(p[0:3], p[3:6])
        k = np.array([[p[6], 0.0, p[8]], [0.0, p[7], p[9]], [0.0, 0.0, 1.0]])
        dist = np.concatenate([p[10:14], [0.0]])
        brds, at = {}, 14
        for kind in kinds:
            rb = cv2.Rodrigues(p[at : at + 3])[0]
            where = (
                np.array([p[at + 3], p[at + 4], board_centre_height_m]) if kind == 0 else p[at + 3 : at + 6]
            )
            at += 5 if kind == 0 else 6
            brd = np.eye(4)
            brd[:3, :3], brd[:3, 3] = rb, where - rb @ centre
            brds[kind] = brd
        return cam, k, dist, brds

    def residuals(p):
        cam, k, dist, brds = unpack(p)
        out = []
        for obj, px, turn, kind in zip(objects, pixels, turns, which, strict=True):
            pose = cam @ turn @ brds[kind]
            rvec = cv2.Rodrigues(pose[:3, :3])[0]
            proj, _ = cv2.projectPoints(obj, rvec, pose[:3, 3], k, dist)
            out.append((proj.reshape(-1, 2) - px).ravel())
        return np.concatenate(out)

    fit = least_squares(residuals, start, x_scale="jac", method="lm")
    if not fit.success:
        raise CalibrationError(
            f"the joint camera fit did not converge ({fit.message}): check that the photographs show the board "
            "sharp on the wedge and that the rig file's camera pose is roughly right, then solve again with --from"
        )
    cam, k, dist, brds = unpack(fit.x)
    # the gauge: turn the world about z until the camera stands at the azimuth the rig file gives it
    believed_centre = -believed_rotation.T @ believed_translation
    centre_now = -cam[:3, :3].T @ cam[:3, 3]
    phi = np.arctan2(believed_centre[1], believed_centre[0]) - np.arctan2(centre_now[1], centre_now[0])
    cam, brds = cam @ rotation_z(-phi), {kind: rotation_z(phi) @ b for kind, b in brds.items()}
    r = fit.fun.reshape(-1, 2)
    bounds = np.cumsum([0] + [len(o) for o in objects])
    per_view = np.array(
        [np.sqrt(np.mean(np.sum(r[a:b] ** 2, axis=1))) for a, b in itertools.pairwise(bounds)]
    )
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1))))
    by_view = {v: r[a:b] for v, a, b in zip(used, bounds[:-1], bounds[1:], strict=True)}
    se, covariance = _standard_errors(fit.jac, fit.fun)[6:10], _camera_covariance(fit.jac, fit.fun, fit.x[:3])
    return CameraPose(k, dist, cam[:3, :3], cam[:3, 3], brds[0], rms, per_view, by_view, se, covariance)


def _standard_errors(jacobian: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """(P,) standard errors of a least-squares fit's parameters: the covariance σ² (JᵀJ)⁻¹ with σ² the
    residuals' variance per degree of freedom (nan where JᵀJ is singular)."""
    m, n = jacobian.shape
    variance = float(residuals @ residuals) / max(m - n, 1)
    try:
        return np.sqrt(np.diag(np.linalg.inv(jacobian.T @ jacobian)) * variance)
    except np.linalg.LinAlgError:
        return np.full(n, np.nan)


def _camera_covariance(jacobian: np.ndarray, residuals: np.ndarray, rvec: np.ndarray) -> np.ndarray:
    """(14, 14) the covariance of the fit's first 14 parameters (rvec, tvec, fx fy cx cy, k1 k2 p1 p2) with
    the rotation vector's block turned into a turn ω of the camera's own axes (R' = exp(ω)·R: what
    CAMERA_PARAMETERS means, and what the gauge turn about the axis, applied on the right, leaves alone).
    The pseudo-inverse gives the gauge direction, which the residuals cannot see, no variance."""
    m, n = jacobian.shape
    variance = float(residuals @ residuals) / max(m - n, 1)
    full = np.linalg.pinv(jacobian.T @ jacobian) * variance
    cov = full[:14, :14]
    r0 = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    turn = np.eye(14)
    for i in range(3):  # ∂ω/∂rvec by central differences
        step = np.zeros(3)
        step[i] = 1e-6
        plus = cv2.Rodrigues(cv2.Rodrigues(rvec + step)[0] @ r0.T)[0].ravel()
        minus = cv2.Rodrigues(cv2.Rodrigues(rvec - step)[0] @ r0.T)[0].ravel()
        turn[:3, i] = (plus - minus) / 2e-6
    return turn @ cov @ turn.T


def _pose(rvec, tvec) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3))[0]
    m[:3, 3] = np.asarray(tvec, float).reshape(3)
    return m
