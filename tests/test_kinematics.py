"""Gantry and turntable kinematics: plan angles ↔ device ticks/steps, and agreement with the simulated rig."""

import numpy as np
import pytest

from hlr_lab.rig.kinematics import GantryKinematics, TurntableKinematics
from sim.camera import GantryGeometry, StageGeometry

HALF_TICK_DEG = 360.0 / 4096 / 2  # rounding to the nearest tick moves an angle by at most this


@pytest.mark.parametrize("directions", [(1, 1), (-1, 1), (1, -1)])
def test_angles_survive_the_round_trip_through_ticks(directions):
    k = GantryKinematics(np.array([0.01, -0.02, 0.07]), 0.3, (2048, 1024), directions)
    rng = np.random.default_rng(5)
    for az, el in zip(rng.uniform(-180, 180, 200), rng.uniform(-10, 80, 200), strict=True):
        ticks = k.ticks_for(az, el)
        assert all(isinstance(t, int) for t in ticks)
        back = k.angles_for(ticks)
        assert abs(back[0] - az) <= HALF_TICK_DEG + 1e-9
        assert abs(back[1] - el) <= HALF_TICK_DEG + 1e-9
        # the lamp position names the same angles (azimuth wraps into (−180, 180])
        np.testing.assert_allclose(k.angles_of(k.light_position(ticks)), back, atol=1e-9)


def test_direction_flips_the_tick_sense():
    forward = GantryKinematics(np.zeros(3), 0.3, (2048, 1024), (1, 1))
    reverse = GantryKinematics(np.zeros(3), 0.3, (2048, 1024), (-1, 1))
    assert forward.ticks_for(90.0, 0.0) == (3072, 1024)
    assert reverse.ticks_for(90.0, 0.0) == (1024, 1024)
    np.testing.assert_allclose(reverse.light_position((1024, 1024)), [0.0, 0.3, 0.0], atol=1e-12)


def test_light_lies_on_the_arm_sphere():
    k = GantryKinematics(np.array([0.0, 0.0, 0.07]), 0.3, (2048, 1024))
    ticks = np.random.default_rng(1).integers(0, 4096, size=(50, 2))
    r = [np.linalg.norm(k.light_position(tuple(t)) - k.centre) for t in ticks]
    np.testing.assert_allclose(r, 0.3, rtol=1e-12)


def test_sim_rig_file_matches_the_simulated_hardware(rig):
    """The built-in rig file must describe the simulated gantry and stage exactly, or frames rendered by
    the simulator would carry a different light than the one the fit is told about."""
    truth = GantryGeometry()
    assert rig.gantry.servo_ids == (truth.azimuth_servo, truth.elevation_servo)
    np.testing.assert_allclose(rig.gantry.kinematics.centre, rig.gantry.centre)
    ticks = np.random.default_rng(2).integers(0, 4096, size=(100, 2))
    for t in ticks:
        np.testing.assert_allclose(
            rig.gantry.kinematics.light_position(tuple(t)), truth.light_position(*t), atol=1e-12
        )
    assert rig.turntable_kinematics.steps_per_degree == StageGeometry().steps_per_degree
    # −10°…80° elevation about tick 1024 is 910.2…1934.2; the full-circle azimuth loses tick 4096 (= 0)
    assert rig.gantry.servo_limits == ((0, 4095), (910, 1934))


def test_turntable_round_trip():
    k = TurntableKinematics(steps_per_degree=100.0, zero_steps=-250)
    assert k.steps_for(0.0) == -250
    assert k.steps_for(90.0) == 8750
    for deg in np.random.default_rng(3).uniform(-180, 180, 100):
        assert abs(k.degrees_for(k.steps_for(deg)) - deg) <= 0.5 / 100.0 + 1e-12


def test_a_tilted_azimuth_axis_carries_the_whole_gantry_with_it():
    """Azimuth axis tilted 5° toward +x: straight up (elevation 90°) is along the axis, azimuth 0 lies in
    the plane of world x and the axis, every angle survives the round trip through a position."""
    tilt = np.radians(5.0)
    axis = (np.sin(tilt), 0.0, np.cos(tilt))
    k = GantryKinematics(np.array([0.0, 0.0, 0.07]), 0.3, (2048, 1024), azimuth_axis=axis)
    np.testing.assert_allclose(k.frame.T @ k.frame, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(k.unit_direction(0.0, np.pi / 2), axis, atol=1e-12)
    zero = k.unit_direction(0.0, 0.0)
    assert abs(zero @ axis) < 1e-12
    assert abs(zero[1]) < 1e-12
    assert zero[0] > 0.99
    rng = np.random.default_rng(3)
    az, el = rng.uniform(-np.pi, np.pi, 200), rng.uniform(-0.2, 1.4, 200)
    back = k.direction_angles(k.unit_direction(az, el))
    np.testing.assert_allclose(back, (az, el), atol=1e-9)
    upright = GantryKinematics(np.zeros(3), 0.3, (2048, 1024))
    np.testing.assert_allclose(upright.frame, np.eye(3))


def test_a_true_rig_file_is_read_alike_by_hlr_lab_and_by_the_simulator(tmp_path):
    """The simulator reads a true rig file in its own words (sim.true_rig); on a rig with every offset
    the calibration will look for (tilted axis, zero ticks, arm, camera roll and pose, turntable zero)
    both readings put the lamp, the camera and the turntable in the same place."""
    from importlib import resources

    from hlr_lab.rig.file import load_rig
    from sim.true_rig import load_true_rig

    with resources.as_file(resources.files("sim.data") / "bench-offsets.toml") as path:
        believed = load_rig(path)
    truth = load_true_rig("builtin:bench-offsets")
    assert truth.gantry.azimuth_axis != (0.0, 0.0, 1.0)
    ticks = np.random.default_rng(4).integers(0, 4096, size=(100, 2))
    for t in ticks:
        np.testing.assert_allclose(
            believed.gantry.kinematics.light_position(tuple(t)), truth.gantry.light_position(*t), atol=1e-12
        )
    np.testing.assert_allclose(believed.camera.rotation, truth.camera.rotation, atol=1e-12)
    np.testing.assert_allclose(believed.camera.translation, truth.camera.translation, atol=1e-12)
    np.testing.assert_allclose(believed.camera.matrix, truth.camera.matrix)
    assert believed.turntable_kinematics.degrees_for(1234) == pytest.approx(truth.stage.degrees(1234))


def test_camera_roll_turns_the_image_about_the_optical_axis():
    """roll_deg is right-handed about the camera's +z: the camera's axes turn by the angle, i.e. its
    rotation is Rᵀ(θ)·R₀ with R(θ) OpenCV's Rodrigues rotation of θ about z."""
    import cv2

    from hlr_lab.geometry.camera import Camera

    common = {"matrix": np.diag([1000.0, 1000.0, 1.0]), "width": 640, "height": 480}
    plain = Camera.look_at((0.0, -0.6, 0.3), (0.0, 0.0, 0.07), **common)
    rolled = Camera.look_at((0.0, -0.6, 0.3), (0.0, 0.0, 0.07), roll_deg=30.0, **common)
    turn, _ = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(30.0)]))
    np.testing.assert_allclose(rolled.rotation, turn.T @ plain.rotation, atol=1e-12)
    np.testing.assert_allclose(rolled.centre, plain.centre, atol=1e-12)
