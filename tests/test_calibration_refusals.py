"""What the mirror-ball solver refuses, each with one line saying what to do: no ball in view, a clipped
highlight, a glare with no edge, a highlight off the ball or on its edge, too few usable highlights.
Synthetic frames drawn with OpenCV (no renderer needed): a dark disc where the simulated rig's camera
sees the ball, on a lit plate."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.charuco import CalibrationError
from calibration.gantry_procedure import BallFrame, solve_gantry
from calibration.mirror_ball import ball_centre, highlight_px, lamp_ray

RADIUS = 0.025
CENTRE = np.array([0.06, 0.0, RADIUS])  # where builtin:sim's [calibration.mirror_ball] puts it at 0°
TOP = 4095  # a 12-bit sensor


def _outline_frame(rig, level: int = 2500) -> tuple[np.ndarray, tuple[float, float]]:
    """A lit plate with the ball as a dark disc, and where its centre projects (px)."""
    cam = rig.camera
    (cx, cy), _ = (v[0] for v in cam.project(CENTRE[None]))
    r = cam.matrix[0, 0] * RADIUS / np.linalg.norm(CENTRE - cam.centre)
    frame = np.full((cam.height, cam.width), level, np.uint16)
    cv2.circle(frame, (round(cx), round(cy)), round(r), 20, -1, cv2.LINE_AA)
    return frame, (cx, cy)


def _spot(shape, at, sigma_px: float, peak: float) -> np.ndarray:
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]]
    return peak * np.exp(-((x - at[0]) ** 2 + (y - at[1]) ** 2) / (2 * sigma_px**2))


def test_no_ball_in_view_is_refused(rig):
    with pytest.raises(CalibrationError, match="no mirror ball in view"):
        ball_centre(np.full((960, 1280), 2500, np.uint16), rig.camera, RADIUS, (700.0, 500.0))


def test_the_outline_gives_the_ball_and_the_centroid_is_sub_pixel(rig):
    """The checks below stand on working parts: the synthetic disc is found within a millimetre, and a
    smooth spot's centroid lands within 0.01 px (no threshold: no pull toward the pixel centre)."""
    frame, near = _outline_frame(rig)
    assert np.linalg.norm(ball_centre(frame, rig.camera, RADIUS, near) - CENTRE) < 1e-3
    at = (near[0] + 3.37, near[1] - 5.71)
    spot = (_spot((960, 1280), at, 0.8, 3000) + 40).astype(np.uint16)
    assert np.linalg.norm(highlight_px(spot, near, TOP) - at) < 0.01


def test_a_clipped_highlight_or_a_glare_without_an_edge_is_refused(rig):
    _, near = _outline_frame(rig)
    clipped = np.minimum(_spot((960, 1280), near, 1.0, 9000), TOP).astype(np.uint16)
    with pytest.raises(CalibrationError, match="clipped: use a shorter exposure"):
        highlight_px(clipped, near, TOP)
    glare = _spot((960, 1280), near, 80.0, 3000).astype(np.uint16)  # wider than any window grown about it
    with pytest.raises(CalibrationError, match="no clear edge"):
        highlight_px(glare, near, TOP)


def test_a_highlight_off_the_ball_or_on_its_edge_is_refused(rig):
    cam = rig.camera
    (cx, cy), _ = (v[0] for v in cam.project(CENTRE[None]))
    r = cam.matrix[0, 0] * RADIUS / np.linalg.norm(CENTRE - cam.centre)
    point, direction = lamp_ray(cam, CENTRE, RADIUS, np.array([cx, cy]))  # the middle: fine
    assert abs(np.linalg.norm(point - CENTRE) - RADIUS) < 1e-9
    assert abs(np.linalg.norm(direction) - 1) < 1e-9
    with pytest.raises(CalibrationError, match="off the ball's outline"):
        lamp_ray(cam, CENTRE, RADIUS, np.array([cx + 1.5 * r, cy]))
    with pytest.raises(CalibrationError, match="on the ball's edge"):
        lamp_ray(cam, CENTRE, RADIUS, np.array([cx + 0.995 * r, cy]))


def test_too_few_usable_highlights_or_no_outline_first_is_refused(rig):
    outline, near = _outline_frame(rig)
    dark = np.full_like(outline, 20)
    highlight = dark + _spot(dark.shape, (near[0] + 2.0, near[1] - 3.0), 0.8, 3000).astype(np.uint16)
    frames = [BallFrame(outline, "outline", 0, (1024, 1300), 12)] + [
        BallFrame(highlight, "highlight", 0, (1024 + 10 * i, 1300), 12) for i in range(5)
    ]
    with pytest.raises(CalibrationError, match=r"only 5 usable highlights \(need 12\)"):
        solve_gantry(frames, rig)
    with pytest.raises(CalibrationError, match="before any outline frame"):
        solve_gantry(frames[1:], rig)
