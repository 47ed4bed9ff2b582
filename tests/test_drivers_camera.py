"""The network camera driver (a frame endpoint: one JSON line per request) against the simulated rig's
older camera endpoint (Mitsuba frames over TCP; the simulated rig serves a GigE Vision camera by default)."""

import socket
import threading

import numpy as np
import pytest

from drivers.errors import DeviceError, DeviceTimeout, LimitError
from drivers.net_camera import NetworkCamera
from drivers.protocols import Camera
from sim.render.camera import CameraSpec
from sim.render.scene import builtin_scene
from sim.rig import SimRig
from tests.cameras import half_size_camera

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

GAIN_X2_DB = 20 * np.log10(2.0)


@pytest.fixture(scope="module")
def sim():
    c = half_size_camera()
    spec = CameraSpec(c.matrix, c.distortion, c.rotation, c.translation, c.width, c.height)
    with SimRig(
        speed_factor=40.0, scene=builtin_scene("cylinder"), camera=spec, spp=4, camera_link="network"
    ) as s:
        s.turntable.stage.lamp = True  # the stage model's lamp is what the renderer reads
        yield s


def test_frames_with_exposure_and_gain(sim):
    camera = NetworkCamera(sim.endpoints.camera)
    assert isinstance(camera, Camera)
    camera.set_exposure(0.25)
    plain = camera.capture()
    assert plain.pixels.shape == (480, 640, 3)
    assert plain.pixels.dtype == np.uint16
    assert (plain.bits, plain.exposure_s, plain.gain_db) == (12, 0.25, 0.0)
    assert plain.meta["lamp"] is True
    camera.set_gain(GAIN_X2_DB)
    doubled = camera.capture()
    assert doubled.meta["gain_db"] == pytest.approx(GAIN_X2_DB)
    lit = plain.pixels > 200  # the lit cylinder, well above the read noise and below saturation at ×2
    assert lit.sum() > 5000
    # thousands of pixels average the photon and read noise to well under 1 %: 2 % is a real failure
    ratio = doubled.pixels[lit].astype(float).mean() / plain.pixels[lit].astype(float).mean()
    assert ratio == pytest.approx(2.0, rel=0.02)
    camera.close()


def test_settings_outside_the_range_are_refused_before_asking(sim):
    camera = NetworkCamera(sim.endpoints.camera)
    with pytest.raises(LimitError, match="gain 30 dB is outside"):
        camera.set_gain(30)
    with pytest.raises(LimitError, match="must be positive"):
        camera.set_exposure(0)
    assert camera.gain_db == 0.0
    camera.close()


def test_an_unreachable_camera_is_named():
    with pytest.raises(DeviceError, match=r"camera on 127\.0\.0\.1:1: cannot connect"):
        NetworkCamera("127.0.0.1:1", reply_timeout_s=1)


def test_a_frame_cut_short_is_an_error_and_closes_the_link():
    """A peer that dies mid-frame (a crashed bridge) must not hand back a partial frame."""
    server = socket.create_server(("127.0.0.1", 0))

    def answer_half():
        conn, _ = server.accept()
        with conn:
            conn.recv(1024)
            conn.sendall(b'{"width": 4, "height": 2, "channels": 3, "dtype": "uint16", "meta": {}}\n')
            conn.sendall(bytes(10))  # of 48

    peer = threading.Thread(target=answer_half)
    peer.start()
    camera = NetworkCamera(f"127.0.0.1:{server.getsockname()[1]}", reply_timeout_s=5)
    with pytest.raises(DeviceTimeout, match="stopped after 10 of 48 bytes"):
        camera.capture()
    server.close()  # the bridge is gone: the next capture opens a new link, and says it cannot
    with pytest.raises(DeviceError, match="cannot connect"):
        camera.capture()
    peer.join()


def test_after_a_dropped_link_the_next_frame_comes_on_a_new_one(sim):
    camera = NetworkCamera(sim.endpoints.camera)
    sim.camera_server.cut_replies = 1
    with pytest.raises(DeviceTimeout, match="stopped after"):
        camera.capture()
    assert camera.capture().pixels.shape == (480, 640, 3)
    camera.close()


def test_ten_thousand_broken_requests_leave_the_camera_answering(sim, caplog):
    """Random bytes, JSON that is not an object, exposures and gains of the wrong type, NaN, ±inf, 0,
    negative or beyond an hour, missing keys, all on one connection: each is answered with one error
    line (never a render, never a traceback), and a proper request afterwards gets its frame."""
    import json
    import logging
    import random

    rng = random.Random(14)
    odd = [None, "x", [], {}, -1, 1e308, 3601, float("nan"), float("inf"), -float("inf")]  # none valid
    host, port = sim.endpoints.camera.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as conn, caplog.at_level(logging.WARNING):
        replies = conn.makefile("rb")
        for k in range(10_000):
            kind = k % 4
            if kind == 0:
                line = rng.randbytes(rng.randint(0, 30)).replace(b"\n", b" ")
            elif kind == 1:
                line = json.dumps(rng.choice([[], 3, "exposure", None, {"gain_db": 0}])).encode()
            else:
                request = (
                    {"exposure_s": rng.choice([*odd, 0])}
                    if kind == 2
                    else {"exposure_s": 0.01, "gain_db": rng.choice([*odd, 25])}
                )
                line = json.dumps(request).encode()
            conn.sendall(line + b"\n")
            assert json.loads(replies.readline())["error"].startswith("bad request")
        conn.sendall(b'{"exposure_s": 0.01}\n')
        header = json.loads(replies.readline())
        assert (header["width"], header["height"], header["channels"]) == (640, 480, 3)
    assert "Traceback" not in caplog.text
