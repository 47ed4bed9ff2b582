"""The lamp's direction from a mirror ball, and the gantry's kinematics from many such directions.

* The ball's centre in 3-D comes from its outline: a polished ball in a dark room shows black against
  the lit plate behind it. The rays through its outline graze the sphere: they form a cone about the
  line from the camera to the centre, which lies a radius above the plate the ball rests on (the
  calibrated camera gives the rays). Only the upper part of the outline is used: below, the ball meets
  its own shadow and the plate.
* The highlight is the lamp's reflection: its sub-pixel centroid's ray meets the sphere at a point
  whose normal mirrors the view direction into the direction of the lamp.
* The gantry: every lamp lies on its mirrored ray. One least-squares fit over all rays of the gantry's
  centre, arm radius, azimuth axis and zero ticks (the ticks each lamp was at are known), and of the
  ball's place on the plate, on which every ray hangs (the outline places it to a few hundredths of a
  millimetre at best; the fit, to a few thousandths). Rays from one ball all start at nearly one point,
  which leaves the arm's length badly determined; the ball is therefore photographed at two places (the
  turntable turned half a turn), so that every lamp is seen from two points a ball-offset apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares

from calibration.charuco import CalibrationError
from hlr_lab.geometry.camera import Camera
from hlr_lab.rig.file import GANTRY_PARAMETERS
from hlr_lab.rig.kinematics import GantryKinematics

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
    """(2,) sub-pixel centroid (px) of the brightest spot within ``search_px`` of ``near_px``.

    Every value of a window about the peak counts, less the background of the ring around it; the window
    grows until that ring holds nothing of the spot (under 2 % of its peak). No threshold: cutting a spot
    a pixel or two wide at a fraction of its peak pulls the centroid toward the peak pixel's centre
    ("pixel locking"; 0.15 px rms on the simulated ball, against 0.02 px without, at 128 samples per
    pixel). Refuses a peak at ``top``, the sensor's full scale (a clipped spot's centroid is biased;
    a 12-bit sensor's full scale is 4095 in a 16-bit word)."""
    grey = _grey(image)
    x0, y0 = (round(v) for v in near_px)
    y_lo, x_lo = max(y0 - search_px, 0), max(x0 - search_px, 0)
    window = grey[y_lo : y0 + search_px, x_lo : x0 + search_px]
    py, px = np.unravel_index(np.argmax(window), window.shape)
    if window[py, px] >= top:
        raise CalibrationError("the highlight on the mirror ball is clipped: use a shorter exposure")
    py, px = py + y_lo, px + x_lo
    for half in range(3, 40):
        outer = grey[py - half - 2 : py + half + 3, px - half - 2 : px + half + 3]
        if outer.shape != (2 * half + 5,) * 2:
            break  # the image's edge
        ring = np.ones(outer.shape, bool)
        ring[2:-2, 2:-2] = False
        background = np.median(outer[ring])
        spot = outer[2:-2, 2:-2] - background
        if outer[ring].max() - background < 0.02 * spot.max():
            offsets = np.arange(-half, half + 1)
            total = spot.sum()
            return np.array(
                [px + spot.sum(axis=0) @ offsets / total, py + spot.sum(axis=1) @ offsets / total]
            )
    raise CalibrationError(
        "the highlight on the mirror ball has no clear edge (a spread glare, or cut by the image's edge): "
        "darken the room and bring the ball into full view"
    )


def _mirrored(
    origins: np.ndarray, directions: np.ndarray, centres: np.ndarray, radius_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera rays (N, 3) reflected by balls at ``centres`` (N, 3): (points on the balls (N, 3), unit
    mirrored directions (N, 3), cosine between each ray and the normal it meets (N,)). A ray that misses
    its ball is taken at its closest approach (cosine 0): the fit below may try such a centre on its way."""
    oc = origins - centres
    b = np.einsum("ij,ij->i", oc, directions)
    disc = np.clip(b * b - (np.einsum("ij,ij->i", oc, oc) - radius_m**2), 0.0, None)
    points = origins + (-b - np.sqrt(disc))[:, None] * directions
    normals = (points - centres) / radius_m
    along = np.einsum("ij,ij->i", directions, normals)
    return points, directions - 2 * along[:, None] * normals, -along


def ball_centres(place_xy: np.ndarray, radius_m: float, turntable_rad: np.ndarray) -> np.ndarray:
    """(N, 3) world centres of a ball resting on the plate at ``place_xy`` (m, at turntable 0) with the
    turntable at each of ``turntable_rad`` (N,)."""
    c, s = np.cos(turntable_rad), np.sin(turntable_rad)
    x, y = place_xy
    return np.stack([c * x - s * y, s * x + c * y, np.full_like(c, radius_m)], axis=1)


def lamp_ray(
    camera: Camera, centre: np.ndarray, radius_m: float, pixel: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(point on the ball (3,), unit direction toward the lamp (3,)) for the highlight at ``pixel``.
    Refuses a highlight at the ball's edge, where the mirrored direction is not determined."""
    o, d = camera.pixel_rays(np.asarray(pixel, float)[None])
    oc = o[0] - centre
    if (oc @ d[0]) ** 2 - (oc @ oc - radius_m**2) <= 0:
        raise CalibrationError("the highlight is off the ball's outline: the lamp is behind the ball")
    points, mirrored, facing = _mirrored(o, d, np.asarray(centre, float)[None], radius_m)
    if facing[0] < 0.2:  # grazing: within ~78° of the edge, a pixel of error turns the ray by degrees
        raise CalibrationError("the highlight is on the ball's edge: move the lamp toward the camera's side")
    return points[0], mirrored[0]


@dataclass(frozen=True)
class Highlights:
    """What the ball showed: per lamp pose, where its highlight was, where the ball was, where the lamp
    was."""

    pixels: np.ndarray  # (N, 2) px, the highlights' centroids
    turntable_rad: np.ndarray  # (N,) the turntable's angle for each
    ticks: np.ndarray  # (N, 2) the gantry servos' readings for each


@dataclass(frozen=True)
class GantryFit:
    """The gantry's kinematics fitted to the lamp's rays, the ball's place, each ray's miss (mm) and the
    standard errors."""

    kinematics: GantryKinematics
    place_xy_m: np.ndarray  # (2,) where the ball rests on the plate at turntable 0, as the fit puts it
    miss_mm: np.ndarray  # (N,) each lamp's distance from its ray at the fit
    standard_errors: dict[str, float]  # per fitted quantity, in its own unit (m; the axis's x/z, y/z; ticks)
    covariance: np.ndarray  # (8, 8) of the kinematics' quantities, in GANTRY_PARAMETERS' order


def fit_gantry(
    highlights: Highlights,
    camera: Camera,
    radius_m: float,
    start: GantryKinematics,
    place_xy_m: np.ndarray,
) -> GantryFit:
    """The gantry's centre (m), arm radius (m), azimuth axis and zero ticks, and the ball's place on the
    plate (m), that put every lamp on the ray its highlight mirrors. ``start``: the rig file's kinematics
    (its tick directions and ticks per turn are kept); ``place_xy_m``: the ball's place from its outline.

    The place is fitted too because every ray hangs on it: a ball 0.1 mm off turns the normals, and so
    the rays, by 0.2–0.5°, which at the lamp's distance is 1–3 mm — more than the outline can promise
    (a tenth of a pixel of outline is 0.2 mm of depth). The highlights of lamps all around fix it far
    better: each one's ray must meet its lamp."""
    ticks = np.asarray(highlights.ticks, float)
    origins, rays = camera.pixel_rays(np.asarray(highlights.pixels, float))
    a0 = np.asarray(start.azimuth_axis, float) / np.linalg.norm(start.azimuth_axis)
    x0 = np.concatenate([start.centre, [start.arm_radius, a0[0] / a0[2], a0[1] / a0[2]], start.zero_ticks,
                         place_xy_m])  # fmt: skip

    def kinematics(x) -> GantryKinematics:
        return GantryKinematics(x[0:3], x[3], (x[6], x[7]), start.directions, start.ticks_per_rev,
                                (x[4], x[5], 1.0))  # fmt: skip

    def misses(x) -> np.ndarray:
        k = kinematics(x)
        az, el = np.radians(k.angles_for((ticks[:, 0], ticks[:, 1])))
        lamps = np.asarray(k.centre) + k.arm_radius * k.unit_direction(az, el)
        centres = ball_centres(x[8:10], radius_m, highlights.turntable_rad)
        points, mirrored, _ = _mirrored(origins, rays, centres, radius_m)
        off = lamps - points
        return off - np.einsum("ij,ij->i", off, mirrored)[:, None] * mirrored

    fit = least_squares(lambda x: misses(x).ravel(), x0, x_scale="jac")
    if not fit.success:
        raise CalibrationError(
            f"the gantry fit did not converge ({fit.message}): check that [calibration.mirror_ball] gives the "
            "ball's radius and rough place, and that the rig file's gantry is within a few centimetres of the "
            "bench, then solve again with --from"
        )
    dof = max(fit.fun.size - len(x0), 1)
    covariance = np.linalg.pinv(fit.jac.T @ fit.jac) * (fit.fun @ fit.fun) / dof
    se = np.sqrt(np.clip(np.diag(covariance), 0, None))
    k = kinematics(fit.x)
    names = ("centre_x_m", "centre_y_m", "centre_z_m", "arm_radius_m", "axis_x", "axis_y", "zero_az_ticks",
             "zero_el_ticks", "ball_x_m", "ball_y_m")  # fmt: skip
    axis = tuple(np.asarray(k.azimuth_axis) / np.linalg.norm(k.azimuth_axis))
    zero = (round(k.zero_ticks[0]), round(k.zero_ticks[1]))
    rounded = GantryKinematics(k.centre, k.arm_radius, zero, k.directions, k.ticks_per_rev, axis)
    assert names[:8] == GANTRY_PARAMETERS
    return GantryFit(rounded, fit.x[8:10].copy(), 1e3 * np.linalg.norm(misses(fit.x), axis=1),
                     dict(zip(names, se.tolist(), strict=True)), covariance[:8, :8])  # fmt: skip
