"""A GigE Vision camera in Python: GVCP on ``address``:3956, frames as GVSP to whoever holds control.

What a real camera does, as far as a client can tell: discovery (asked of its address, or broadcast as
Aravis's device list asks it), register and memory reads and writes (the bootstrap registers, the
features of :mod:`sim.gige.features`, the GenICam XML), control privilege kept alive by the client's
heartbeat (lost when it stays silent past ``GevHeartbeatTimeout``), test packets for packet-size
negotiation, software-triggered or continuous frames (at ``AcquisitionFrameRate`` when enabled), the
chunks ``ChunkSelector``/``ChunkEnable`` choose (exposure, gain, size, timestamp and the simulator's account
of the frame), stream packets no faster than the link carries them (plus ``GevSCPD``), and resends of the
packets a client asks for again. Aravis's ``arv-test-0.8`` passes against it (docs/camera.md).

Faults, for the soak and the stop tests (:class:`Faults`): stream packets dropped on their first
sending (a resend brings them), packets dropped for good (the frame arrives incomplete), triggers that
bring no frame, and a device that stops answering GVCP altogether.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import random
import socket
import struct
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.gige import features as ft
from sim.gige import gvcp, gvsp
from sim.gige.pixels import BY_CODE, FORMATS, PixelFormat, encode, sensor_values, test_pattern

log = logging.getLogger(__name__)

FrameSource = Callable[[float, float], tuple[np.ndarray, dict]]  # (exposure s, gain dB) → (H, W, 3) DN, truth
KEPT_BLOCKS = 8  # blocks whose packets are kept for resend requests
DEFAULT_PACKET_BYTES = 1500  # a standard Ethernet frame, until the client negotiates more
MAX_PACKET_BYTES = 9000  # jumbo frames, as GigE Vision cameras offer
GIGABIT = 1e9  # bits a second: a GigE camera's link
# each packet's bytes on the wire beyond what sendto is given: IP and UDP headers (28), and Ethernet's
# preamble, header, checksum and inter-frame gap (38)
WIRE_OVERHEAD_BYTES = 28 + 38
# the stream waits for the link only once this far ahead of it (s): at 1 Gb/s a burst of at most ~60 kB,
# well within a receiver's default socket buffer (~200 kB), where sleeping per packet would cost more
# than the packet's own 12 µs
PACING_SLACK_S = 0.0005
TICKS_PER_S = 1_000_000_000  # the device's timestamp (and GevSCPD) tick: ns


@dataclass
class Faults:
    """Faults injected into the device (each counts down as it is used; set them between frames)."""

    drop_ratio: float = 0.0  # each stream packet lost on its first sending with this probability
    drop_for_good: int = 0  # this many next frames lose a packet that no resend brings back
    lost_triggers: int = 0  # this many next software triggers bring no frame
    silent: bool = False  # the device answers nothing on GVCP (a camera unplugged, powered off, hung)
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))


@dataclass(frozen=True)
class Identity:
    """What the camera says it is. An empty ``serial`` is one of its own, from the address it serves on
    (SIM0042 on 127.0.0.42), and so is the MAC address's last byte: every camera has its own, and Aravis's
    device list keeps one device per vendor, model and serial."""

    vendor: str = "hlr-lab"
    model: str = "Simulated reflectance camera"
    version: str = "1.0"
    serial: str = ""
    firmware: str = "hlr-lab sim 1"
    mac: bytes = b"\x02\x00\x00\x00\x00\x01"  # locally administered


class GigECamera:
    """The device. ``source(exposure_s, gain_db)`` takes one frame ((H, W, 3) DN of ``sensor_bits``, and
    the simulator's account of it); ``serve(address)`` binds 127.0.0.N:3956 and starts answering."""

    def __init__(
        self,
        source: FrameSource,
        *,
        width: int,
        height: int,
        sensor_bits: int,
        pixel_format: str | None = None,
        identity: Identity = Identity(),
        temperature_c: Callable[[], float] = lambda: 38.0,
        link_bits_per_s: float = GIGABIT,
    ):
        self.source, self.sensor_bits, self.identity = source, sensor_bits, identity
        self.link_bits_per_s = link_bits_per_s
        self.width, self.height = width, height
        self.temperature_c = temperature_c
        self.faults = Faults()
        xml = ft.genicam_xml(identity.model, identity.vendor, MAX_PACKET_BYTES).encode()
        self._memory = bytearray(ft.XML_AT + len(xml) + 4)
        self._memory[ft.XML_AT : ft.XML_AT + len(xml)] = xml
        self._lock = threading.RLock()
        self._controller: tuple[str, int] | None = None
        self._last_heard = 0.0
        self._jobs: queue.Queue[str | None] = queue.Queue()
        self._sent: OrderedDict[int, list[bytes]] = OrderedDict()  # block id → its datagrams, for resends
        self._block_id = 0
        self._acquiring = False
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.frames_sent = 0
        self.packets_resent = 0
        # the sensor's own depth unless asked otherwise: RGB8, RGB12 or RGB16
        self._init_registers(len(xml), pixel_format or {8: "RGB8", 16: "RGB16"}.get(sensor_bits, "RGB12"))

    # -- registers --------------------------------------------------------------------------------

    def _init_registers(self, xml_bytes: int, pixel_format: str) -> None:
        i = self.identity
        self._put(gvcp.VERSION, (2 << 16) | 0)
        self._put(gvcp.DEVICE_MODE, 1 << 31)  # a transmitter, big-endian registers, UTF-8 strings
        self._put(gvcp.MAC_HIGH, int.from_bytes(i.mac[:2], "big"))
        self._put(gvcp.MAC_LOW, int.from_bytes(i.mac[2:], "big"))
        self._put(gvcp.IP_CONFIG_SUPPORTED, 0b111)
        self._put(gvcp.IP_CONFIG_CURRENT, 0b001)
        self._put(gvcp.CURRENT_MASK, 0xFF000000)
        for at, text, size in ((gvcp.MANUFACTURER_NAME, i.vendor, 32), (gvcp.MODEL_NAME, i.model, 32),
                               (gvcp.DEVICE_VERSION, i.version, 32), (gvcp.SERIAL_NUMBER, i.serial, 16),
                               (ft.BY_NAME["DeviceFirmwareVersion"].address, i.firmware, 32)):  # fmt: skip
            self._put_text(at, text, size)
        url = f"Local:hlr-sim-camera.xml;{ft.XML_AT:x};{xml_bytes:x}".encode()
        self._memory[gvcp.FIRST_URL : gvcp.FIRST_URL + len(url)] = url
        self._put(gvcp.N_INTERFACES, 1)
        self._put(gvcp.N_STREAM_CHANNELS, 1)
        self._put(gvcp.GVCP_CAPABILITY, gvcp.CAPABILITY_WRITE_MEMORY | gvcp.CAPABILITY_PACKET_RESEND
                  | gvcp.CAPABILITY_SERIAL_NUMBER | gvcp.CAPABILITY_USER_NAME)  # fmt: skip
        self._put(gvcp.HEARTBEAT_TIMEOUT, 3000)
        self._put(gvcp.TICK_FREQUENCY_LOW, TICKS_PER_S)  # timestamps in nanoseconds
        self._put(gvcp.SC_PACKET_SIZE, DEFAULT_PACKET_BYTES)
        for name, value in (("SensorWidth", self.width), ("SensorHeight", self.height), ("Width", self.width),
                            ("Height", self.height), ("PixelFormat", FORMATS[pixel_format].code),
                            ("TriggerMode", 0)):  # fmt: skip
            self._put(ft.BY_NAME[name].address, value)
        self._put_float("ExposureTime", 10_000.0)
        self._put_float("AcquisitionFrameRate", 30.0)
        self._put(ft.BY_NAME["GevLinkSpeed"].address, round(self.link_bits_per_s / 1e6))
        for i in range(len(ft.CHUNKS)):  # every chunk on: chunk mode alone turns them on or off
            self._put(_chunk_enable_at(i), 1)
        self._update_payload_size()

    def _put_text(self, address: int, text: str, size: int) -> None:
        self._memory[address : address + size] = text.encode()[: size - 1].ljust(size, b"\0")

    def _put(self, address: int, value: int) -> None:
        self._memory[address : address + 4] = struct.pack(">I", value & 0xFFFFFFFF)

    def _get(self, address: int) -> int:
        return struct.unpack_from(">I", self._memory, address)[0]

    def _put_float(self, name: str, value: float) -> None:
        at = ft.BY_NAME[name].address
        self._memory[at : at + 8] = struct.pack(">d", value)

    def feature(self, name: str) -> float:
        """A feature's current value, as its register holds it (for tests and the simulator's own use)."""
        f = ft.BY_NAME[name]
        return (
            struct.unpack_from(">d", self._memory, f.address)[0]
            if f.kind == "float"
            else self._get(f.address)
        )

    @property
    def pixel_format(self) -> PixelFormat:
        return BY_CODE[self._get(ft.BY_NAME["PixelFormat"].address)]

    def _chunks_sent(self) -> list[ft.Chunk]:
        """The chunks a frame carries: those ChunkEnable sets, in chunk mode; none otherwise."""
        if not self.feature("ChunkModeActive"):
            return []
        return [c for i, c in enumerate(ft.CHUNKS) if self._get(_chunk_enable_at(i))]

    def _update_payload_size(self) -> None:
        size = self.pixel_format.payload_bytes(self.width, self.height)
        if chunks := self._chunks_sent():  # the image and each chunk are followed by their id and length
            size += 8 + sum(8 + c.size for c in chunks)
        self._put(ft.BY_NAME["PayloadSize"].address, size)

    # -- GVCP -------------------------------------------------------------------------------------

    def serve(self, address: str) -> None:
        """Bind ``address``:3956 (GVCP) and start answering; raises OSError if it is taken."""
        self.address = address
        self._gvcp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._gvcp.bind((address, gvcp.PORT))
        except OSError:
            self._gvcp.close()
            raise
        self._gvcp.settimeout(0.1)
        self._stream = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stream.bind((address, 0))
        self._stream.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        self._put(gvcp.CURRENT_IP, int.from_bytes(socket.inet_aton(address), "big"))
        if not self.identity.serial:  # its own, from its address (Identity)
            last = socket.inet_aton(address)[-1]
            self._put_text(gvcp.SERIAL_NUMBER, f"SIM{last:04d}", 16)
            self._put(gvcp.MAC_LOW, int.from_bytes(self.identity.mac[2:-1] + bytes([last]), "big"))
        self._discovery = _broadcast_listener()
        loops = [(self._answer_loop, "gvcp"), (self._frame_loop, "gvsp")]
        if self._discovery is not None:
            loops.append((self._discovery_loop, "discovery"))
        for target, name in loops:
            thread = threading.Thread(target=target, name=f"sim-camera-{name}-{address}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def serve_on_loopback(self) -> str:
        """Serve on a free loopback address 127.0.0.N (2 ≤ N ≤ 254; GVCP's port is fixed, so each simulated
        camera takes an address of its own and parallel rigs do not meet); return it."""
        for n in random.sample(range(2, 255), 253):
            try:
                self.serve(f"127.0.0.{n}")
                return self.address
            except OSError:  # taken by another simulated camera
                continue
        raise OSError("no free loopback address 127.0.0.2–254 for a simulated GigE Vision camera")

    def _answer_loop(self) -> None:
        while not self._stop.is_set():
            try:
                datagram, peer = self._gvcp.recvfrom(2048)
            except (TimeoutError, OSError):  # nothing waiting: only now is silence the client's, not ours
                self._drop_stale_control()
                continue
            command = gvcp.parse_command(datagram)
            if command is None or self.faults.silent:
                continue
            try:
                reply = self._answer(command, peer)
            except (struct.error, ValueError):  # a payload too short for its command, or an odd pair count
                reply = gvcp.ack(command, status=gvcp.INVALID_PARAMETER)
            except Exception:  # a bug answering one command must not take the camera down
                log.exception("simulated camera: command 0x%04x failed", command.code)
                reply = gvcp.ack(command, status=gvcp.INVALID_HEADER)
            if reply is not None and (command.ack_required or command.code == gvcp.DISCOVERY):
                with contextlib.suppress(OSError):  # closed meanwhile, or the peer gone: as a lost datagram
                    self._gvcp.sendto(reply, peer)

    def _discovery_loop(self) -> None:
        """Broadcast discovery (how Aravis's device list and vendors' tools find cameras): answered from
        the camera's own address, as to a discovery sent to it; every other broadcast command ignored."""
        assert self._discovery is not None
        while not self._stop.is_set():
            try:
                datagram, peer = self._discovery.recvfrom(2048)
            except (TimeoutError, OSError):
                continue
            command = gvcp.parse_command(datagram)
            if command is None or command.code != gvcp.DISCOVERY or self.faults.silent:
                continue
            reply = self._answer(command, peer)
            if reply is not None:  # always, for a discovery
                with contextlib.suppress(OSError):
                    self._gvcp.sendto(reply, peer)

    def _drop_stale_control(self) -> None:
        with self._lock:
            timeout_s = self._get(gvcp.HEARTBEAT_TIMEOUT) / 1000
            if self._controller and time.monotonic() - self._last_heard > timeout_s:
                log.info(
                    "simulated camera %s: no heartbeat for %.1f s; control released", self.address, timeout_s
                )
                self._release_control()

    def _release_control(self) -> None:
        """No client holds control: acquisition stops and the stream channel closes (port 0), so no frame
        still queued goes to a port its client no longer has (another program may have it by then)."""
        self._controller = None
        self._put(gvcp.CONTROL_PRIVILEGE, 0)
        self._put(gvcp.SC_PORT, 0)
        self._acquiring = False

    def _answer(self, command: gvcp.Command, peer: tuple[str, int]) -> bytes | None:
        with self._lock:
            if self._controller == peer:
                self._last_heard = time.monotonic()
            code, payload = command.code, command.payload
            if code == gvcp.DISCOVERY:
                return gvcp.ack(command, bytes(self._memory[: gvcp.DISCOVERY_DATA_BYTES]))
            if code == gvcp.READREG:
                addresses = gvcp.words(payload)
                if any(a % 4 for a in addresses):
                    return gvcp.ack(command, status=gvcp.BAD_ALIGNMENT)
                if any(a + 4 > len(self._memory) for a in addresses):
                    return gvcp.ack(command, status=gvcp.INVALID_ADDRESS)
                self._refresh()
                return gvcp.ack(command, b"".join(self._memory[a : a + 4] for a in addresses))
            if code == gvcp.READMEM:
                address, count = struct.unpack(">IxxH", payload[:8])
                if count > gvcp.MAX_MEM_BYTES or address + count > len(self._memory):
                    return gvcp.ack(command, status=gvcp.INVALID_ADDRESS)
                self._refresh()
                return gvcp.ack(command, payload[:4] + bytes(self._memory[address : address + count]))
            if code in (gvcp.WRITEREG, gvcp.WRITEMEM):
                if code == gvcp.WRITEREG:
                    pairs = gvcp.words(payload)
                    writes = [
                        (a, struct.pack(">I", v)) for a, v in zip(pairs[0::2], pairs[1::2], strict=True)
                    ]
                else:
                    writes = [(struct.unpack(">I", payload[:4])[0], payload[4:])]
                for done, (address, data) in enumerate(writes):
                    status = self._write(address, data, peer)
                    if status != gvcp.SUCCESS:
                        return gvcp.ack(command, struct.pack(">I", done), status)
                return gvcp.ack(
                    command, struct.pack(">I", len(writes) if code == gvcp.WRITEREG else len(writes[0][1]))
                )
            if code == gvcp.PACKETRESEND:  # block id, first and last packet id (no acknowledge either way)
                if len(payload) >= 12:
                    self._resend(*gvcp.words(payload)[:3])
                return None
            return gvcp.ack(command, status=gvcp.NOT_IMPLEMENTED)

    def _refresh(self) -> None:
        self._put_float("DeviceTemperature", float(self.temperature_c()))

    def _write(self, address: int, data: bytes, peer: tuple[str, int]) -> int:
        """One write: privilege, access and range checked, then the register's effect."""
        if address == gvcp.CONTROL_PRIVILEGE:
            value = struct.unpack(">I", data[:4])[0]
            if self._controller not in (None, peer):
                return gvcp.ACCESS_DENIED
            if value & (gvcp.CCP_CONTROL | gvcp.CCP_EXCLUSIVE):
                self._controller, self._last_heard = peer, time.monotonic()
                self._put(gvcp.CONTROL_PRIVILEGE, value)
            else:
                self._release_control()
            return gvcp.SUCCESS
        if self._controller != peer:
            return gvcp.ACCESS_DENIED  # only the application holding control may write
        feature = next((f for f in ft.FEATURES if f.address <= address < f.address + f.size), None)
        writable = {
            gvcp.SC_PORT,
            gvcp.SC_PACKET_SIZE,
            gvcp.SC_PACKET_DELAY,
            gvcp.SC_DESTINATION,
            gvcp.HEARTBEAT_TIMEOUT,
        }
        if feature is None and address not in writable:
            return gvcp.WRITE_PROTECT if address < ft.XML_AT + 0x10000 else gvcp.INVALID_ADDRESS
        if feature is not None and feature.access == "RO":
            return gvcp.WRITE_PROTECT
        if feature is not None and feature.kind == "float" and len(data) == 8:
            value = struct.unpack(">d", data)[0]
            if not feature.minimum <= value <= feature.maximum:  # type: ignore[operator]  (floats have bounds)
                return gvcp.INVALID_PARAMETER
        if (
            feature is not None
            and feature.kind == "enum"
            and struct.unpack(">I", data[:4])[0] not in feature.entries.values()
        ):
            return gvcp.INVALID_PARAMETER
        if address == gvcp.SC_PACKET_SIZE:
            return self._set_packet_size(struct.unpack(">I", data[:4])[0])
        if feature is not None and feature.name in _PAYLOAD_LAYOUT and self._acquiring:
            return gvcp.ACCESS_DENIED  # the payload's layout is locked while frames flow
        self._memory[address : address + len(data)] = data
        if feature is not None:
            self._effect(feature.name)
        return gvcp.SUCCESS

    def _set_packet_size(self, value: int) -> int:
        size = min(max(value & gvcp.SCPS_SIZE, 576), MAX_PACKET_BYTES) // 4 * 4
        self._put(gvcp.SC_PACKET_SIZE, (value & gvcp.SCPS_DO_NOT_FRAGMENT) | size)
        if value & gvcp.SCPS_FIRE_TEST:  # a test packet of exactly the packet size, to the stream's host
            self._stream.sendto(bytes(size - 28), self._destination())
        return gvcp.SUCCESS

    def _effect(self, name: str) -> None:
        if name in _PAYLOAD_LAYOUT:
            self._update_payload_size()
        elif name == "AcquisitionStart":
            self._acquiring = True
            if self.feature("TriggerMode") == 0:
                self._jobs.put("free-running")
        elif name == "AcquisitionStop":
            self._acquiring = False
        elif name == "TriggerSoftware" and self._acquiring and self.feature("TriggerMode") == 1:
            if self.faults.lost_triggers > 0:
                self.faults.lost_triggers -= 1
            else:
                self._jobs.put("triggered")

    def _destination(self) -> tuple[str, int]:
        return socket.inet_ntoa(struct.pack(">I", self._get(gvcp.SC_DESTINATION))), self._get(
            gvcp.SC_PORT
        ) & 0xFFFF

    # -- GVSP -------------------------------------------------------------------------------------

    def _frame_loop(self) -> None:
        while not self._stop.is_set():
            try:
                job = self._jobs.get(timeout=0.1)
            except queue.Empty:
                continue
            if job is None:
                return
            if job == "free-running":  # frames one after another until the acquisition stops
                while self._acquiring and not self._stop.is_set():
                    started = time.monotonic()
                    self._send_frame()
                    if self.feature("AcquisitionMode") == 1:  # SingleFrame
                        self._acquiring = False
                    self._rest_of_frame_period(started)
            elif self._acquiring:
                self._send_frame()

    def _rest_of_frame_period(self, started: float) -> None:
        """Wait out the frame begun at ``started`` (monotonic s): a sensor delivers a frame no sooner than
        it has exposed it, so free-running frames come at most 1 / ExposureTime a second (Python alone sent
        ~3 400 frames a second of 160 × 120: a core's worth of packets, which no camera sends), and at
        AcquisitionFrameRate when it is enabled. Ends early when the acquisition stops."""
        period = self.feature("ExposureTime") / 1e6
        if self.feature("AcquisitionFrameRateEnable"):
            period = max(period, 1 / self.feature("AcquisitionFrameRate"))
        end = started + period
        while self._acquiring and (left := end - time.monotonic()) > 0:
            if self._stop.wait(min(left, 0.05)):
                return

    def _send_frame(self) -> None:
        try:
            with self._lock:
                exposure_s, gain_db = self.feature("ExposureTime") / 1e6, self.feature("Gain")
                black, fmt, pattern = (
                    self.feature("BlackLevel"),
                    self.pixel_format,
                    self.feature("TestPattern"),
                )
            if pattern:
                values, truth = (
                    test_pattern(self.height, self.width, fmt),
                    {"test_pattern": "GreyDiagonalRamp"},
                )
            else:
                frame, truth = self.source(exposure_s, gain_db)
                if black:
                    frame = np.minimum(frame + np.uint16(round(black)), np.uint16(2**self.sensor_bits - 1))
                values = sensor_values(frame, fmt, self.sensor_bits)
            truth = {**truth, "exposure_s": exposure_s, "gain_db": gain_db}
            timestamp_ns = time.time_ns()
            with self._lock:
                data = self._payload(values, truth, fmt, timestamp_ns)
                self._block_id = self._block_id % 0xFFFF + 1
                packets = gvsp.block(
                    self._block_id, data, pixel_format=fmt.code, width=self.width, height=self.height,
                    timestamp_ns=timestamp_ns, packet_bytes=self._get(gvcp.SC_PACKET_SIZE) & gvcp.SCPS_SIZE,
                    chunks=bool(self.feature("ChunkModeActive")),
                )  # fmt: skip
                self._sent[self._block_id] = packets
                while len(self._sent) > KEPT_BLOCKS:
                    self._sent.popitem(last=False)
                destination = self._destination()
                lose = self._losses(len(packets))
            if destination[1] == 0:  # the stream channel was closed meanwhile (its client left)
                return
            self._transmit(packets, destination, lose)
            self.frames_sent += 1
        except Exception:  # a frame that cannot be made is a frame that never comes, as on a real camera
            log.exception("simulated camera: frame failed")

    def _transmit(self, packets: list[bytes], destination: tuple[str, int], lose: set[int]) -> None:
        """Send a frame's packets (but those in ``lose``) no faster than the link carries them, each
        followed by the inter-packet delay GevSCPD asks (ticks): a GigE camera streams ~120 MB/s, where
        a loop of sendto on loopback outruns any receiver whose socket buffer is smaller than a frame."""
        wire_s_per_byte = 8 / self.link_bits_per_s
        gap_s = self._get(gvcp.SC_PACKET_DELAY) / TICKS_PER_S
        start, due = time.monotonic(), 0.0
        for i, packet in enumerate(packets):
            if i not in lose:
                self._stream.sendto(packet, destination)
            due += (len(packet) + WIRE_OVERHEAD_BYTES) * wire_s_per_byte + gap_s
            if (ahead := start + due - time.monotonic()) > PACING_SLACK_S and self._stop.wait(ahead):
                return

    def _payload(self, values: np.ndarray, truth: dict, fmt: PixelFormat, timestamp_ns: int) -> bytes:
        """The frame's bytes: the image, then (chunk mode) the chunks ChunkEnable sets, each followed by
        its id and length (GigE Vision chunk layout, read from the end). ``truth`` holds the exposure (s)
        and gain (dB) the frame was taken with; ``timestamp_ns`` is the frame's GVSP timestamp."""
        image = encode(values, fmt)
        if not (chunks := self._chunks_sent()):
            return image
        text = json.dumps(truth).encode()[: ft.TRUTH_CHUNK_BYTES - 1].ljust(ft.TRUTH_CHUNK_BYTES, b"\0")
        value = {"ExposureTime": struct.pack(">d", truth["exposure_s"] * 1e6),
                 "Gain": struct.pack(">d", truth["gain_db"]),
                 "SimulatorTruth": text,
                 "Width": struct.pack(">I", self.width),
                 "Height": struct.pack(">I", self.height),
                 "Timestamp": struct.pack(">Q", timestamp_ns)}  # fmt: skip
        parts = [(image, ft.CHUNK_IMAGE), *((value[c.name], c.chunk_id) for c in chunks)]
        return b"".join(data + struct.pack(">II", chunk_id, len(data)) for data, chunk_id in parts)

    def _losses(self, n_packets: int) -> set[int]:
        """Which data packets this frame loses on the way (never the leader or trailer: a receiver
        asks for a resend of what lies between two it has)."""
        f = self.faults
        lost = (
            set((1 + np.flatnonzero(f.rng.random(n_packets - 2) < f.drop_ratio)).tolist())
            if f.drop_ratio
            else set()
        )
        if f.drop_for_good > 0:
            f.drop_for_good -= 1
            self._sent[self._block_id][n_packets // 2] = b""  # gone from the device's memory too
            lost.add(n_packets // 2)
        return lost

    def _resend(self, block_id: int, first: int, last: int) -> None:
        packets = self._sent.get(block_id & 0xFFFF)
        if packets is None:
            return
        for packet in packets[first : last + 1]:
            if packet:
                self._stream.sendto(gvsp.resent(packet), self._destination())
                self.packets_resent += 1

    def close(self) -> None:
        """Stop answering and sending (idempotent)."""
        self._stop.set()
        self._jobs.put(None)
        for thread in self._threads:
            thread.join(timeout=5)
        self._threads.clear()
        for sock in ("_gvcp", "_stream", "_discovery"):
            if getattr(self, sock, None) is not None:
                getattr(self, sock).close()


_PAYLOAD_LAYOUT = ("PixelFormat", "ChunkModeActive", "ChunkEnable")  # features that change the payload


def _chunk_enable_at(i: int) -> int:
    """The register of ChunkEnable for ChunkSelector's entry ``i`` (one register per entry, 4 bytes apart)."""
    return ft.BY_NAME["ChunkEnable"].address + 4 * i


def _broadcast_listener() -> socket.socket | None:
    """A socket on 255.255.255.255:3956, shared (SO_REUSEADDR) with every other camera on this machine
    (Aravis's fake camera binds it too): where a discovery broadcast from any local interface arrives.
    None where the system refuses it; the camera then answers discovery sent to its address only."""
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("255.255.255.255", gvcp.PORT))
    except OSError:
        log.warning("simulated camera: broadcast discovery unavailable (port %d taken)", gvcp.PORT)
        listener.close()
        return None
    listener.settimeout(0.1)
    return listener
