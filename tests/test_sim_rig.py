"""The simulated rig as drivers meet it: endpoints, real client libraries, a clean stop."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

from dynamixel_sdk import COMM_SUCCESS, PacketHandler
from pymodbus.client import ModbusTcpClient

from drivers.dynamixel import UrlPortHandler
from drivers.genicam_camera import GenICamCamera, GenICamConfig
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS
from sim.rig import SimRig
from sim.turntable import register_map as rm


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_endpoints_answer_real_clients_and_stop_cleanly():
    fds = open_fds()
    with SimRig(speed_factor=10.0) as rig:
        e = rig.endpoints
        port = UrlPortHandler(e.dynamixel, CLIENT_REPLY_TIMEOUT_MS)
        assert port.openPort()
        ph = PacketHandler(2.0)
        assert all(ph.ping(port, i)[1] == COMM_SUCCESS for i in e.servo_ids)
        port.closePort()
        host, tcp_port = e.modbus.split(":")
        client = ModbusTcpClient(host, port=int(tcp_port), timeout=1, retries=0)
        assert client.connect()
        assert not client.read_holding_registers(rm.STATUS, count=2, device_id=e.stage_unit).isError()
        assert not client.write_coil(e.lamp_coil, True, device_id=e.lamp_unit).isError()
        assert rig.turntable.stage.lamp
        client.close()
    # no pty, socket or pipe is left open; the autouse fixture fails the test if a thread is left running
    assert open_fds() <= fds


@contextlib.contextmanager
def sim_serve(*args):
    """``hlr-lab sim serve`` in a child process; killed if the test leaves it running."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hlr_lab.cli.main", "sim", "serve", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_sim_serve_prints_endpoints_and_stops_on_sigint():
    with sim_serve() as proc:
        endpoints = json.loads(proc.stdout.readline())
        assert set(endpoints) >= {"dynamixel", "modbus", "servo_ids"}
        port = UrlPortHandler(endpoints["dynamixel"], CLIENT_REPLY_TIMEOUT_MS)
        assert port.openPort()
        assert PacketHandler(2.0).ping(port, endpoints["servo_ids"][0])[1] == COMM_SUCCESS
        port.closePort()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0


def test_the_camera_photographs_where_the_axes_are():
    import numpy as np
    import trimesh

    from tests.renderer_guard import require_renderer

    require_renderer()
    from dynamixel_sdk import GroupSyncWrite

    from sim.camera import GantryGeometry
    from sim.render.camera import CameraSpec
    from sim.render.scene import Material, SceneSpec, pose_matrix
    from sim.render.sensor import SensorModel
    from tests.cameras import half_size_camera

    cam = half_size_camera()
    body = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    spec = SceneSpec(
        np.asarray(body.vertices),
        np.asarray(body.faces),
        np.zeros(len(body.faces), np.int64),
        [Material((0.6, 0.5, 0.4), (0.3, 0.3, 0.3), 40.0)],
        pose_matrix((0, 0, 0.07)),
    )
    camera_spec = CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480)
    sensor = SensorModel(bits=12, sensitivity=2000.0)
    with SimRig(speed_factor=5.0, scene=spec, camera=camera_spec, sensor=sensor, spp=4) as rig:
        camera = rig.camera
        port = UrlPortHandler(rig.endpoints.dynamixel, CLIENT_REPLY_TIMEOUT_MS)
        port.openPort()
        ph = PacketHandler(2.0)
        for sid in rig.endpoints.servo_ids:
            ph.write1ByteTxRx(port, sid, 64, 1)
        g = GantryGeometry()
        goal = (g.zero_ticks[0] - 512, g.zero_ticks[1] + 512)  # azimuth −45°, elevation +45°
        writer = GroupSyncWrite(port, ph, 116, 4)
        for sid, ticks in zip(rig.endpoints.servo_ids, goal, strict=True):
            writer.addParam(sid, list(int(ticks).to_bytes(4, "little")))
        writer.txPacket()
        _, moving = camera.capture(0.01)  # the arm is still on its way: the frame shows where it is
        assert moving["servo_ticks"] != list(goal)
        deadline = time.monotonic() + 5
        while camera.pose()["servo_ticks"] != list(goal):
            assert time.monotonic() < deadline
        rig.turntable.stage.lamp = True
        frame, meta = camera.capture(0.01)
        np.testing.assert_allclose(meta["light_position_m"], g.light_position(*goal))
        expected = np.array(g.centre) + 0.3 * np.array(
            [np.cos(np.pi / 4) ** 2, -(np.cos(np.pi / 4) ** 2), np.sin(np.pi / 4)]
        )
        np.testing.assert_allclose(meta["light_position_m"], expected, atol=1e-12)
        assert frame.dtype == np.uint16
        assert frame.max() > 100
        rig.turntable.stage.lamp = False
        dark, _ = camera.capture(0.01)
        bright = frame.max(axis=2) > 100
        assert dark[bright].mean() < 5  # lamp off: read noise only where the lamp lit the object
        port.closePort()


def test_sim_serve_with_a_scene_serves_a_camera():

    with sim_serve("--scene", "builtin:cylinder") as proc:
        endpoints = json.loads(proc.stdout.readline())
        host, port = endpoints["modbus"].split(":")
        client = ModbusTcpClient(host, port=int(port), timeout=2, retries=0)
        assert client.connect()
        assert not client.write_coil(rm.LAMP_COIL, True, device_id=rm.RELAY_UNIT).isError()
        client.close()
        camera = GenICamCamera(GenICamConfig(endpoints["camera"]))  # a GigE Vision camera on 127.0.0.N
        try:
            camera.set_exposure(0.5)
            frame = camera.capture()
        finally:
            camera.close()
        assert frame.meta["lamp"] is True
        assert frame.exposure_s == frame.meta["exposure_s"] == 0.5
        assert frame.pixels.shape == (960, 1280, 3)
        # the arm rests horizontal along +x (servos at their zero ticks); under this distant light the
        # cylinder side facing it reads Rd · exposure · sensitivity = 230/255 · 0.5 s · 4095 ≈ 1847 DN
        assert 0.95 * 1847 < frame.pixels.max() < 1.2 * 1847
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
