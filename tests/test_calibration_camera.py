"""Camera calibration from a ChArUco board on a wedge on the turntable, photographed by the simulated
camera of a rig that is not its drawing (builtin:bench-offsets): the intrinsics OpenCV recovers against
the true ones, and refusals when the views cannot support a calibration."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from calibration.camera_procedure import FRAMES_PER_VIEW
from calibration.charuco import BoardSpec, CalibrationError, Detection, calibrate_intrinsics, detect
from sim.render.sensor import SensorModel
from sim.targets import Board, Wedge, charuco_scene
from sim.true_rig import load_true_rig

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

BOARD = Board()  # the simulator's print of it
SPEC = BoardSpec(BOARD.squares, BOARD.square_m, BOARD.marker_m, BOARD.dictionary)  # hlr-lab's description


@pytest.fixture(scope="module")
def truth():
    """builtin:bench-offsets with pixels 0.6 % taller than wide: a fit that tied fy to fx would miss one of
    them by 0.3 %, past the 0.2 % target."""
    true_rig = load_true_rig("builtin:bench-offsets")
    k = true_rig.camera.matrix.copy()
    k[1, 1] *= 1.006
    return replace(true_rig, camera=replace(true_rig.camera, matrix=k))


def photographs(truth, tilts_deg, turntable_deg, seed=0) -> list[np.ndarray]:
    """The board on a wedge of each tilt at each turntable angle, lit by the gantry lamp from above the
    camera's side, as the procedure sees it: the mean of FRAMES_PER_VIEW raw 12-bit frames (of one render:
    a still camera's frames differ by the sensor's noise, not by the renderer's)."""
    from sim.render.renderer import Renderer

    g = truth.gantry
    lamp = g.light_position(g.zero_ticks[0] - 1024, g.zero_ticks[1] + 400)  # azimuth −90°, elevation 35°
    sensor, rng = SensorModel(), np.random.default_rng(seed)
    frames = []
    for tilt in tilts_deg:
        renderer = Renderer(charuco_scene(BOARD, Wedge(tilt_deg=tilt)), truth.camera, spp=16)
        for angle in turntable_deg:
            radiance = renderer.render(angle, lamp, lamp_on=True, seed=len(frames))
            exposure = 0.7 * sensor.top / (sensor.sensitivity * max(radiance.max(), 1e-9))
            shots = [
                sensor.expose(radiance, exposure, rng).astype(np.float64) for _ in range(FRAMES_PER_VIEW)
            ]
            frames.append(np.mean(shots, axis=0))
    return frames


@pytest.fixture(scope="module")
def views(truth) -> list[Detection]:
    frames = photographs(truth, (20.0, 45.0), np.arange(-50.0, 51.0, 10.0))
    return [detect(f, SPEC) for f in frames]


def test_intrinsics_are_recovered_from_the_turntable_views(truth, views):
    """22 views (two wedge tilts × 11 turntable angles): focal length within 0.2 %, principal point
    within 1 px, reprojection RMS ≤ 0.3 px (the issue's targets), and the whole model (K and distortion
    together: k1 and k2 trade off against each other, so are not compared one by one) maps every ray
    that falls where the board was seen to within 0.3 px of where the true camera does, once the
    common shift is taken out (a shift of the principal point is the same image as a tilt of the camera
    by f⁻¹ radians: the camera's pose, calibrated with it, absorbs it)."""
    size = (truth.camera.width, truth.camera.height)
    assert all(len(v.ids) >= 30 for v in views)
    found = calibrate_intrinsics(views, SPEC, size)
    k, true_k = found.matrix, truth.camera.matrix
    assert found.rms_px <= 0.3
    assert abs(k[0, 0] / true_k[0, 0] - 1) < 0.002
    assert abs(k[1, 1] / true_k[1, 1] - 1) < 0.002
    assert np.hypot(k[0, 2] - true_k[0, 2], k[1, 2] - true_k[1, 2]) < 1.0
    w, h = size
    u, v = np.meshgrid(np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 25))
    seen = cv2.convexHull(np.concatenate([v.pixels for v in views]).astype(np.float32))
    grid = np.stack([u.ravel(), v.ravel()], axis=1)
    inside = [cv2.pointPolygonTest(seen, (float(x), float(y)), False) >= 0 for x, y in grid]
    pixels = grid[inside].reshape(-1, 1, 2)
    assert len(pixels) > 300
    rays = cv2.undistortPoints(pixels, true_k, truth.camera.distortion).reshape(-1, 2)
    rays3 = np.concatenate([rays, np.ones((len(rays), 1))], axis=1)
    again, _ = cv2.projectPoints(rays3, np.zeros(3), np.zeros(3), k, found.distortion)
    moved = again.reshape(-1, 2) - pixels.reshape(-1, 2)
    assert np.linalg.norm(moved.mean(axis=0)) < 1.0
    assert np.linalg.norm(moved - moved.mean(axis=0), axis=1).max() < 0.3


def test_too_few_views_or_too_small_a_board_is_refused(truth, views):
    size = (truth.camera.width, truth.camera.height)
    with pytest.raises(CalibrationError, match=r"only 5 of 5 views show the board .*need 8"):
        calibrate_intrinsics(views[:5], SPEC, size)
    shrunk = [Detection(v.ids, size[0] / 2 + (v.pixels - size[0] / 2) * 0.3) for v in views]
    with pytest.raises(CalibrationError, match=r"cover \d+% of the image \(need 33%\)"):
        calibrate_intrinsics(shrunk, SPEC, size)
    empty = np.zeros((size[1], size[0], 3), np.uint16)
    assert len(detect(empty, SPEC).ids) == 0


def test_the_camera_pose_against_the_turntable_axis_is_recovered(truth, views, rig):
    """The joint fit (camera pose, board poses, intrinsics) over the same views, started from the drawing's
    camera: the true camera's position within 1 mm, its viewing direction and roll within 0.05° (the
    issue's targets). A turn of the whole world about the axis is invisible in any photograph of the
    turntable; the fit keeps the camera at the drawing's azimuth, so the truth is compared turned the
    same way (the true camera stands 0.28° off the drawing's azimuth)."""
    from calibration.camera_pose import refine_pose

    size = (truth.camera.width, truth.camera.height)
    angles = np.tile(np.arange(-50.0, 51.0, 10.0), 2)
    # the stage reports steps; hlr-lab turns them into degrees with its believed zero
    steps = truth.stage.zero_steps + angles * truth.stage.steps_per_degree
    turntable_deg = np.array([rig.turntable_kinematics.degrees_for(s) for s in steps])
    pose = refine_pose(
        views,
        turntable_deg,
        SPEC,
        calibrate_intrinsics(views, SPEC, size),
        rig.camera.rotation,
        rig.camera.translation,
        board_centre_height_m=0.09,
        placements=[0] * 11 + [1] * 11,  # the wedge at 20°, then at 45°
    )
    # the true world, turned about z so that the true camera stands at the drawing's azimuth (the stage's
    # zero, 20 steps = 0.2° off the believed one, only turns the board on the plate in the fit)
    drawn, real = rig.camera.centre, truth.camera.centre
    gauge = np.arctan2(drawn[1], drawn[0]) - np.arctan2(real[1], real[0])
    turn = np.array([[np.cos(gauge), -np.sin(gauge), 0], [np.sin(gauge), np.cos(gauge), 0], [0, 0, 1]])
    true_rotation = truth.camera.rotation @ turn.T  # the true camera in that world
    true_centre = turn @ real
    assert pose.rms_px <= 0.3
    assert np.linalg.norm(pose.position_m - true_centre) < 1e-3
    assert np.degrees(np.arccos(np.clip(pose.rotation[2] @ true_rotation[2], -1, 1))) < 0.05
    assert np.degrees(np.arccos(np.clip(pose.rotation[0] @ true_rotation[0], -1, 1))) < 0.05
    assert abs(pose.matrix[0, 0] / truth.camera.matrix[0, 0] - 1) < 0.002
    assert abs(pose.matrix[1, 1] / truth.camera.matrix[1, 1] - 1) < 0.002
    # what the rig file will say reproduces the fitted rotation
    from hlr_lab.geometry.camera import Camera

    again = Camera.look_at(pose.position_m, pose.look_at_m, matrix=pose.matrix, width=size[0],
                           height=size[1], roll_deg=pose.roll_deg)  # fmt: skip
    np.testing.assert_allclose(again.rotation, pose.rotation, atol=1e-9)


@pytest.mark.slow
def test_the_intrinsics_standard_errors_are_the_spread_of_the_estimates(truth, rig):
    """Seeded synthetic corners (the true projections plus 0.08 px of Gaussian noise, a single frame's)
    over the procedure's 24 views: the joint fit's stated standard errors of fx, fy, cx, cy agree with the
    spread of its estimates over 16 noise draws within 40 % (16 draws pin a spread down to about ±25 %),
    and the estimates centre on the truth (within 3 standard errors of their mean)."""
    from calibration.camera_pose import refine_pose
    from calibration.camera_procedure import board_angles
    from calibration.charuco import Intrinsics

    cam = truth.camera
    faces = [Wedge(tilt_deg=20.0), Wedge(tilt_deg=45.0)]
    views = board_angles(24)
    rng = np.random.default_rng(7)
    estimates, stated = [], []
    for _ in range(16):
        detections = []
        for face, angle in views:
            a = np.radians(angle)
            turn = np.array(
                [[np.cos(a), -np.sin(a), 0, 0], [np.sin(a), np.cos(a), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
            )
            m = turn @ faces[face].board_to_turntable(BOARD)
            world = SPEC.corners_m @ m[:3, :3].T + m[:3, 3]
            pixels, _ = cv2.projectPoints(world, cv2.Rodrigues(cam.rotation)[0], cam.translation, cam.matrix,
                                          cam.distortion)  # fmt: skip
            pixels = pixels.reshape(-1, 2) + rng.normal(0.0, 0.08, (len(world), 2))
            detections.append(Detection(np.arange(len(world)), pixels))
        start = Intrinsics(cam.matrix * [[1.01], [1.01], [1]], cam.distortion, 0.0)
        pose = refine_pose(detections, np.array([a for _, a in views]), SPEC, start, rig.camera.rotation,
                           rig.camera.translation, 0.09, placements=[f for f, _ in views])  # fmt: skip
        k = pose.matrix
        estimates.append([k[0, 0], k[1, 1], k[0, 2], k[1, 2]])
        stated.append(pose.intrinsics_se_px)
    estimates, stated = np.array(estimates), np.array(stated).mean(axis=0)
    spread = estimates.std(axis=0, ddof=1)
    np.testing.assert_allclose(spread, stated, rtol=0.4)
    true = [cam.matrix[0, 0], cam.matrix[1, 1], cam.matrix[0, 2], cam.matrix[1, 2]]
    assert np.all(np.abs(estimates.mean(axis=0) - true) < 3 * stated / np.sqrt(len(estimates)))
