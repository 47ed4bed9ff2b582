"""The lamp's direction from a mirror ball, and the gantry's kinematics from many such directions.

* The ball's centre in 3-D comes from its outline: a polished ball in a dark room shows black against
  the lit plate behind it. The rays through its outline graze the sphere: they form a cone about the
  line from the camera to the centre, which lies a radius above the plate the ball rests on (the
  calibrated camera gives the rays). Only the upper part of the outline is used: below, the ball meets
  its own shadow and the plate.
* The highlight is the lamp's reflection: its sub-pixel centroid's ray meets the sphere at a point
  whose normal mirrors the view direction into the direction of the lamp.
* The gantry: every lamp lies on its ray from the ball. One least-squares fit over all rays of the
  gantry's centre, arm radius, azimuth axis and zero ticks (the ticks each lamp was at are known). Rays
  from one ball all start at nearly one point, which leaves the arm's length badly determined; the ball
  is therefore photographed at two places (the turntable turned half a turn), so that every lamp is
  seen from two points a ball-offset apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares

from calibration.charuco import CalibrationError
from hlr_lab.camera import Camera
from hlr_lab.kinematics import GantryKinematics

OUTLINE_ARC_DEG = 70.0  # either side of straight up: the part of the outline against the plate


def _grey(image: np.ndarray) -> np.ndarray:
    g = image.astype(np.float64)
    return g.mean(axis=2) if g.ndim == 3 else g


def ball_centre(
    image: np.ndarray, camera: Camera, radius_m: float, near_px: tuple[float, float]
) -> np.ndarray:
    """(3,) world centre of the ball resting on the plate whose outline is nearest ``near_px`` (px)."""
    grey = _grey(image)
    lit = grey > 0.3 * np.percentile(grey, 90)
    dark = cv2.morphologyEx((~lit).astype(np.uint8), cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(dark)
    candidates = [i for i in range(1, count) if stats[i, cv2.CC_STAT_AREA] > 200]
    if not candidates:
        raise CalibrationError("no mirror ball in view (no dark disc against the plate): check its place")
    ball = min(candidates, key=lambda i: np.hypot(*(centroids[i] - np.asarray(near_px))))
    contours, _ = cv2.findContours(
        (labels == ball).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    outline = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    arc = _subpixel_arc(grey, outline)
    if len(arc) < 20:
        raise CalibrationError("the mirror ball's outline is too small or cut off: bring it into full view")
    _, directions = camera.pixel_rays(arc)
    # the grazing rays form a cone about the line from the camera to the ball's centre: their directions
    # lie on a circle of the unit sphere whose plane's normal is that line. (The cone's angle gives the
    # distance too, but a third of a pixel of outline is 2 mm of depth here; the ball rests on the plate,
    # so its centre is where the line is a radius above it: far sharper.)
    mean = directions.mean(axis=0)
    _, _, vt = np.linalg.svd(directions - mean)
    axis = vt[2] if vt[2] @ mean > 0 else -vt[2]
    if axis[2] >= -1e-6:
        raise CalibrationError(
            "the camera does not look down on the plate: the ball's centre is undetermined"
        )
    return camera.centre + (radius_m - camera.centre[2]) / axis[2] * axis


def _subpixel_arc(grey: np.ndarray, outline: np.ndarray, samples: int = 240) -> np.ndarray:
    """(M, 2) points of the upper outline to a fraction of a pixel: along rays from the outline's middle,
    where the grey level crosses halfway between the ball (inside) and the plate (outside) — the edge of
    an anti-aliased disc, whatever the plate's brightness there."""
    middle = outline.mean(axis=0)
    reach = np.median(np.linalg.norm(outline - middle, axis=1))
    angles = np.radians(90.0 + np.linspace(-OUTLINE_ARC_DEG, OUTLINE_ARC_DEG, samples))
    steps = np.arange(-8.0, 8.0, 0.05)  # px across the rough edge
    found = []
    for a in angles:
        u = np.array([np.cos(a), -np.sin(a)])  # image y grows downward: 90° is straight up
        along = middle + (reach + steps)[:, None] * u
        profile = map_coordinates(grey, [along[:, 1], along[:, 0]], order=1, mode="nearest")
        inside, outside = np.median(profile[steps < -5]), np.median(profile[steps > 5])
        if outside - inside < 10 * max(np.std(profile[steps > 5]), 1e-9):
            continue  # no clean edge here (a shadow, the plate's end)
        above = np.nonzero(profile >= 0.5 * (inside + outside))[0]
        if len(above) == 0 or above[0] == 0:
            continue
        i = above[0]
        t = (0.5 * (inside + outside) - profile[i - 1]) / (profile[i] - profile[i - 1])
        found.append(middle + (reach + steps[i - 1] + t * (steps[i] - steps[i - 1])) * u)
    return np.array(found)


def highlight_px(
    image: np.ndarray, near_px: tuple[float, float], top: int, search_px: int = 150
) -> np.ndarray:
    """(2,) sub-pixel centroid of the brightest spot within ``search_px`` of ``near_px``: the values above
    half its peak, background taken off. Refuses a peak at ``top``, the sensor's full scale (a clipped
    spot's centroid would be biased; a 12-bit sensor's full scale is 4095 in a 16-bit word). On the
    simulated ball (rough conductor, GGX α 0.01) it lands 0.05–0.2 px from the true mirror point: the
    spot is not symmetric in the image (a log-parabola peak fit did worse)."""
    grey = _grey(image)
    x0, y0 = (round(v) for v in near_px)
    y_lo, x_lo = max(y0 - search_px, 0), max(x0 - search_px, 0)
    window = grey[y_lo : y0 + search_px, x_lo : x0 + search_px]
    peak = np.unravel_index(np.argmax(window), window.shape)
    if window[peak] >= top:
        raise CalibrationError("the highlight on the mirror ball is clipped: use a shorter exposure")
    py, px = peak
    spot = window[max(py - 6, 0) : py + 7, max(px - 6, 0) : px + 7]
    level = spot.min()
    weights = np.where(spot - level >= 0.5 * (window[peak] - level), spot - level, 0.0)
    ys, xs = np.mgrid[0 : spot.shape[0], 0 : spot.shape[1]]
    cy = (weights * ys).sum() / weights.sum() + max(py - 6, 0) + y_lo
    cx = (weights * xs).sum() / weights.sum() + max(px - 6, 0) + x_lo
    return np.array([cx, cy])


def lamp_ray(
    camera: Camera, centre: np.ndarray, radius_m: float, pixel: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(point on the ball (3,), unit direction toward the lamp (3,)) for the highlight at ``pixel``.
    Refuses a highlight at the ball's edge, where the mirrored direction is not determined."""
    o, d = (a[0] for a in camera.pixel_rays(np.asarray(pixel, float)[None]))
    oc = o - centre
    b = oc @ d
    disc = b * b - (oc @ oc - radius_m**2)
    if disc <= 0:
        raise CalibrationError("the highlight is off the ball's outline: the lamp is behind the ball")
    point = o + (-b - np.sqrt(disc)) * d
    normal = (point - centre) / radius_m
    if -(d @ normal) < 0.2:  # grazing: within ~78° of the edge, a pixel of error turns the ray by degrees
        raise CalibrationError("the highlight is on the ball's edge: move the lamp toward the camera's side")
    return point, d - 2 * (d @ normal) * normal


@dataclass(frozen=True)
class GantryFit:
    kinematics: GantryKinematics
    miss_mm: np.ndarray  # (K,) each lamp's distance from its ray(s) at the fit
    standard_errors: dict[
        str, float
    ]  # per fitted quantity, in its own unit (m; the axis's x/z and y/z; ticks)


def fit_gantry(
    points: np.ndarray, directions: np.ndarray, ticks: np.ndarray, start: GantryKinematics
) -> GantryFit:
    """The gantry's centre (m), arm radius (m), azimuth axis and zero ticks that put every lamp on its
    rays. points, directions (N, 3): rays from the ball toward the lamp; ticks (N, 2): the servo readings
    of each ray's lamp; ``start``: the rig file's kinematics (its tick directions and ticks per turn are
    kept)."""
    points, directions, ticks = (np.asarray(a, float) for a in (points, directions, ticks))
    a0 = np.asarray(start.azimuth_axis, float) / np.linalg.norm(start.azimuth_axis)
    x0 = np.concatenate([start.centre, [start.arm_radius, a0[0] / a0[2], a0[1] / a0[2]], start.zero_ticks])

    def kinematics(x) -> GantryKinematics:
        return GantryKinematics(x[0:3], x[3], (x[6], x[7]), start.directions, start.ticks_per_rev,
                                (x[4], x[5], 1.0))  # fmt: skip

    def residuals(x):
        k = kinematics(x)
        az, el = np.radians(k.angles_for((ticks[:, 0], ticks[:, 1])))
        lamps = np.asarray(k.centre) + k.arm_radius * k.unit_direction(az, el)
        off = lamps - points
        return (off - np.einsum("ij,ij->i", off, directions)[:, None] * directions).ravel()

    fit = least_squares(residuals, x0, x_scale="jac")
    if not fit.success:
        raise CalibrationError(f"the gantry fit did not converge ({fit.message})")
    r = fit.fun.reshape(-1, 3)
    dof = max(r.size - len(x0), 1)
    covariance = np.linalg.pinv(fit.jac.T @ fit.jac) * (fit.fun @ fit.fun) / dof
    se = np.sqrt(np.clip(np.diag(covariance), 0, None))
    k = kinematics(fit.x)
    names = ("centre_x_m", "centre_y_m", "centre_z_m", "arm_radius_m", "axis_x", "axis_y", "zero_az_ticks",
             "zero_el_ticks")  # fmt: skip
    axis = tuple(np.asarray(k.azimuth_axis) / np.linalg.norm(k.azimuth_axis))
    zero = tuple(round(t) for t in k.zero_ticks)
    rounded = GantryKinematics(k.centre, k.arm_radius, zero, k.directions, k.ticks_per_rev, axis)
    return GantryFit(rounded, 1e3 * np.linalg.norm(r, axis=1), dict(zip(names, se.tolist(), strict=True)))
