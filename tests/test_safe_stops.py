"""Stops that leave the rig safe, checked from outside: ``hlr-lab acquire`` runs as its own process against
simulated devices served by this one (as a real bench is separate from the computer), and afterwards the
devices are read with the vendors' client libraries (dynamixel-sdk, pymodbus), never through hlr-lab.

HLR_LAB_STOP_TRIALS sets how many random moments each kind of stop is tried at (2 here; 8 or more in a
nightly-sized run: 24 stops), HLR_LAB_STOP_SEED which moments.
"""

from __future__ import annotations

import contextlib
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler
from pymodbus.client import ModbusTcpClient

from benchmarks.acquire import repeated_poses
from drivers.dynamixel import UrlPortHandler
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.session.journal import JOURNAL, read_journal
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS
from sim.rig import SimRig
from sim.turntable import register_map as rm
from worlds.plan_world import rig_file_text, sim_scene, world_geometry

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

TRIALS = int(os.environ.get("HLR_LAB_STOP_TRIALS", "2"))
SEED = os.environ.get("HLR_LAB_STOP_SEED", "0")  # other moments in another nightly run
TORQUE_ENABLE, MOVING = 64, 122


@pytest.fixture(scope="module")
def long_plan(builtin_plan, tmp_path_factory) -> Path:
    """builtin:pebble's plan cycled to 12 poses, so that a stop lands mid-run."""
    path = tmp_path_factory.mktemp("long") / "plan.json"
    write_plan(path, repeated_poses(read_plan(builtin_plan), 12))
    return path


@contextlib.contextmanager
def bench(plan_path: Path, rig, folder: Path, speed_factor: float = 4.0):
    """The simulated devices of ``plan_path``'s world, and a rig file naming their endpoints: (world, rig
    file)."""
    scene = sim_scene(read_plan(plan_path), plan_path, None)
    with SimRig(scene=scene, speed_factor=speed_factor, spp=2, **world_geometry(rig)) as world:
        e = world.endpoints
        rig_file = folder / "rig.toml"
        rig_file.write_text(rig_file_text(e.dynamixel, e.modbus, e.camera, reply_timeout_s=5.0))
        yield world, rig_file


def start_acquire(plan: Path, rig_file: Path, session: Path) -> subprocess.Popen:
    command = ["acquire", "--plan", str(plan), "--rig", str(rig_file), "--out", str(session)]
    return subprocess.Popen(
        [sys.executable, "-m", "hlr_lab.cli.main", *command],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for_frames(child: subprocess.Popen, session: Path, n: int = 1, timeout_s: float = 90) -> None:
    deadline = time.monotonic() + timeout_s
    while sum(e["event"] == "frame" for e in read_journal(session / JOURNAL)) < n:
        assert child.poll() is None, child.stderr.read()
        assert time.monotonic() < deadline, "no frame in time"
        time.sleep(0.02)


def finish(child: subprocess.Popen, timeout_s: float = 60) -> tuple[int, str]:
    try:
        status = child.wait(timeout=timeout_s)
        return status, child.stderr.read()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stderr.close()


def device_state(world: SimRig) -> dict:
    """What the simulated devices report, asked through dynamixel-sdk and pymodbus."""
    port = UrlPortHandler(world.endpoints.dynamixel, CLIENT_REPLY_TIMEOUT_MS)
    assert port.openPort()
    ph = PacketHandler(2.0)
    try:
        servos = {}
        for sid in world.endpoints.servo_ids:
            torque, r1, _ = ph.read1ByteTxRx(port, sid, TORQUE_ENABLE)
            moving, r2, _ = ph.read1ByteTxRx(port, sid, MOVING)
            assert r1 == r2 == COMM_SUCCESS
            servos[sid] = {"torque": torque, "moving": moving}
    finally:
        port.closePort()
    host, _, tcp = world.endpoints.modbus.rpartition(":")
    client = ModbusTcpClient(host, port=int(tcp))
    assert client.connect()
    try:
        lamp = client.read_coils(rm.LAMP_COIL, count=1, device_id=rm.RELAY_UNIT).bits[0]
        status = client.read_holding_registers(rm.STATUS, count=2, device_id=rm.STAGE_UNIT).registers[1]
    finally:
        client.close()
    return {"servos": servos, "lamp": bool(lamp), "stage_moving": bool(status & rm.MOVE)}


SAFE = {"servos": {1: {"torque": 0, "moving": 0}, 2: {"torque": 0, "moving": 0}}, "lamp": False,
        "stage_moving": False}  # fmt: skip

STOPS = {"SIGTERM": [signal.SIGTERM], "SIGINT": [signal.SIGINT], "double": [signal.SIGTERM, signal.SIGINT]}


@pytest.mark.slow
@pytest.mark.parametrize("kind", STOPS)
def test_a_signal_at_a_random_moment_leaves_the_rig_safe_and_says_so(kind, long_plan, rig, tmp_path):
    """SIGTERM, SIGINT, or SIGTERM then SIGINT up to 50 ms later, at random moments of a run: exit 130,
    the journal ends with the stop and the safe state the devices confirmed, and the devices, asked
    afterwards through their vendors' libraries, have torque off, nothing moving and the lamp off."""
    rng = random.Random(f"{kind}-stops-{SEED}")
    with bench(long_plan, rig, tmp_path) as (world, rig_file):
        for trial in range(TRIALS):
            session = tmp_path / f"session-{trial}"
            child = start_acquire(long_plan, rig_file, session)
            wait_for_frames(child, session)
            time.sleep(rng.uniform(0.0, 1.5))
            for i, sig in enumerate(STOPS[kind]):
                time.sleep(rng.uniform(0.001, 0.05) * (i > 0))  # the second lands in the stop, or after
                child.send_signal(sig)
            status, err = finish(child)
            assert status == 130, err
            assert "the rig is safe" in err
            assert "NOT SAFE" not in err
            events = read_journal(session / JOURNAL)
            assert [e["event"] for e in events[-2:]] == ["stopped", "safe_state"]
            assert events[-1]["ok"]
            assert len(events[-1]["steps"]) == 3
            assert device_state(world) == SAFE, f"trial {trial}: {err}"


@pytest.mark.slow
def test_a_lost_device_is_one_line_naming_it_and_what_could_not_be_made_safe(long_plan, rig, tmp_path):
    """The simulator dies mid-run (as a cable is pulled): exit status 1, one error line naming the lost
    device and saying that the rig is NOT confirmed safe, no internal error, no traceback."""
    with bench(long_plan, rig, tmp_path) as (world, rig_file):
        session = tmp_path / "session"
        child = start_acquire(long_plan, rig_file, session)
        wait_for_frames(child, session)
        world.close()
        status, err = finish(child, timeout_s=90)
    assert status == 1, err
    after_table = err[err.index("starting session") :].splitlines()[2:]
    lines = [line for line in after_table if line.strip()]
    assert len(lines) == 1, err
    assert re.match(r"error: stopped: (camera|gantry|turntable|lamp relay) ", lines[0]), lines[0]
    assert "NOT SAFE" in lines[0]
    assert "internal error" not in err
    assert "Traceback" not in err
    events = read_journal(session / JOURNAL)
    assert [e["event"] for e in events[-2:]] == ["stopped", "safe_state"]
    assert not events[-1]["ok"]


@pytest.mark.slow
def test_a_second_run_on_the_same_session_or_devices_is_refused_naming_the_first(long_plan, rig, tmp_path):
    """While one run holds a session and the rig, a second run on the same session, and a third on the
    same devices with another session, are refused with the first run's PID; neither writes anything."""
    with bench(long_plan, rig, tmp_path) as (_world, rig_file):
        session = tmp_path / "session"
        first = start_acquire(long_plan, rig_file, session)
        try:
            wait_for_frames(first, session)
            frames = len(read_journal(session / JOURNAL))
            same_session = start_acquire(long_plan, rig_file, session)
            status, err = finish(same_session)
            assert status == 1
            assert f"session {session} is in use by PID {first.pid}" in err
            other = tmp_path / "other"
            same_rig = start_acquire(long_plan, rig_file, other)
            status, err = finish(same_rig)
            assert status == 1
            assert f"is in use by PID {first.pid}" in err
            assert not other.exists()
            assert len(read_journal(session / JOURNAL)) >= frames
        finally:
            first.send_signal(signal.SIGTERM)
            status, err = finish(first)
        assert status == 130, err
        events = read_journal(session / JOURNAL)
        keys = [(e["pose"], e["exposure_index"]) for e in events if e["event"] == "frame"]
        assert len(keys) == len(set(keys))  # no frame taken twice
        assert events[-1]["event"] == "safe_state"
