"""Benchmarks of the simulated devices, driven by the real client libraries (``hlr-lab bench sim``)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.dynamixel import UrlPortHandler
from sim.dynamixel.bus import CLIENT_REPLY_TIMEOUT_MS, SimBus
from sim.turntable import register_map as rm
from sim.turntable.server import TurntableServer


def _timed(fn: Callable[[], int], n: int) -> dict[str, float]:
    times = []
    for _ in range(n):
        t = time.perf_counter()
        if fn() != COMM_SUCCESS:
            raise RuntimeError("a transaction failed during the benchmark")
        times.append(time.perf_counter() - t)
    times.sort()
    return {"median_ms": 1e3 * statistics.median(times), "p95_ms": 1e3 * times[int(0.95 * (n - 1))]}


def servo_round_trips(n: int = 1000) -> dict[str, dict[str, float]]:
    """Ping and a sync read of two servos' present positions, with dynamixel-sdk over the bus's pty
    (Return Delay Time 0, as a driver sets it)."""
    with SimBus.with_servos([1, 2]) as bus:
        for s in bus.servos:
            s.table[9] = 0
        port = UrlPortHandler(bus.serve_pty(), CLIENT_REPLY_TIMEOUT_MS)
        port.openPort()
        try:
            ph = PacketHandler(2.0)
            sync = GroupSyncRead(port, ph, 132, 4)
            sync.addParam(1)
            sync.addParam(2)
            return {
                "ping": _timed(lambda: ph.ping(port, 1)[1], n),
                "sync read, 2 servos": _timed(sync.txRxPacket, n),
                "fast sync read, 2 servos": _timed(sync.fastSyncRead, n),
            }
        finally:
            port.closePort()


def modbus_round_trips(n: int = 1000) -> dict[str, dict[str, float]]:
    """Reading the stage's status and alarm (2 × int32, as the driver polls them) and writing a command,
    with pymodbus over TCP and RTU."""
    figures = {}
    with TurntableServer.simulated() as server:
        host, port = server.serve_tcp()
        clients = {
            "TCP": ModbusTcpClient(host, port=port, timeout=1, retries=0),
            "RTU 115200 Bd": ModbusSerialClient(server.serve_rtu(), baudrate=115_200, timeout=1, retries=0),
        }
        for name, client in clients.items():
            client.connect()
            try:
                figures[f"read status and alarm, {name}"] = _timed(
                    lambda c=client: _ok(
                        c.read_holding_registers(rm.STATUS, count=4, device_id=rm.STAGE_UNIT)
                    ),
                    n,
                )
                figures[f"write command, {name}"] = _timed(
                    lambda c=client: _ok(c.write_registers(rm.COMMAND, [0, 0], device_id=rm.STAGE_UNIT)), n
                )
            finally:
                client.close()
    return figures


def _ok(response) -> int:
    return COMM_SUCCESS if not response.isError() else -1


def render_figures(frames: int = 1000, sizes=((640, 480), (1280, 960)), spp: int = 16) -> dict[str, float]:
    """Render time per frame (after the JIT's first frame) at each size, and resident memory before and after
    ``frames`` re-renders with a moving light and turntable (the scene is never reloaded)."""
    import numpy as np
    import trimesh

    from sim.render.camera import CameraSpec
    from sim.render.renderer import Renderer
    from sim.render.scene import Material, SceneSpec, pose_matrix

    body = trimesh.creation.icosphere(subdivisions=6, radius=0.06)
    spec = SceneSpec(
        np.asarray(body.vertices),
        np.asarray(body.faces),
        np.zeros(len(body.faces), np.int64),
        [Material((0.5, 0.4, 0.3), (0.3, 0.3, 0.3), 40.0)],
        pose_matrix((0, 0, 0.07)),
    )
    figures = {}
    renderer: Renderer | None = None
    for width, height in sizes:
        f = 2400 * width / 1280
        k = np.array([[f, 0, width / 2 + 1.5], [0, f, height / 2 - 2.0], [0, 0, 1]])
        look = np.array([0.0, 0.0, 0.07]) - np.array([0.0, -0.62, 0.30])
        z = look / np.linalg.norm(look)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        rot = np.stack([x, np.cross(z, x), z])
        cam = CameraSpec(k, np.array([-0.04, 0.015]), rot, -rot @ np.array([0.0, -0.62, 0.30]), width, height)
        renderer = Renderer(spec, cam, spp=spp)
        renderer.render(0.0, np.array([0.2, -0.2, 0.3]))  # JIT
        n = 10
        t = time.perf_counter()
        for i in range(n):  # a new light position every frame, as between poses of one view
            renderer.render(0.0, np.array([0.2, -0.2 + 0.01 * i, 0.3]))
        figures[f"render {width}x{height} {spp} spp, new light, s/frame"] = (time.perf_counter() - t) / n
        t = time.perf_counter()
        for i in range(n):  # the turntable too: vertex upload and acceleration-structure rebuild
            renderer.render(float(i + 1), np.array([0.2, -0.2 + 0.01 * i, 0.3]))
        figures[f"render {width}x{height} {spp} spp, new view, s/frame"] = (time.perf_counter() - t) / n
    assert renderer is not None, "no film size to render at"
    before = _rss_mb()
    for i in range(frames):
        renderer.render(float(i % 360), np.array([0.3 * np.cos(i / 50), 0.3 * np.sin(i / 50), 0.25]), seed=i)
    figures[f"RSS before {frames} re-renders, MB"] = before
    figures[f"RSS after {frames} re-renders, MB"] = _rss_mb()
    return figures


@dataclass(frozen=True)
class CameraTransport:
    """``hlr-lab bench sim``'s camera part: ms per frame (median, p95) by case, and the GigE Vision
    stream's packet counters (Aravis's names) by case."""

    timings: dict[str, dict[str, float]]
    packets: dict[str, dict[str, int]]


GIGE_CASES = (("Mono16", 0.0), ("RGB12", 0.0), ("Mono16", 0.01), ("Mono16", 0.05))  # format, packets lost


def camera_transport_figures(n: int = 20, width: int = 1280, height: int = 960) -> CameraTransport:
    """Per frame, from trigger to decoded pixels, with a frame already made (no rendering: only the
    transport is timed): through GigE Vision (the simulated device on the simulated rig's 10 GigE link, Aravis,
    the GenICam driver) in Mono16
    and RGB12, then Mono16 with 1 % and 5 % of the stream's packets lost on their first sending (the
    resends counted); and through the older TCP frame endpoint."""
    import numpy as np

    from drivers.genicam_camera import GenICamCamera, GenICamConfig
    from drivers.net_camera import NetworkCamera
    from sim.camera_server import CameraServer
    from sim.gige.device import GigECamera
    from sim.rig import CAMERA_LINK_BITS_PER_S

    frame = np.random.default_rng(0).integers(0, 4096, (height, width, 3), dtype=np.uint16)

    class Ready:  # a sensor whose frame is already exposed
        def capture(self, exposure_s: float, gain_db: float = 0.0) -> tuple[np.ndarray, dict]:
            return frame, {"exposure_s": exposure_s}

    timings, packets = {}, {}
    for fmt, lost in GIGE_CASES:
        case = f"GigE Vision, {width}×{height} {fmt}" + (f", {lost:.0%} of packets lost" if lost else "")
        device = GigECamera(Ready().capture, width=width, height=height, sensor_bits=12,
                            link_bits_per_s=CAMERA_LINK_BITS_PER_S)  # fmt: skip
        try:
            device.serve_on_loopback()
            camera = GenICamCamera(GenICamConfig(device.address, pixel_format=fmt))
            try:
                camera.capture()  # the first frame allocates
                device.faults.drop_ratio = lost
                before = camera.statistics()
                timings[case] = _timed(lambda camera=camera: camera.capture() and COMM_SUCCESS, n)
                packets[case] = {k: v - before[k] for k, v in camera.statistics().items()}
            finally:
                camera.close()
        finally:
            device.close()
    server = CameraServer(Ready())  # type: ignore[arg-type]  (duck-typed: it only calls capture)
    try:
        camera = NetworkCamera(server.serve_tcp())
        try:
            camera.capture()
            timings[f"TCP frame endpoint, {width}×{height} RGB 16-bit"] = _timed(
                lambda: camera.capture() and COMM_SUCCESS, n
            )
        finally:
            camera.close()
    finally:
        server.close()
    return CameraTransport(timings, packets)


def camera_transport_report(figures: CameraTransport) -> list[str]:
    """The camera part of ``hlr-lab bench sim`` as lines: times, then each GigE Vision case's packets."""
    title = "a frame from trigger to pixels, already exposed (GigE Vision Mono16: target ≤ TCP + 20 ms):"
    lines = round_trip_report(title, figures.timings)
    lines.append(
        "GigE Vision packets over those frames (received / lost and resent / missing; frames whole):"
    )
    for case, c in figures.packets.items():
        lines.append(
            f"  {case:<48} {c['n_received_packets']} / {c['n_resent_packets']} / {c['n_missing_packets']}; "
            f"{c['n_completed_buffers']} of {c['n_completed_buffers'] + c['n_failures']}"
        )
    return lines


def _rss_mb() -> float:
    import os

    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def round_trip_report(title: str, figures: dict[str, dict[str, float]]) -> list[str]:
    """A section of ``hlr-lab bench sim``: ``title``, then each transaction's median and p95."""
    return [title] + [
        f"  {name:30s} median {f['median_ms']:.3f} ms, p95 {f['p95_ms']:.3f} ms"
        for name, f in figures.items()
    ]


def render_report(figures: dict[str, float]) -> list[str]:
    return [
        "renderer (Mitsuba llvm_ad_rgb, direct integrator; target ≤ 0.3 s per 1280×960 frame, flat memory):"
    ] + [f"  {name:40s} {value:8.3f}" for name, value in figures.items()]


def transactions_report(n: int, progress: Callable[[str], None] = lambda _: None) -> list[str]:
    """``hlr-lab bench sim``'s first part: ``n`` servo and ``n`` Modbus round trips, timed, as lines."""
    progress("timing servo transactions…")
    servo = servo_round_trips(n)
    progress("timing Modbus transactions…")
    modbus = modbus_round_trips(n)
    return [
        *round_trip_report(f"servo transactions over a pty, dynamixel-sdk, {n} each (target ≤ 1 ms):", servo),
        *round_trip_report(f"Modbus transactions, pymodbus, {n} each (target ≤ 3 ms):", modbus),
    ]
