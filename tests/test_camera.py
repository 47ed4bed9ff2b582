import cv2
import numpy as np
import pytest

from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import rotation_z

K = np.array([[1500.0, 0.0, 330.5], [0.0, 1480.0, 236.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.05, 0.001, -0.002, 0.01])


@pytest.fixture
def camera():
    return Camera.look_at(
        [0.1, -0.6, 0.3], [0.0, 0.0, 0.05], matrix=K, width=640, height=480, distortion=DIST
    )


def test_projection_matches_opencv(camera):
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (200, 3)) + np.array([0.0, 0.0, 0.05])
    ours, _ = camera.project(pts)
    rvec, _ = cv2.Rodrigues(camera.rotation)
    theirs, _ = cv2.projectPoints(pts, rvec, camera.translation, K, DIST)
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), atol=1e-9)


def test_look_at_centres_the_target(camera):
    px, z = camera.project(np.array([[0.0, 0.0, 0.05]]))
    np.testing.assert_allclose(px[0], K[:2, 2], atol=1e-9)  # on the optical axis distortion vanishes
    assert z[0] == pytest.approx(np.linalg.norm([0.1, -0.6, 0.25]))
    assert camera.rotation @ camera.rotation.T == pytest.approx(np.eye(3))


def test_pixel_rays_invert_projection_with_distortion(camera):
    rng = np.random.default_rng(1)
    pixels = rng.uniform([0, 0], [639, 479], (300, 2))
    origins, dirs = camera.pixel_rays(pixels)
    back, _ = camera.project(origins + 0.5 * dirs)
    np.testing.assert_allclose(back, pixels, atol=1e-6)  # iterative undistortion converges far below a pixel


def test_grid_rays_are_every_pixels_ray_for_each_camera_asked(camera):
    """``grid_rays`` (the grid's undistortion kept per intrinsics) is ``pixel_rays(pixel_grid())`` exactly:
    for the camera, the same camera turned (the kept grid reused, the pose its own), another distortion and
    another size asked in turn, and the first again."""
    turned = camera.in_frame(rotation_z(np.radians(30)))
    other = Camera.look_at([0.1, -0.6, 0.3], [0.0, 0.0, 0.05], matrix=K, width=640, height=480,
                           distortion=-DIST)  # fmt: skip
    smaller = Camera.look_at([0.1, -0.6, 0.3], [0.0, 0.0, 0.05], matrix=K, width=320, height=240)
    for cam in (camera, turned, other, smaller, camera):
        for ours, theirs in zip(cam.grid_rays(), cam.pixel_rays(cam.pixel_grid()), strict=True):
            assert np.array_equal(ours, theirs)
    assert not np.array_equal(other.grid_rays()[1], camera.grid_rays()[1])


def test_points_behind_the_camera_do_not_project(camera):
    behind = camera.centre - camera.forward
    px, z = camera.project(behind[None])
    assert z[0] < 0
    assert np.isnan(px).all()
    assert not camera.in_image(px)[0]


def test_expressing_the_camera_in_another_frame_keeps_the_image(camera):
    frame = rotation_z(0.7)
    frame[:3, 3] = [0.01, 0.02, -0.03]
    pts_frame = np.random.default_rng(2).uniform(-0.05, 0.05, (50, 3))
    pts_world = pts_frame @ frame[:3, :3].T + frame[:3, 3]
    np.testing.assert_allclose(
        camera.in_frame(frame).project(pts_frame)[0], camera.project(pts_world)[0], atol=1e-9
    )


def test_projected_area_matches_the_projected_polygon():
    cam = Camera.look_at([0.0, -0.5, 0.0], [0.0, 0.0, 0.0], matrix=K, width=640, height=480)
    # a 1 mm square patch off-axis and tilted 40° away from the camera
    c, n = np.array([0.05, 0.0, 0.03]), np.array([np.sin(0.7), -np.cos(0.7), 0.0])
    u = np.cross(n, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    h = 0.0005
    corners = np.array([c + h * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    px, _ = cam.project(corners)
    x, y = px[:, 0], px[:, 1]
    polygon = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
    predicted = cam.projected_area_px(c[None], n[None], np.array([(2 * h) ** 2]))[0]
    assert predicted == pytest.approx(polygon, rel=2e-3)  # first-order formula on a 1 mm patch
