"""The simulated bus: servos behind one serial line, served on a pseudo-terminal or a TCP socket.

:meth:`SimBus.handle` turns received bytes into the bytes the servos answer (every instruction of
Protocol 2.0); the transports only move bytes. Faults can be injected per servo, and every goal position
a servo accepts is logged, so tests can prove that nothing outside the limits was ever commanded.

As a real bus does (ROBOTIS e-manual, Protocol 2.0 and the X-series control table):
* nothing a master sends ends the bus: a packet the simulator cannot answer is logged in one line and
  dropped, and the next one is served;
* a partial packet followed by :data:`INTER_BYTE_TIMEOUT_S` of silence is dropped (the servo's receive
  timeout), so a bad length field cannot swallow the packets after it;
* a read beyond the control table is an Access Error with no data (never a reply longer than the table);
* Secondary ID (12): a servo also obeys packets sent to its secondary ID, without a status packet;
* Protocol Type (13): a servo switched to Protocol 1.0 no longer answers Protocol 2.0 (1.0 itself is not
  simulated: it stays silent);
* Baud Rate (8): a pseudo-terminal has no speed of its own, so a servo hears a master at whatever speed
  its port is set to, as if it had been set to match; once Baud Rate is written, it ignores packets sent
  at any other speed until the master's port is switched too (the speed is read from the pty's
  settings, which the master's ``tcsetattr`` sets; over TCP there is none, and every servo hears);
* Bus Watchdog (98): every instruction packet a servo hears, with a good CRC, restarts its watchdog's
  timer (the servo stops itself when the bus stays silent too long: sim.dynamixel.servo).
"""

from __future__ import annotations

import logging
import os
import select
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field

from sim.dynamixel.control_table import BAUD_RATES, BY_NAME
from sim.dynamixel.protocol import (
    BROADCAST_ID,
    STATUS,
    Error,
    Instruction,
    Packet,
    PacketReader,
    crc16,
    status_packet,
)
from sim.dynamixel.servo import SimServo

log = logging.getLogger(__name__)
GOAL_POSITION = BY_NAME["goal_position"]
INTER_BYTE_TIMEOUT_S = 0.01  # silence that ends a partial packet (a master writes a packet in one go)
# how long a master should wait for a reply: the servos are threads of a Python process that may also be
# rendering, on a machine that may be busy, so a reply can be far later than a real servo's (the SDK
# waits 34 ms); the simulated rig's file sets its gantry.reply_timeout_ms to this
CLIENT_REPLY_TIMEOUT_MS = 250
BAUD_CODES = {bps: code for code, bps in BAUD_RATES.items()}
_TERMIOS_SPEEDS = {getattr(termios, f"B{b}"): b for b in BAUD_CODES if hasattr(termios, f"B{b}")}


@dataclass
class Faults:
    """Injected faults of one servo: replies dropped or corrupted (counts), extra reply delay."""

    drop_replies: int = 0
    corrupt_replies: int = 0
    delay_s: float = 0.0


@dataclass
class GoalRecord:
    servo_id: int
    goal: int
    time_s: float


@dataclass
class _Reply:
    servo_id: int
    data: bytes


@dataclass
class SimBus:
    servos: list[SimServo]
    speed_factor: float = 1.0
    goals: list[GoalRecord] = field(default_factory=list)
    faults: dict[int, Faults] = field(default_factory=dict)
    instructions: int = 0  # instruction packets received (transactions, for the acquisition benchmark)

    def __post_init__(self):
        for (
            s
        ) in self.servos:  # every goal a servo is sent, accepted or not, directly or through Indirect Data
            s.on_goal = lambda servo, goal: self.goals.append(GoalRecord(servo.id, goal, servo.clock()))
        self._reader = PacketReader(INTER_BYTE_TIMEOUT_S)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._fds: list[int] = []
        self._sockets: list[socket.socket] = []

    @classmethod
    def with_servos(
        cls, ids: list[int], *, speed_factor: float = 1.0, positions: dict[int, int] | None = None, **servo_kw
    ) -> SimBus:
        """Servos sharing one clock; ``positions`` gives where some of them rest at power-up (else 2048)."""
        t0 = time.monotonic()
        clock: Callable[[], float] = lambda: (time.monotonic() - t0) * speed_factor  # noqa: E731
        at = positions or {}
        return cls(
            [SimServo(i, clock, **({"position": at[i]} if i in at else {}), **servo_kw) for i in ids],
            speed_factor,
        )

    def servo(self, servo_id: int) -> SimServo:
        return next(s for s in self.servos if s.id == servo_id)

    def fault(self, servo_id: int) -> Faults:
        return self.faults.setdefault(servo_id, Faults())

    # -- protocol ---------------------------------------------------------------------------------
    def handle(self, data: bytes, *, line_baud: int | None = None) -> bytes:
        """Bytes in from the master → bytes the servos send back (faults applied). ``line_baud``: the
        speed the master's port is set to (None: a link without one, e.g. TCP)."""
        with self._lock:
            out = bytearray()
            for packet in self._reader.feed(data, time.monotonic()):
                self.instructions += 1
                try:
                    for reply in self._dispatch(packet, line_baud):
                        out.extend(self._apply_faults(reply))
                except Exception as exc:  # a bug answering one packet must not end the bus for good
                    log.warning("dropped instruction 0x%02x to ID %d: %s: %s", packet.instruction, packet.id,
                                type(exc).__name__, exc)  # fmt: skip
                    log.debug("the packet that could not be answered", exc_info=True)
            return bytes(out)

    def _listening(self, line_baud: int | None) -> list[SimServo]:
        """The servos that can hear a Protocol 2.0 packet sent at ``line_baud``."""
        heard = []
        for s in self.servos:
            if s.get("protocol_type") != 2:
                continue
            if s.line_baud is not None and line_baud in BAUD_CODES and s.line_baud != line_baud:
                continue
            heard.append(s)
        return heard

    def _dispatch(self, p: Packet, line_baud: int | None = None) -> list[_Reply]:
        listening = self._listening(line_baud)
        if p.crc_ok:
            for servo in listening:
                servo.heard()
        broadcast = p.id == BROADCAST_ID
        if not broadcast:  # a servo also obeys its secondary ID, silently (no status packet)
            for s in listening:
                if s.id != p.id and s.get("secondary_id") == p.id and p.crc_ok:
                    self._single(s, p.instruction, p.params, True)
        targets = listening if broadcast else [s for s in listening if s.id == p.id]
        if not p.crc_ok:
            return (
                [] if broadcast else [_Reply(s.id, status_packet(s.id, Error.CRC | s.alert)) for s in targets]
            )
        i, params = p.instruction, p.params
        if i in (
            Instruction.SYNC_READ,
            Instruction.FAST_SYNC_READ,
            Instruction.SYNC_WRITE,
            Instruction.BULK_READ,
            Instruction.FAST_BULK_READ,
            Instruction.BULK_WRITE,
        ):
            return (
                self._group(i, params, listening)
                if broadcast
                else self._unicast_error(targets, Error.INSTRUCTION)
            )
        replies = []
        for s in targets:
            error, payload, level = self._single(s, i, params, broadcast)
            if i == Instruction.PING:
                replies.append(_Reply(s.id, status_packet(s.id, error, payload)))  # ping always answers
            elif not broadcast and s.get("status_return_level") >= level:
                replies.append(_Reply(s.id, status_packet(s.id, error, payload)))
            if i == Instruction.REBOOT and error & 0x7F == 0:
                s.reboot()
        return replies

    def _single(self, s: SimServo, i: int, params: bytes, broadcast: bool) -> tuple[int, bytes, int]:
        """(error, payload, the status return level at which it is answered) of one servo."""
        if i == Instruction.PING:
            return s.alert, s.model_and_firmware(), 0
        if i == Instruction.READ:
            if len(params) != 4:
                return Error.DATA_LENGTH | s.alert, b"", 1
            error, data = s.read(_u16(params, 0), _u16(params, 2))
            return error, data, 1
        if i in (Instruction.WRITE, Instruction.REG_WRITE):
            if len(params) < 3:
                return Error.DATA_LENGTH | s.alert, b"", 2
            address, data = _u16(params, 0), params[2:]
            write = s.write if i == Instruction.WRITE else s.reg_write
            error = write(address, data)
            return error, b"", 2
        if i == Instruction.ACTION:
            return s.action(), b"", 2
        if i == Instruction.FACTORY_RESET:
            option = params[0] if params else 0xFF
            if broadcast and option == 0xFF:
                return Error.RESULT_FAIL, b"", 2  # the manual: not activated for broadcast + reset all
            return s.factory_reset(option), b"", 2
        if i == Instruction.REBOOT:
            return s.alert, b"", 2
        if i == Instruction.CLEAR:
            if params[:5] != b"\x01\x44\x58\x4c\x22":
                return Error.DATA_RANGE | s.alert, b"", 2
            return s.clear_multi_turn(), b"", 2
        return Error.INSTRUCTION | s.alert, b"", 2

    def _group(self, i: int, params: bytes, listening: list[SimServo]) -> list[_Reply]:
        if i in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ, Instruction.SYNC_WRITE):
            if len(params) < 4:
                return []
            address, length = _u16(params, 0), _u16(params, 2)
            if i == Instruction.SYNC_WRITE:
                step = 1 + length
                for k in range(4, len(params) - step + 1, step):
                    s = self._find(params[k])
                    if s is not None and s in listening:
                        data = params[k + 1 : k + step]
                        s.write(address, data)
                return []
            reads = [(sid, address, length) for sid in params[4:]]
        elif i == Instruction.BULK_WRITE:
            k = 0
            while k + 5 <= len(params):
                sid, address, length = params[k], _u16(params, k + 1), _u16(params, k + 3)
                data = params[k + 5 : k + 5 + length]
                s = self._find(sid)
                if s is not None and s in listening:
                    s.write(address, data)
                k += 5 + length
            return []
        else:
            reads = [
                (params[k], _u16(params, k + 1), _u16(params, k + 3)) for k in range(0, len(params) - 4, 5)
            ]
        results = []
        for sid, address, length in reads:
            s = self._find(sid)
            if s is None or s not in listening or s.get("status_return_level") < 1:
                continue  # a missing servo stays silent, as on a real bus
            error, data = s.read(address, length)  # an error: no data (never more than the table holds)
            results.append((s, error, data))
        if i in (Instruction.SYNC_READ, Instruction.BULK_READ):
            return [_Reply(s.id, status_packet(s.id, error, data)) for s, error, data in results]
        # a FAST read's one packet has a fixed-size block per servo, with no room for a refusal: a servo
        # that cannot read what was asked leaves its block out (the master sees it missing, not garbage)
        results = [r for r in results if r[1] & 0x7F == 0]
        return [_Reply(BROADCAST_ID, _fast_read_packet(results))] if results else []

    def _unicast_error(self, targets, error) -> list[_Reply]:
        return [_Reply(s.id, status_packet(s.id, error | s.alert)) for s in targets]

    def _find(self, servo_id: int) -> SimServo | None:
        return next((s for s in self.servos if s.id == servo_id), None)

    def _apply_faults(self, reply: _Reply) -> bytes:
        f = self.faults.get(reply.servo_id)
        if f is None:
            return reply.data
        if f.drop_replies > 0:
            f.drop_replies -= 1
            return b""
        data = bytearray(reply.data)
        if f.corrupt_replies > 0:
            f.corrupt_replies -= 1
            data[-3] ^= 0x5A  # a flipped byte just before the CRC: the receiver's CRC check fails
        if f.delay_s > 0:
            time.sleep(f.delay_s)
        return bytes(data)

    # -- transports -----------------------------------------------------------------------------
    def serve_pty(self) -> str:
        """Serve the bus on a new pseudo-terminal; returns the device path a driver opens."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._fds += [master, slave]  # keep the slave open: the master reads EIO when no one holds it
        self._start(lambda: self._pump_fd(master, slave))
        return os.ttyname(slave)

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Serve the bus on TCP (one client at a time); returns a ``socket://host:port`` URL for pyserial."""
        server = socket.create_server((host, port))
        server.settimeout(0.1)
        self._sockets.append(server)
        self._start(lambda: self._pump_tcp(server))
        return f"socket://{host}:{server.getsockname()[1]}"

    def _start(self, target) -> None:
        t = threading.Thread(target=target, name="sim-dynamixel-bus", daemon=True)
        t.start()
        self._threads.append(t)

    def _pump_fd(self, fd: int, slave: int) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(fd, 4096)
                line_baud = _TERMIOS_SPEEDS.get(termios.tcgetattr(slave)[5])  # as the master set its port
            except (OSError, termios.error):
                return
            reply = self.handle(data, line_baud=line_baud)
            if reply:
                self._delay(reply)
                os.write(fd, reply)

    def _pump_tcp(self, server: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = server.accept()
            except (TimeoutError, OSError):
                continue
            with conn:
                conn.settimeout(0.05)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                while not self._stop.is_set():
                    try:
                        data = conn.recv(4096)
                    except TimeoutError:
                        continue
                    except OSError:
                        break
                    if not data:
                        break
                    reply = self.handle(data)
                    if reply:
                        self._delay(reply)
                        conn.sendall(reply)

    def _delay(self, reply: bytes) -> None:
        """The first replier's Return Delay Time (2 µs per unit), as the device waits before answering."""
        if len(reply) > 4:
            s = self._find(reply[4])
            if s is not None and s.get("return_delay_time"):
                time.sleep(s.get("return_delay_time") * 2e-6)

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        for fd in self._fds:
            os.close(fd)
        for s in self._sockets:
            s.close()
        self._threads, self._fds, self._sockets = [], [], []

    def __enter__(self) -> SimBus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _u16(b: bytes, at: int) -> int:
    return int.from_bytes(b[at : at + 2], "little")


def _fast_read_packet(results) -> bytes:
    """One status packet (ID 0xFE) holding ``ERR ID data CRC`` per servo; each CRC covers everything sent
    before it, so the last one is the packet's own CRC (as dynamixel-sdk reads it)."""
    body_len = sum(4 + len(data) for _, _, data in results)
    out = bytearray(
        b"\xff\xff\xfd\x00" + bytes([BROADCAST_ID]) + (body_len + 1).to_bytes(2, "little") + bytes([STATUS])
    )
    for s, error, data in results:
        out += bytes([error, s.id]) + data
        out += crc16(bytes(out)).to_bytes(2, "little")
    return bytes(out)
