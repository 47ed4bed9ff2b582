"""The rig file's devices opened on the simulated rig: plan → targets → drivers → where the sim lamp is."""

import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.opencv_camera import OpenCVCamera
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import read_plan
from hlr_lab.instrument.devices import gantry_config, open_camera, open_devices, stage_config
from hlr_lab.instrument.motion import (
    ACCELERATION_UNIT_REV_S2,
    VELOCITY_UNIT_REV_S,
    motion_targets,
    trapezoid_s,
)
from hlr_lab.rig.file import load_rig, sim_rig
from sim.camera import GantryGeometry, StageGeometry
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS
from sim.rig import SimRig
from sim.turntable import register_map as rm


@pytest.fixture
def sim():
    with SimRig(speed_factor=40.0) as s:
        yield s


def devices_on(sim, rig):
    return open_devices(rig, gantry_port=sim.endpoints.dynamixel, stage_address=sim.endpoints.modbus)


def test_sim_rig_file_addresses_the_simulated_devices(rig):
    assert stage_config(rig, "x:1").map.unit == rm.STAGE_UNIT
    assert (rig.file.lamp.device_id, rig.file.lamp.coil) == (rm.RELAY_UNIT, rm.LAMP_COIL)


def test_plan_poses_put_the_simulated_lamp_where_planned(sim, rig, plan_file):
    path, *_ = plan_file
    plan = read_plan(path)
    targets = motion_targets(plan, rig, path)[:3]
    truth = GantryGeometry()
    # rounding (½ tick) plus the settle tolerance (2 ticks) per axis: an arc of R·√2·2.5·2π/4096 = 1.6 mm
    tolerance_m = truth.arm_radius * np.sqrt(2) * 2.5 * 2 * np.pi / truth.ticks_per_rev
    with devices_on(sim, rig) as devices:
        found = devices.connect()
        assert found["servo 1"] == found["servo 2"] == "XM430-W350"
        for servo, (lo, hi) in zip(sim.bus.servos, rig.gantry.servo_limits, strict=True):
            assert (servo.get("min_position_limit"), servo.get("max_position_limit")) == (lo, hi)
        for pose, target in zip(plan.poses, targets, strict=True):
            devices.stage.move_to((target.turntable_steps,))
            devices.gantry.move_to(target.gantry_ticks)  # both axes travel at once
            devices.stage.wait_settled(timeout_s=10)
            ticks = devices.gantry.wait_settled(timeout_s=10)
            devices.lamp.set(True)
            assert sim.turntable.stage.lamp
            assert np.linalg.norm(truth.light_position(*ticks) - pose.light.position_m) <= tolerance_m
            stage_deg = sim.turntable.stage.position() / StageGeometry().steps_per_degree
            assert stage_deg == pytest.approx(pose.turntable_deg, abs=0.011)  # ½ step + 1 step tolerance
    # leaving the block leaves the rig safe
    assert not sim.turntable.stage.lamp
    assert all(s.get("torque_enable") == 0 for s in sim.bus.servos)


def test_safe_state_runs_every_step_even_when_one_fails(sim, rig):
    """A lamp relay that refuses (an address the module does not have) must not keep the torque on."""
    broken = replace(
        rig, file=rig.file.model_copy(update={"lamp": rig.file.lamp.model_copy(update={"coil": 99})})
    )
    with devices_on(sim, broken) as devices:
        devices.gantry.connect()
        assert all(s.get("torque_enable") == 1 for s in sim.bus.servos)
    assert all(s.get("torque_enable") == 0 for s in sim.bus.servos)


@pytest.mark.parametrize(
    ("make", "field"), [(gantry_config, "gantry.port"), (stage_config, "turntable.address")]
)
def test_a_missing_link_is_named(rig, make, field):
    with pytest.raises(InputError, match=r"no (port|address)") as err:
        make(rig)
    assert err.value.field == field
    assert "builtin:sim" in str(err.value)


def test_turntable_limits_become_stage_step_limits(rig):
    config = stage_config(rig, "x:1")
    assert (config.min_steps, config.max_steps) == (-18000, 18000)


def test_the_documented_real_rig_example_is_valid():
    """docs/rig.example.toml is what operators copy: it must load and give the drivers their settings."""
    rig = load_rig(Path(__file__).resolve().parents[1] / "docs" / "rig.example.toml")
    # azimuth ±170° about tick 2048; elevation −5…75° about 1024 counting down (directions = [1, −1])
    assert rig.gantry.servo_limits == ((114, 3982), (171, 1081))
    gantry = gantry_config(rig)
    assert gantry.port.startswith("/dev/serial/by-id/")
    assert [(a.servo_id, a.min_ticks, a.max_ticks) for a in gantry.axes] == [(1, 114, 3982), (2, 171, 1081)]
    stage = stage_config(rig)
    assert (stage.address, stage.min_steps, stage.max_steps) == ("192.168.0.30:502", -18000, 18000)
    assert (rig.file.lamp.device_id, rig.file.lamp.coil) == (2, 0)
    capture = rig.file.camera.capture
    assert (capture.device, capture.fourcc, capture.bits, capture.msb_aligned) == (
        "/dev/video0",
        "Y16 ",
        12,
        True,
    )
    assert (rig.file.light.type, rig.file.light.power) == ("point", 0.85)
    assert (rig.file.sensor.sensitivity, rig.file.sensor.black_level_dn) == (52000.0, 64.0)
    assert gantry.reply_timeout_ms == 34  # the SDK's wait: a real adapter's latency timer, twice


def test_the_simulated_rig_waits_for_its_servos_as_long_as_the_simulator_asks():
    """The simulated servos answer from threads of a busy process: the built-in rig file's reply wait is
    the simulator's, which the driver then uses."""
    assert gantry_config(sim_rig(), "/dev/pts/0").reply_timeout_ms == CLIENT_REPLY_TIMEOUT_MS


def _with_camera(tmp_path, snippet: str):
    """The simulated rig's file with ``snippet`` (TOML) added to the end of its [camera] section."""
    text = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    head, rest = text.split("[gantry]", 1)
    path = tmp_path / "rig.toml"
    path.write_text(f"{head}\n{snippet}\n\n[gantry]{rest}")
    return load_rig(path)


def test_the_camera_comes_from_camera_capture_through_opencv(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "0000.png"), np.full((4, 6), 300, np.uint16))
    pattern = str(frames / "%04d.png")
    rig = _with_camera(tmp_path, f'[camera.capture]\ndevice = "{pattern}"\nbackend = "images"\nbits = 16')
    camera = open_camera(rig)
    try:
        assert isinstance(camera, OpenCVCamera)
        assert camera.capture().pixels.max() == 300
    finally:
        camera.close()


def test_a_rig_without_a_frame_source_is_refused_and_two_are_refused(rig, tmp_path):
    with pytest.raises(InputError, match=r"camera\.address.*\[camera\.capture\]"):
        open_camera(rig)  # the simulated rig's file leaves the endpoint to the simulator
    with pytest.raises(InputError, match="one way to the camera, not address and capture"):
        _with_camera(tmp_path, 'address = "localhost:1"\n[camera.capture]\ndevice = "/dev/video0"')


def test_the_duration_estimate_matches_the_simulated_servo(rig):
    """--dry-run's motion model against the simulated servo's trapezoidal profile (same e-manual units)."""
    g = rig.file.gantry
    speed = g.profile_velocity * VELOCITY_UNIT_REV_S * g.ticks_per_rev
    acceleration = g.profile_acceleration * ACCELERATION_UNIT_REV_S2 * g.ticks_per_rev
    with SimRig(speed_factor=2.0) as sim, devices_on(sim, rig) as devices:
        devices.connect()
        servo = sim.bus.servo(1)
        for distance in (1000, 60):  # a trapezoid, and a move too short to reach cruising speed
            start = servo.present_position()
            goals = len(sim.bus.goals)
            devices.gantry.move_to((start + distance, 1024))  # a sync write: no reply to wait for
            deadline = time.monotonic() + 5.0
            while len(sim.bus.goals) < goals + 2:  # until both servos have taken their goal
                assert time.monotonic() < deadline, "the servos never took the goals"
                time.sleep(0.001)
            t0 = next(g.time_s for g in sim.bus.goals[goals:] if g.servo_id == 1)
            # the arrival, bracketed between the servo's clock before a reading that saw it still on the
            # way and after one that saw it at rest: however sparse a busy machine makes the readings,
            # the model must fall within (2 %: the clock is read a moment apart from the state)
            on_the_way = t0
            while True:
                before = servo.clock()
                if servo.present_position() == start + distance and not servo.get("moving"):
                    at_rest = servo.clock()
                    break
                on_the_way = before
                time.sleep(0.001)
            model = trapezoid_s(distance, speed, acceleration)
            assert on_the_way - t0 <= 1.02 * model
            assert 0.98 * model <= at_rest - t0
            assert at_rest - on_the_way < 0.2 * model  # the bracket is narrow enough to say something


def test_park_policy_hold_keeps_the_torque(sim, rig):
    holding = replace(
        rig, file=rig.file.model_copy(update={"gantry": rig.file.gantry.model_copy(update={"park": "hold"})})
    )
    with devices_on(sim, holding) as devices:
        devices.connect()
        devices.gantry.move_to((1500, 1300))  # stopped mid-move: it must come to rest and hold there
    assert all(s.get("torque_enable") == 1 for s in sim.bus.servos)
    assert all(s.get("moving") == 0 for s in sim.bus.servos)
    assert not sim.turntable.stage.lamp
    assert devices.safe.ok, devices.safe.sentence()
    assert devices.safe.steps[-1].detail == "holding, not moving (read back)"


def test_the_safe_state_outlasts_a_burst_of_modbus_faults(sim, rig):
    """Five Modbus requests in a row go unanswered as the run ends, more than the driver's own four
    tries: the lamp step is tried again on a fresh link, and the lamp is confirmed off."""
    with devices_on(sim, rig) as devices:
        devices.connect()
        devices.lamp.set(True)
        sim.turntable.faults.no_reply = 5
    assert devices.safe.ok, devices.safe.sentence()
    assert not sim.turntable.stage.lamp
