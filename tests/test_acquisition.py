"""Acquisition on the simulated rig: plan → motion → Mitsuba frames → session; resumed without repeats."""

import contextlib
import json
import math
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.errors import DeviceFault, DeviceTimeout, HardwareAlarm, SettleTimeout
from drivers.genicam_camera import GenICamCamera, GenICamConfig
from hlr_lab.acquisition.poses import Bracketing, acquire
from hlr_lab.cli.main import main
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.instrument.devices import open_devices
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.segment import segment
from hlr_lab.session.frames import load_frame
from hlr_lab.session.journal import JOURNAL, read_journal
from sim.camera import GantryGeometry
from sim.dynamixel.servo import OVERLOAD
from sim.render.camera import CameraSpec
from sim.render.scene import Material, SceneSpec
from sim.render.sensor import SensorModel
from sim.rig import SimRig
from tests.cameras import half_size_camera

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames


@contextlib.contextmanager
def world_of(plan_file, power=1.0, sensor=None):
    """The planned pebble under a point lamp of power Φ, photographed at 640×480."""
    _, _, obj, m = plan_file
    seg = segment(obj.mesh)
    scene = SceneSpec(
        obj.mesh.vertices,
        obj.mesh.faces,
        seg.face_labels,
        [Material((0.5, 0.4, 0.3), (0.3, 0.3, 0.3), 40.0)] * len(seg.regions),
        m,
        power=power,
    )
    c = half_size_camera()
    spec = CameraSpec(c.matrix, c.distortion, c.rotation, c.translation, c.width, c.height)
    with SimRig(speed_factor=40.0, scene=scene, camera=spec, sensor=sensor, spp=2) as world:
        yield world


@pytest.fixture
def sim_world(plan_file):
    with world_of(plan_file) as world:
        yield world


def run(world, rig, plan, session, bracket=None, progress=None, object_window=None, settle_timeout_s=60.0,
        reply_timeout_s=20.0, safe_states=None):  # fmt: skip
    """acquire() on the simulated rig through the real drivers; ``safe_states`` (a list) gets what the
    devices confirmed of the safe state at the end."""
    targets = motion_targets(plan, rig)
    e = world.endpoints
    devices = open_devices(rig, gantry_port=e.dynamixel, stage_address=e.modbus)
    with contextlib.ExitStack() as stack:
        stack.callback(lambda: safe_states.append(devices.safe) if safe_states is not None else None)
        stack.enter_context(devices)
        devices.connect()
        camera = GenICamCamera(GenICamConfig(e.camera, frame_timeout_s=reply_timeout_s))
        try:
            return acquire(
                plan,
                targets,
                Instruments(devices.stage, devices.gantry, camera, devices.lamp, (devices.gantry,)),
                session,
                bracket=bracket or Bracketing(),
                progress=progress or (lambda _: None),
                object_window=object_window,
                settle_timeout_s=settle_timeout_s,
            )
        finally:
            camera.close()


def test_acquire_then_resume(sim_world, rig, plan_file, tmp_path):
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:2]})
    bracket = len(plan.poses[0].exposures_s)
    first = run(sim_world, rig, plan, tmp_path)
    assert (first.taken, first.already_done) == (2 * bracket, 0)
    frames = [e for e in read_journal(tmp_path / JOURNAL) if e["event"] == "frame"]
    assert [(e["pose"], e["exposure_index"]) for e in frames] == [
        (p.id, k) for p in plan.poses for k in range(bracket)
    ]
    truth = GantryGeometry()
    for event in frames[::bracket]:
        pixels = load_frame(tmp_path, event)
        assert pixels.shape == (480, 640, 3)
        assert pixels.max() > 100  # lit: the lamp was on for the capture
        pose = next(p for p in plan.poses if p.id == event["pose"])
        sidecar = json.loads((tmp_path / event["sidecar"]).read_text())
        ticks = sidecar["measured"]["gantry_ticks"]
        # the simulated servos sit at 30 °C and warm by 3 °C with torque on
        assert sidecar["temperatures_c"] == {"azimuth": 33.0, "elevation": 33.0}
        # ½ tick rounding + 2 ticks settle tolerance per axis: 1.6 mm on the 0.30 m arm (test_devices)
        assert np.linalg.norm(truth.light_position(*ticks) - pose.light.position_m) < 1.7e-3
    assert not sim_world.turntable.stage.lamp  # off between poses and at the end

    again = run(sim_world, rig, plan, tmp_path)
    assert (again.taken, again.already_done) == (0, 2 * bracket)

    (tmp_path / frames[1]["file"]).unlink()  # a frame lost after the fact is taken again, under a new name
    third = run(sim_world, rig, plan, tmp_path)
    assert (third.taken, third.retaken) == (1, [frames[1]["file"]])
    events = read_journal(tmp_path / JOURNAL)
    latest = [e for e in events if e["event"] == "frame"][-1]
    assert latest["file"].endswith("_e1_a2.png")
    assert [e["event"] for e in events].count("run_start") == 3
    assert events[-1]["event"] == "run_end"
    # the GigE Vision camera's link over the run (its own counters, since it was opened): the frame's
    # packets arrived, none went missing
    stream = events[-1]["camera_stream"]
    assert stream["n_received_packets"] >= 640 * 480 * 3 * 2 // 9000
    assert stream["n_missing_packets"] == 0


def test_no_goal_outside_the_limits_ever_reaches_the_devices(sim_world, rig, plan_file, tmp_path):
    """Every goal the simulated servos and stage received during a whole run (the final stop included) lies
    within the rig's limits; a plan with a pose outside them sends nothing at all."""
    plan = read_plan(plan_file[0])
    run(sim_world, rig, plan, tmp_path / "a")
    (az_lo, az_hi), (el_lo, el_hi) = rig.gantry.servo_limits
    limits = dict(zip(rig.gantry.servo_ids, [(az_lo, az_hi), (el_lo, el_hi)], strict=True))
    goals = sim_world.bus.goals
    assert len(goals) >= 2 * len(plan.poses)
    assert all(limits[g.servo_id][0] <= g.goal <= limits[g.servo_id][1] for g in goals)
    steps = sorted(rig.turntable_kinematics.steps_for(d) for d in rig.turntable_limits_deg)
    moves = sim_world.turntable.stage.moves
    assert len(moves) == len(plan.poses)
    assert all(steps[0] <= m <= steps[1] for m in moves)

    beyond = plan.poses[0].model_copy(update={"turntable_deg": rig.turntable_limits_deg[1] + 5.0})
    bad = plan.model_copy(update={"poses": [plan.poses[0], beyond]})
    sent = (len(goals), len(moves))  # both lists grow in place
    with pytest.raises(InputError, match=r"poses\[1\]\.turntable_deg"):
        run(sim_world, rig, bad, tmp_path / "b")
    assert (len(sim_world.bus.goals), len(sim_world.turntable.stage.moves)) == sent


def test_cli_acquire_dry_run_resume_and_changed_plan(builtin_plan, tmp_path, capsys):
    plan_path = builtin_plan
    session = tmp_path / "session"
    common = ["acquire", "--plan", str(plan_path), "--sim", "--out", str(session)]
    assert main([*common, "--dry-run"]) == 0
    assert "within limits" in capsys.readouterr().err
    assert not session.exists()  # a dry run writes nothing

    assert main([*common, "--speed-factor", "40"]) == 0
    plan = read_plan(plan_path)
    frames = sum(len(p.exposures_s) for p in plan.poses)
    summary = capsys.readouterr().err
    assert re.search(rf"frames taken\s+│\s+{frames} ", summary)
    assert re.search(rf"poses moved to\s+│\s+{len(plan.poses)} ", summary)
    assert re.search(r"camera packets \(received / resent / missing\)\s+│\s+[\d,]+ / [\d,]+ / 0 ", summary)
    # the last line: what the devices confirmed, as the journal's safe_state line has it
    last = summary.strip().splitlines()[-1]
    assert last.startswith("the rig is safe: "), last
    assert "lamp" in last
    assert "turntable" in last
    assert main([*common, "--speed-factor", "40"]) == 0
    summary = capsys.readouterr().err
    assert re.search(r"frames taken\s+│\s+0 ", summary)
    assert re.search(rf"frames already done\s+│\s+{frames} ", summary)
    log = (session / "acquire.log").read_text()  # both runs logged to the session
    assert log.count("run summary") == 2
    assert log.count(f"{plan.poses[0].id}: settled at") == 1

    other = tmp_path / "other-plan.json"
    write_plan(other, plan.model_copy(update={"poses": plan.poses[:1]}))
    assert main(["acquire", "--plan", str(other), "--sim", "--out", str(session)]) == 1
    assert "started with another plan" in capsys.readouterr().err
    events = read_journal(session / JOURNAL)
    assert sum(e["event"] == "frame" for e in events) == frames  # the refused run added nothing


def test_cli_acquire_refuses_a_scene_without_sim(plan_file, capsys):
    assert main(["acquire", "--plan", str(plan_file[0]), "--rig", "x.toml", "--scene", "s.toml"]) == 1
    assert "--scene" in capsys.readouterr().err


def test_a_world_that_does_not_match_the_plan_creates_no_session(plan_file, tmp_path, capsys):
    """plan_file plans a finer pebble than builtin:pebble: the simulated world must refuse it, early."""
    session = tmp_path / "session"
    assert main(["acquire", "--plan", str(plan_file[0]), "--sim", "--out", str(session)]) == 1
    assert "has changed since the plan was made" in capsys.readouterr().err
    assert not session.exists()


def test_a_killed_run_stops_safely_and_resumes_without_repeats(builtin_plan, tmp_path):
    """`kill` mid-run: exit 130, the journal says why, every journaled frame is intact; the same command
    again finishes the plan, each frame exactly once."""
    session = tmp_path / "session"
    command = ["acquire", "--plan", str(builtin_plan), "--sim", "--out", str(session)]
    child = subprocess.Popen(
        [sys.executable, "-m", "hlr_lab.cli.main", *command, "--speed-factor", "5"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not any(e["event"] == "frame" for e in read_journal(session / JOURNAL)):
            assert child.poll() is None, child.stderr.read()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        child.send_signal(signal.SIGTERM)
        assert child.wait(timeout=30) == 130
        assert "interrupted" in child.stderr.read()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stderr.close()
    events = read_journal(session / JOURNAL)
    assert events[-2] == {**events[-2], "event": "stopped", "reason": "signal SIGTERM"}
    assert events[-1]["event"] == "safe_state"
    assert events[-1]["ok"]
    assert [s["device"] for s in events[-1]["steps"]] == ["lamp", "turntable", "gantry"]
    frames = [e for e in events if e["event"] == "frame"]
    assert all(load_frame(session, e) is not None for e in frames)

    assert main([*command, "--speed-factor", "40"]) == 0
    frames = [e for e in read_journal(session / JOURNAL) if e["event"] == "frame"]
    keys = [(e["pose"], e["exposure_index"]) for e in frames]
    plan = read_plan(builtin_plan)
    assert sorted(keys) == sorted((p.id, k) for p in plan.poses for k in range(len(p.exposures_s)))


@pytest.mark.parametrize("seed", [1, 2])
def test_a_kill_9_at_a_random_point_resumes_to_the_same_frames_without_duplicates(
    builtin_plan, tmp_path, seed
):
    """SIGKILL (no handler runs) once the journal has a random number of lines; the same command again
    ends with every planned frame journaled exactly once, each intact."""
    session = tmp_path / "session"
    command = ["acquire", "--plan", str(builtin_plan), "--sim", "--out", str(session)]
    plan = read_plan(builtin_plan)
    expected = sorted((p.id, k) for p in plan.poses for k in range(len(p.exposures_s)))
    # run_start, then a pose line and its frames per pose: kill somewhere before the last frame
    lines = random.Random(seed).randint(1, len(expected) + len(plan.poses))
    child = subprocess.Popen(
        [sys.executable, "-m", "hlr_lab.cli.main", *command, "--speed-factor", "5"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while not (session / JOURNAL).exists() or len(read_journal(session / JOURNAL)) < lines:
            assert child.poll() is None
            assert time.monotonic() < deadline
            time.sleep(0.01)
        child.send_signal(signal.SIGKILL)
        assert child.wait(timeout=30) == -signal.SIGKILL
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert main([*command, "--speed-factor", "40"]) == 0
    frames = [e for e in read_journal(session / JOURNAL) if e["event"] == "frame"]
    assert sorted((e["pose"], e["exposure_index"]) for e in frames) == expected
    assert all(load_frame(session, e) is not None for e in frames)


def test_adaptive_bracketing_adds_shorter_frames_until_nothing_clips(plan_file, rig, tmp_path):
    """A lamp bright enough to clip the highlight even in the shortest planned exposure."""
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    planned = len(plan.poses[0].exposures_s)
    with world_of(plan_file, power=300.0) as world:
        first = run(world, rig, plan, tmp_path)
        frames = [e for e in read_journal(tmp_path / JOURNAL) if e["event"] == "frame"]
        sidecars = [json.loads((tmp_path / e["sidecar"]).read_text()) for e in frames]
        assert sidecars[planned - 1]["clipped_pixels"] > 0  # the planned bracket was not enough
        extra = sidecars[planned:]
        assert 1 <= len(extra) <= 3
        assert first.taken == planned + len(extra)
        assert all(e["adaptive"] for e in extra)
        assert extra[-1]["clipped_pixels"] == 0  # the HDR merge has an unclipped value everywhere
        exposures = [e["exposure_s"] for e in sidecars]
        np.testing.assert_allclose(np.divide(exposures[planned - 1 : -1], exposures[planned:]), 4.0)
        # complete: a resumed run neither moves nor captures
        again = run(world, rig, plan, tmp_path)
        assert (again.taken, again.already_done) == (0, planned + len(extra))


def test_clipping_counts_only_inside_the_object_window(plan_file, rig, tmp_path):
    """The same clipping lamp, but the window says the object is elsewhere (as if the clipped pixels were
    a bright background): no shorter frames. A window of another size than the frames is refused."""
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    with world_of(plan_file, power=300.0) as world:
        elsewhere = np.zeros((480, 640), bool)
        outcome = run(world, rig, plan, tmp_path / "a", object_window=lambda _: elsewhere)
        assert outcome.taken == len(plan.poses[0].exposures_s)
        frames = [e for e in read_journal(tmp_path / "a" / JOURNAL) if e["event"] == "frame"]
        assert all(e["clipped_pixels"] == 0 for e in frames)
        with pytest.raises(InputError, match=r"delivers 640×480 frames, the rig file says 1280×960"):
            run(world, rig, plan, tmp_path / "b", object_window=lambda _: np.ones((960, 1280), bool))


def test_adaptive_bracketing_stops_at_its_limit(plan_file, rig, tmp_path):
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    with world_of(plan_file, power=1e6) as world:  # clips at any exposure the bracket will reach
        outcome = run(world, rig, plan, tmp_path, bracket=Bracketing(max_extra=1))
        assert outcome.taken == len(plan.poses[0].exposures_s) + 1
        assert run(world, rig, plan, tmp_path, bracket=Bracketing(max_extra=1)).taken == 0


def test_dark_frames_record_the_ambient_light(plan_file, rig, tmp_path):
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    exposures = plan.poses[0].exposures_s
    sensor = SensorModel(ambient=0.5)  # stray light everywhere: 0.5 · t · 4095 DN
    with world_of(plan_file, sensor=sensor) as world:
        outcome = run(world, rig, plan, tmp_path, bracket=Bracketing(dark_frames=True))
        assert outcome.taken == 2 * len(exposures)
        frames = [e for e in read_journal(tmp_path / JOURNAL) if e["event"] == "frame"]
        darks = {e["exposure_index"]: e for e in frames if e["dark"]}
        lit = {e["exposure_index"]: e for e in frames if not e["dark"]}
        assert sorted(darks) == sorted(lit) == list(range(len(exposures)))
        for k, t in enumerate(exposures):
            dark, bright = load_frame(tmp_path, darks[k]), load_frame(tmp_path, lit[k])
            # a million pixels average photon and read noise far below the 5 % allowed here
            assert dark.mean() == pytest.approx(0.5 * t * sensor.sensitivity, rel=0.05)
            assert bright.max() > dark.max()
        assert run(world, rig, plan, tmp_path, bracket=Bracketing(dark_frames=True)).taken == 0


def test_a_dropping_camera_link_is_retried_and_journaled(plan_file, rig, tmp_path):
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    with world_of(plan_file) as world:
        world.gige.faults.drop_for_good = 2  # two frames lose a packet that no resend brings back
        outcome = run(world, rig, plan, tmp_path)
    assert outcome.taken == len(plan.poses[0].exposures_s)
    events = read_journal(tmp_path / JOURNAL)
    cut = [e for e in events if e["event"] == "retry" and "frame incomplete" in e["error"]]
    assert len(cut) == 2
    assert all(load_frame(tmp_path, e) is not None for e in events if e["event"] == "frame")


def _inject_on_second_pose(inject):
    """A progress callback that injects a fault as the rig starts moving to the second pose."""

    def progress(step):
        if (step.index, step.action) == (1, "moving"):
            inject()

    return progress


def _places(steps: list[int]) -> list[int]:
    """The places a stage was sent to, a start repeated in place counted once."""
    return [x for k, x in enumerate(steps) if k == 0 or x != steps[k - 1]]


LINK_FAULTS = {  # fault → the logger of the driver that must retry it
    "servo no reply": (lambda w: setattr(w.bus.fault(2), "drop_replies", 1), "drivers.dynamixel"),
    "servo corrupted byte": (lambda w: setattr(w.bus.fault(1), "corrupt_replies", 1), "drivers.dynamixel"),
    "Modbus no reply": (lambda w: setattr(w.turntable.faults, "no_reply", 1), "drivers.modbus_stage"),
    "Modbus disconnect": (lambda w: w.turntable.disconnect_clients(), "drivers.modbus_stage"),
}


@pytest.mark.parametrize("fault", LINK_FAULTS)
def test_a_link_fault_is_retried_journaled_and_the_run_completes(fault, plan_file, rig, tmp_path):
    """One lost, corrupted or disconnected exchange while moving to the second pose: retried with backoff,
    journaled, every frame taken; the stage went to each pose's place once (a start whose reply was lost
    and is sent again names the same absolute place: no extra motion)."""
    inject, source = LINK_FAULTS[fault]
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:2]})
    targets = motion_targets(plan, rig)
    with world_of(plan_file) as world:
        outcome = run(world, rig, plan, tmp_path, progress=_inject_on_second_pose(lambda: inject(world)))
        moves = world.turntable.stage.moves
        assert _places(moves) == _places([t.turntable_steps for t in targets])
        assert len(moves) <= len(targets) + 1
    assert outcome.taken == sum(len(p.exposures_s) for p in plan.poses)
    events = read_journal(tmp_path / JOURNAL)
    retries = [e for e in events if e["event"] == "retry"]
    # the injected fault is retried where it was injected; a host stalled by other work for longer than
    # the rig file's reply timeout could add a genuine retry elsewhere, journaled and counted like any other
    injected = [e for e in retries if (e["pose"], e["source"]) == (plan.poses[1].id, source)]
    assert injected, retries
    assert "retrying (1 of 3)" in injected[0]["error"]
    assert events[-1]["event"] == "run_end"
    assert outcome.retries == events[-1]["retries"] == len(retries)
    assert all(load_frame(tmp_path, e) is not None for e in events if e["event"] == "frame")


STOPPING_FAULTS = {  # fault → (how to inject it, the error raised, what the message and journal say)
    "Modbus exception 4": (
        lambda w: setattr(w.turntable.faults, "exception", 1),
        DeviceFault,
        r"turntable on .*exception 4",
    ),
    "servo overload": (
        lambda w: w.bus.servo(2).hardware_fault(OVERLOAD),
        HardwareAlarm,
        r"elevation \(id 2\).*overload",
    ),
}


@pytest.mark.parametrize("fault", STOPPING_FAULTS)
def test_a_device_fault_mid_run_stops_safely(fault, plan_file, rig, tmp_path):
    """While moving to the second pose the drive answers exception 4 (device failure), or the elevation
    servo overloads: not link faults, so no retry. The run stops with the device named, the journal says
    why, the lamp is off, no servo holds torque, and the first pose's frames are kept."""
    inject, error, words = STOPPING_FAULTS[fault]
    plan = read_plan(plan_file[0])
    assert len(plan.poses) >= 2
    safe = []
    with world_of(plan_file) as world:
        with pytest.raises(error, match=words):
            run(
                world,
                rig,
                plan,
                tmp_path,
                progress=_inject_on_second_pose(lambda: inject(world)),
                safe_states=safe,
            )
        assert not world.turntable.stage.lamp
        assert all(s.get("torque_enable") == 0 for s in world.bus.servos)
    assert safe[0].ok, safe[0].sentence()  # an overloaded servo has its torque off: confirmed, not "NOT SAFE"
    events = read_journal(tmp_path / JOURNAL)
    assert events[-1]["event"] == "stopped"
    assert re.search(words, events[-1]["reason"])
    assert events[-1]["frames_taken"] == len(plan.poses[0].exposures_s)
    assert {e["pose"] for e in events if e["event"] == "frame"} == {plan.poses[0].id}
    assert not [e for e in events if e["event"] == "retry" and re.search(words, e["error"])]


def test_a_rig_without_a_lamp_relay_is_refused_before_anything_opens(plan_file, tmp_path, capsys):
    text = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(text[: text.index("[lamp]")])
    session = tmp_path / "session"
    assert main(["acquire", "--plan", str(plan_file[0]), "--rig", str(rig_file), "--out", str(session)]) == 1
    assert "add a [lamp] section" in capsys.readouterr().err
    assert not session.exists()


def _slip_during(world, pose_index: int, frame: int, ticks: int, hold_s: float, stuck: bool = False):
    """A progress callback that knocks the elevation servo ``ticks`` off just before frame ``frame`` of
    pose ``pose_index`` is exposed, for ``hold_s`` of the simulated bus's time (``stuck``: and it
    follows no goal any more)."""
    seen = []

    def progress(step):
        if step.index == pose_index and step.action.startswith("exposure"):
            seen.append(step.action)
            if len(seen) == frame + 1:
                world.bus.servo(2).slip(ticks, hold_s=hold_s)
                world.bus.servo(2).stuck = stuck

    return progress


def test_a_frame_exposed_while_an_axis_moved_is_retaken_after_settling(plan_file, rig, tmp_path):
    """The elevation axis is knocked 40 ticks off during an exposure and comes back a moment later: that
    frame is not journaled; the rig settles anew and takes it again. Every journaled frame was rendered
    where its sidecar says the axes were (the simulator's own record, in the sidecar's camera block)."""
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    bracket = len(plan.poses[0].exposures_s)
    with world_of(plan_file) as world:
        outcome = run(world, rig, plan, tmp_path, progress=_slip_during(world, 0, 1, 40, hold_s=20.0))
    assert outcome.taken == bracket
    events = read_journal(tmp_path / JOURNAL)
    assert [e["event"] for e in events].count("pose") == 2  # settled, then settled anew
    retakes = [e for e in events if e["event"] == "retry" and "servo was at" in e["error"]]
    assert len(retakes) == 1
    assert "elevation servo was at" in retakes[0]["error"]
    for e in (e for e in events if e["event"] == "frame"):
        sidecar = json.loads((tmp_path / e["sidecar"]).read_text())
        rendered_at, measured = sidecar["camera"]["servo_ticks"], sidecar["measured"]["gantry_ticks"]
        assert np.abs(np.subtract(rendered_at, measured)).max() <= 2


def test_an_axis_that_stays_off_stops_the_run_with_no_frame_journaled_from_there(plan_file, rig, tmp_path):
    """Knocked off for good (a slipped coupling): the frame is dropped, settling anew times out, the run
    stops safely and the journal holds no frame exposed away from its recorded place."""
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:1]})
    with world_of(plan_file) as world:
        with pytest.raises(SettleTimeout, match="not settled"):
            run(world, rig, plan, tmp_path, progress=_slip_during(world, 0, 1, 52, math.inf, stuck=True),
                settle_timeout_s=1.0)  # fmt: skip
        assert not world.turntable.stage.lamp
    events = read_journal(tmp_path / JOURNAL)
    assert [e["exposure_index"] for e in events if e["event"] == "frame"] == [0]
    assert events[-1]["event"] == "stopped"


def test_a_camera_that_stops_answering_times_out_into_a_safe_stop(plan_file, rig, tmp_path):
    """The camera hangs while a frame is requested (lamp on): after the reply timeout and its retries the
    run stops, the lamp is off and no servo holds torque."""
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:2]})
    with world_of(plan_file) as world:
        hang = _inject_on_second_pose(lambda: setattr(world.gige.faults, "silent", True))
        with pytest.raises(DeviceTimeout, match="is the camera hung or unplugged"):
            run(world, rig, plan, tmp_path, progress=hang, reply_timeout_s=0.5)
        assert not world.turntable.stage.lamp
        assert all(s.get("torque_enable") == 0 for s in world.bus.servos)
    events = read_journal(tmp_path / JOURNAL)
    assert events[-1]["event"] == "stopped"
    assert {e["pose"] for e in events if e["event"] == "frame"} == {plan.poses[0].id}


def _lamp_believed_and_true(session, rig) -> np.ndarray:
    """Per frame, how far the lamp the simulator rendered was from where ``rig`` puts it (m)."""
    misses = []
    for e in (e for e in read_journal(session / JOURNAL) if e["event"] == "frame"):
        sidecar = json.loads((session / e["sidecar"]).read_text())
        believed = rig.gantry.kinematics.light_position(tuple(sidecar["measured"]["gantry_ticks"]))
        misses.append(np.linalg.norm(believed - np.asarray(sidecar["camera"]["light_position_m"])))
    return np.array(misses)


def test_the_simulated_world_can_be_a_rig_other_than_the_one_believed(builtin_plan, rig, tmp_path, capsys):
    """--true-rig builds the world from another rig file: hlr-lab, believing the drawing, puts the lamp
    millimetres from where it really was (zero ticks 14/17 off, arm +3 mm, axis tilted); without it, and
    with --rig naming the true file beside --sim, belief and world agree."""
    from hlr_lab.rig.file import load_rig

    common = ["acquire", "--plan", str(builtin_plan), "--sim", "--speed-factor", "40"]
    assert main([*common, "--true-rig", "builtin:bench-offsets", "--out", str(tmp_path / "off")]) == 0
    assert _lamp_believed_and_true(tmp_path / "off", rig).min() > 5e-3
    assert main([*common, "--out", str(tmp_path / "drawn")]) == 0
    assert _lamp_believed_and_true(tmp_path / "drawn", rig).max() < 1e-9
    true_file = tmp_path / "bench.toml"
    true_file.write_text(
        (Path(__file__).resolve().parents[1] / "sim" / "data" / "bench-offsets.toml").read_text()
    )
    plan = tmp_path / "bench-plan.json"  # a plan for that rig: the drawing's plan is 3 mm off its sphere
    assert main(["plan", "--mesh", "builtin:pebble", "--rig", str(true_file), "-o", str(plan)]) in (0, 3)
    known = ["acquire", "--plan", str(plan), "--sim", "--rig", str(true_file), "--speed-factor", "40"]
    assert main([*known, "--out", str(tmp_path / "known")]) == 0
    assert _lamp_believed_and_true(tmp_path / "known", load_rig(true_file)).max() < 1e-9
    assert main([*common[:4], "--true-rig", "builtin:no-such-rig", "--out", str(tmp_path / "x")]) == 1
    assert (
        "no such built-in true rig; known: builtin:bench-night, builtin:bench-offsets, builtin:bench-other"
        in capsys.readouterr().err
    )


def test_bracketing_and_the_hdr_merge_call_the_same_values_clipped():
    """Top − 1 counts as clipped for both (the merge leaves it out, so bracketing must take a shorter
    exposure for it); top − 2 for neither."""
    import numpy as np

    from hlr_lab.acquisition.poses import _clipped
    from hlr_lab.geometry.clipping import clipped

    pixels = np.zeros((2, 2, 3), np.uint16)
    pixels[0, 0, 1] = 4094  # 12-bit: top − 1
    pixels[1, 1, 2] = 4093  # top − 2
    assert _clipped(pixels, 12, None) == 1
    assert clipped(pixels.reshape(-1, 3), 12, channels=True).tolist() == [True, False, False, False]
    assert _clipped(pixels[..., 2], 12, None) == 0  # a mono frame: value by value
