"""The light gantry: two (or more) Dynamixel X-series servos in position mode, over dynamixel-sdk.

* Ports are device paths or pyserial URLs (``socket://host:port``, ``loop://``): the SDK's PortHandler
  opens ``serial.Serial(port=…)``, which cannot take URLs, so :class:`UrlPortHandler` uses
  ``serial.serial_for_url``. The SDK waits 2 × 16 + 2 ms for a status packet beyond the bytes' time on
  the wire (twice an FTDI adapter's default 16 ms latency timer); :attr:`GantryConfig.reply_timeout_ms`
  sets that wait (a simulated servo, a thread of a busy process, needs longer; an adapter whose latency
  timer is set to 1 ms, ``/sys/bus/usb-serial/devices/ttyUSB0/latency_timer``, can take less).
* Connect: ping, check the model, refuse a servo in hardware alarm (or reboot it if allowed), then with
  torque off write the EEPROM settings and read each back, then the profile, then torque on.
* Goals outside the configured limits are refused before anything is sent. Both axes move with one sync
  write; their state comes back with one sync read. Reads and register writes (which set a value, so
  repeating one does what sending it once does) are retried a bounded number of times with backoff,
  each retry logged with ``RETRY``. The move itself is a broadcast without a reply, so it has nothing
  to retry on: a move that does not arrive ends in a settle timeout, never in a silent second move.
* SDK result codes never leave this module: they become :mod:`drivers.errors` exceptions; so does a
  link that disappears (an unplugged adapter, a dead simulator: pyserial's ``SerialException``/``OSError``).
* The SDK is not thread-safe, and a transaction cut short (an exception raised in the middle of one)
  leaves its PortHandler marked busy for good ("Port is in use!"). Every transaction therefore runs
  under one lock, and a port left busy is cleared before the next one (:meth:`_transaction`).
* :meth:`park` is the safe-state step: it retries the torque-off writes and reads them back, so it says
  only what the servos confirmed.
* Position Control mode is set on every connect. A real servo then reads its position within one turn
  (0–4095; e-manual, "Present Position"), however far a previous program turned it in Extended
  Position mode, so the first move goes the short way; the mode change also zeroes the profile, which
  is therefore written after it.
* REG_WRITE/ACTION are not used: a servo answers ACTION with a status packet, which the SDK's
  ``action()`` does not read, so the next exchange would take it for its own reply. Code that ever uses
  them must flush the port (``clearPort``) after each ACTION.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypeVar

import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncWrite,
    PortHandler,
)
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from drivers.errors import (
    ChecksumError,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    HardwareAlarm,
    LimitError,
    SettleTimeout,
)
from drivers.retrying import retried

log = logging.getLogger(__name__)
T = TypeVar("T")
try:  # a vanished tty fails termios calls (pyserial's buffer resets) with termios.error, not an OSError
    from termios import error as _TermiosError
except ImportError:  # not on POSIX
    _TermiosError = OSError
LINK_LOST = (serial.SerialException, OSError, _TermiosError)

X_SERIES_MODELS = {1020: "XM430-W350", 1030: "XM430-W210", 1060: "XL430-W250", 1120: "XM540-W270"}
# control table (X-series e-manual)
FIRMWARE, RETURN_DELAY, OPERATING_MODE = 6, 9, 11
TEMPERATURE_LIMIT, MAX_VOLTAGE, MIN_VOLTAGE, MAX_POSITION, MIN_POSITION = 31, 32, 34, 48, 52
TORQUE_ENABLE, HARDWARE_ERROR, BUS_WATCHDOG = 64, 70, 98
BUS_WATCHDOG_FIRMWARE = 38  # the e-manual: Bus Watchdog (98) exists from firmware v38
PROFILE_ACCELERATION, PROFILE_VELOCITY, GOAL_POSITION = 108, 112, 116
MOVING, PRESENT_POSITION, PRESENT_VOLTAGE, PRESENT_TEMPERATURE = 122, 132, 144, 146
POSITION_MODE = 3
ERROR_NAMES = {
    1: "result fail",
    2: "instruction error",
    3: "CRC error",
    4: "data range error",
    5: "data length error",
    6: "data limit error",
    7: "access error",
}
HARDWARE_BITS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}


@dataclass(frozen=True)
class ServoReport:
    """What one servo says about itself, read without changing anything (``hlr-lab doctor``)."""

    axis: Axis
    model: str
    firmware: int
    hardware_error: tuple[str, ...]  # names of the set Hardware Error Status bits
    torque_on: bool
    position: int
    stored_limits: tuple[int, int]  # min, max position limit in the servo's EEPROM
    temperature_c: int
    temperature_limit_c: int
    voltage_v: float
    voltage_limits_v: tuple[float, float]  # min, max input voltage before the servo shuts down


SDK_REPLY_TIMEOUT_MS = 2 * 16 + 2  # dynamixel-sdk's wait: twice its LATENCY_TIMER (16 ms), plus 2 ms


class UrlPortHandler(PortHandler):
    """dynamixel-sdk's PortHandler, opening any pyserial URL or device path, and waiting
    ``reply_timeout_ms`` (plus the packet's time on the wire) for a reply instead of the SDK's fixed
    :data:`SDK_REPLY_TIMEOUT_MS`."""

    def __init__(self, port_name: str, reply_timeout_ms: float = SDK_REPLY_TIMEOUT_MS):
        super().__init__(port_name)
        self.reply_timeout_ms = reply_timeout_ms

    def setPacketTimeout(self, packet_length):  # the SDK's formula (port_handler.py), with our wait
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.reply_timeout_ms

    def setupPort(self, cflag_baud):
        if self.is_open:
            self.closePort()
        self.ser = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


@dataclass(frozen=True)
class Axis:
    """One servo of the gantry: its Dynamixel ID, the travel allowed in ticks, and a name for messages."""

    servo_id: int
    min_ticks: int
    max_ticks: int
    name: str = ""

    @property
    def label(self) -> str:
        return self.name or f"servo {self.servo_id}"


@dataclass(frozen=True)
class GantryConfig:
    """How to reach and drive the gantry: its bus (port, baud rate), its axes, the motion profile
    (Dynamixel units), and when an axis counts as arrived (ticks off the goal, seconds held)."""

    port: str
    axes: tuple[Axis, ...]
    baudrate: int = 1_000_000
    profile_velocity: int = 100  # 0.229 rev/min per unit
    profile_acceleration: int = 20  # 214.6 rev/min² per unit
    tolerance_ticks: int = 2
    settle_s: float = 0.05
    retries: int = 3
    backoff_s: float = 0.01
    reboot_on_alarm: bool = False  # only when the operator allowed it
    reply_timeout_ms: float = SDK_REPLY_TIMEOUT_MS  # the wait for a status packet, beyond its bytes' time


@dataclass
class DynamixelGantry:
    """The light gantry's servos as a :class:`drivers.protocols.Positioner` in servo ticks (the
    module's docstring says how it talks to them). ``connect`` configures and energises them; ``move_to``
    refuses a goal outside the configured tick limits before anything is sent; ``park`` is the safe
    state. Device errors are :mod:`drivers.errors` exceptions naming the servo and the port."""

    config: GantryConfig
    retried: int = field(default=0, init=False)  # reads that needed a retry

    def __post_init__(self):
        self.port = UrlPortHandler(self.config.port, self.config.reply_timeout_ms)
        try:
            opened = self.port.openPort()
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(
                f"cannot open the port ({exc}); check the cable and the port in the rig file",
                device=self.name,
            ) from exc
        if not opened:
            raise DeviceError(
                "cannot open the port; check the cable and the port in the rig file", device=self.name
            )
        self.ph = Protocol2PacketHandler()  # what PacketHandler(2.0) returns; the servos speak only 2.0
        self._goal: tuple[int, ...] | None = None
        self._lock = threading.RLock()  # one SDK transaction at a time, whichever thread asks

    @property
    def name(self) -> str:
        return f"gantry on {self.config.port}"

    # -- connection -------------------------------------------------------------------------------
    def connect(self) -> dict[int, str]:
        """Ping, check, configure and energise every axis; returns {servo id: model name}."""
        models = {}
        for axis in self.config.axes:
            # a servo in alarm answers even a ping with the alert bit; the check below says what to do
            model = self._retry(
                lambda a=axis: self._call(a, "ping", *self._tx_rx(self.ph.ping, a.servo_id), alert_ok=True)
            )
            if model not in X_SERIES_MODELS:
                raise DeviceFault(
                    f"model number {model} is not an X-series servo this driver knows",
                    device=self._device(axis),
                    code=0,
                )
            models[axis.servo_id] = X_SERIES_MODELS[model]
            self._clear_alarm(axis)
            self._write(axis, TORQUE_ENABLE, 0, 1)  # the EEPROM is locked while torque is on
            # a bus watchdog another program left on would stop the axis during a long exposure (no packet
            # for seconds) and refuse its goals after: off, and an expired one cleared (e-manual, Bus
            # Watchdog(98)); hlr-lab makes the rig safe itself
            has_watchdog = self._read(axis, FIRMWARE, 1) >= BUS_WATCHDOG_FIRMWARE
            watchdog = [(BUS_WATCHDOG, 0, 1)] if has_watchdog else []
            for address, value, size in (
                (OPERATING_MODE, POSITION_MODE, 1),
                (RETURN_DELAY, 0, 1),
                (MAX_POSITION, axis.max_ticks, 4),
                (MIN_POSITION, axis.min_ticks, 4),
                (PROFILE_ACCELERATION, self.config.profile_acceleration, 4),
                (PROFILE_VELOCITY, self.config.profile_velocity, 4),
                *watchdog,
            ):
                self._write(axis, address, value, size)
                if self._read(axis, address, size) != value:
                    raise DeviceFault(
                        f"wrote {value} at address {address} but read back something else",
                        device=self._device(axis),
                        code=0,
                    )
            self._write(axis, TORQUE_ENABLE, 1, 1)
        return models

    def inspect(self, axis: Axis) -> ServoReport:
        """Read one servo's identity, limits and health; writes nothing, so it is safe on any rig state."""
        model = self._retry(
            lambda: self._call(axis, "ping", *self._tx_rx(self.ph.ping, axis.servo_id), alert_ok=True)
        )

        def read(address: int, size: int) -> int:  # a servo in alarm still answers; that is the point here
            return self._read(axis, address, size, alert_ok=True)

        status = read(HARDWARE_ERROR, 1)
        return ServoReport(
            axis=axis,
            model=X_SERIES_MODELS.get(model, f"model {model} (not an X-series servo this driver knows)"),
            firmware=read(FIRMWARE, 1),
            hardware_error=tuple(n for bit, n in HARDWARE_BITS.items() if status & bit),
            torque_on=bool(read(TORQUE_ENABLE, 1)),
            position=read(PRESENT_POSITION, 4),
            stored_limits=(read(MIN_POSITION, 4), read(MAX_POSITION, 4)),
            temperature_c=read(PRESENT_TEMPERATURE, 1),
            temperature_limit_c=read(TEMPERATURE_LIMIT, 1),
            voltage_v=read(PRESENT_VOLTAGE, 2) / 10,
            voltage_limits_v=(read(MIN_VOLTAGE, 2) / 10, read(MAX_VOLTAGE, 2) / 10),
        )

    def temperatures(self) -> dict[str, float]:
        """Present temperature of every servo, °C, by axis label."""
        return {axis.label: float(self._read(axis, PRESENT_TEMPERATURE, 1)) for axis in self.config.axes}

    def _clear_alarm(self, axis: Axis) -> None:
        status = self._read(axis, HARDWARE_ERROR, 1)
        if not status:
            return
        what = ", ".join(n for bit, n in HARDWARE_BITS.items() if status & bit) or f"0x{status:02x}"
        if not self.config.reboot_on_alarm:
            raise HardwareAlarm(
                f"hardware error ({what}); find the cause, then allow a reboot of the servo",
                device=self._device(axis),
                status=status,
            )
        log.warning("%s: hardware error (%s); rebooting as allowed", self._device(axis), what)
        self._call(axis, "reboot", None, *self._tx_rx(self.ph.reboot, axis.servo_id), alert_ok=True)
        time.sleep(0.1)

    # -- motion -------------------------------------------------------------------------------------
    def move_to(self, goal: tuple[int, ...]) -> None:
        """Send every axis its goal (ticks) in one sync write; refuses any goal outside the limits first."""
        if len(goal) != len(self.config.axes):
            raise LimitError(f"{len(goal)} goals for {len(self.config.axes)} axes", device=self.name)
        for axis, ticks in zip(self.config.axes, goal, strict=True):
            if not axis.min_ticks <= ticks <= axis.max_ticks:
                raise LimitError(
                    f"goal {ticks} ticks is outside [{axis.min_ticks}, {axis.max_ticks}]; nothing was sent",
                    device=self._device(axis),
                )
        writer = GroupSyncWrite(self.port, self.ph, GOAL_POSITION, 4)
        for axis, ticks in zip(self.config.axes, goal, strict=True):
            writer.addParam(axis.servo_id, list(int(ticks).to_bytes(4, "little", signed=True)))
        with self._transaction():
            result = writer.txPacket()
        if result != COMM_SUCCESS:  # a sync write has no reply: only the transmission can fail here
            raise DeviceError(
                f"the goal could not be sent ({self.ph.getTxRxResult(result)})", device=self.name
            )
        self._goal = tuple(int(t) for t in goal)

    def position(self) -> tuple[int, ...]:
        return tuple(p for p, _ in self._state())

    def wait_settled(self, timeout_s: float) -> tuple[int, ...]:
        """Until every axis is within tolerance of its goal and not moving for ``settle_s``."""
        if self._goal is None:
            return self.position()
        deadline, settled_since = time.monotonic() + timeout_s, None
        while True:
            state = self._state()
            done = all(
                abs(p - g) <= self.config.tolerance_ticks and not moving
                for (p, moving), g in zip(state, self._goal, strict=True)
            )
            now = time.monotonic()
            if done:
                settled_since = settled_since or now
                if now - settled_since >= self.config.settle_s:
                    return tuple(p for p, _ in state)
            else:
                settled_since = None
            if now > deadline:
                late = [
                    f"{a.label} at {p} (goal {g})"
                    for a, (p, _), g in zip(self.config.axes, state, self._goal, strict=True)
                    if abs(p - g) > self.config.tolerance_ticks
                ]
                raise SettleTimeout(
                    f"not settled after {timeout_s:g} s: {', '.join(late) or 'still moving'}; "
                    "check for an obstruction or a stuck axis",
                    device=self.name,
                )
            time.sleep(0.002)

    def stop(self) -> None:
        """Hold every axis where it is now."""
        here = self.position()
        self.move_to(
            tuple(min(max(p, a.min_ticks), a.max_ticks) for p, a in zip(here, self.config.axes, strict=True))
        )

    def park(self, *, torque_off: bool = True, attempts: int = 3) -> str:
        """The safe state, confirmed by the servos: torque off on every axis (read back), or with
        ``torque_off`` False the arm held where it is and seen not moving. Each axis is tried
        ``attempts`` times; returns what was confirmed, raises :class:`DeviceError` naming every axis
        that could not be made safe."""
        failed = []
        for axis in self.config.axes:
            problem = "not tried (attempts < 1)"
            for attempt in range(1, attempts + 1):
                try:
                    # a servo in hardware alarm (overload…) answers with the alert bit, and has shut its
                    # torque off itself: what it reads back is what counts
                    if torque_off:
                        self._write(axis, TORQUE_ENABLE, 0, 1, alert_ok=True)
                        confirmed = self._read(axis, TORQUE_ENABLE, 1, alert_ok=True) == 0
                    else:
                        confirmed = self._read(axis, MOVING, 1, alert_ok=True) == 0
                    if confirmed:
                        break
                    problem = "the servo still reports " + ("torque on" if torque_off else "moving")
                except DeviceError as exc:
                    problem = exc.reason
                log.warning("%s: not safe yet (%s); attempt %d of %d", self._device(axis), problem, attempt,
                            attempts)  # fmt: skip
                time.sleep(0.05 * attempt)
            else:
                failed.append(f"{axis.label}: {problem}")
        if failed:
            raise DeviceError(
                ("could not switch torque off" if torque_off else "the arm is not holding still")
                + f" ({'; '.join(failed)})",
                device=self.name,
            )
        return "torque off (read back)" if torque_off else "holding, not moving (read back)"

    def close(self, *, torque_off: bool = True) -> None:
        """Leave the servos safe (torque off unless the park policy keeps it) and release the port; a
        failure to park is logged, the port is released anyway (use :meth:`park` to know)."""
        try:
            if torque_off:
                self.park(torque_off=True)
        except DeviceError as exc:
            log.error("%s", exc)
        finally:
            self.release()

    def release(self) -> None:
        """Close the port (nothing is sent); a port that has vanished is closed all the same."""
        with self._lock:
            try:
                self.port.closePort()
            except LINK_LOST as exc:
                log.warning("%s: closing the port: %s", self.name, exc)

    # -- transport ----------------------------------------------------------------------------------
    def _state(self) -> list[tuple[int, bool]]:
        """(present position, moving) of every axis from one sync read of 122…135, retried on link faults."""
        length = PRESENT_POSITION + 4 - MOVING
        return self._retry(
            lambda: self._sync_read(
                MOVING,
                length,
                lambda d: (
                    int.from_bytes(bytes(d[PRESENT_POSITION - MOVING :]), "little", signed=True),
                    bool(d[0]),
                ),
            )
        )

    def _sync_read(self, address: int, length: int, decode):
        ids = [a.servo_id for a in self.config.axes]
        with self._transaction():
            result = self.ph.syncReadTx(self.port, address, length, ids, len(ids), False)
            if result != COMM_SUCCESS:
                raise DeviceError(
                    f"sync read could not be sent ({self.ph.getTxRxResult(result)})", device=self.name
                )
            out = []
            for axis in self.config.axes:
                data, result, error = self.ph.readRx(self.port, axis.servo_id, length)
                self._call(axis, "sync read", None, result, error)
                out.append(decode(data))
            return out

    def _read(self, axis: Axis, address: int, size: int, *, alert_ok: bool = False) -> int:
        reader = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx, 4: self.ph.read4ByteTxRx}[size]
        value = self._retry(
            lambda: self._call(
                axis, f"read {address}", *self._tx_rx(reader, axis.servo_id, address), alert_ok=alert_ok
            )
        )
        return value - (1 << 32) if size == 4 and value >= 1 << 31 else value

    def _write(self, axis: Axis, address: int, value: int, size: int, *, alert_ok: bool = False) -> None:
        writer = {1: self.ph.write1ByteTxRx, 2: self.ph.write2ByteTxRx, 4: self.ph.write4ByteTxRx}[size]
        raw = value & ((1 << (8 * size)) - 1)
        self._retry(
            lambda: self._call(
                axis,
                f"write {address}",
                None,
                *self._tx_rx(writer, axis.servo_id, address, raw),
                alert_ok=alert_ok,
            )
        )

    def _tx_rx(self, exchange, *args):
        """One SDK request/reply exchange (``exchange(port, *args)``) under the port's lock."""
        with self._transaction():
            return exchange(self.port, *args)

    @contextmanager
    def _transaction(self):
        """Hold the port for one SDK transaction. A port still marked busy was left so by a transaction
        cut short (its reply may still be on the way): wait out a reply time, drop what arrived, and
        free it. A vanished link becomes a :class:`DeviceError` naming the gantry."""
        with self._lock:
            if self.port.is_using:
                log.warning("%s: the previous exchange was cut short; clearing the port", self.name)
                time.sleep(self.config.reply_timeout_ms / 1000 + 0.005)  # a late reply has arrived by then
                self.port.clearPort()
                self.port.is_using = False
            try:
                yield
            except LINK_LOST as exc:
                self.port.is_using = False
                raise DeviceError(
                    f"the link is lost ({exc}); check the adapter's cable and the servos' power",
                    device=self.name,
                ) from exc

    def _call(self, axis: Axis, what: str, value, result: int, error: int = 0, *, alert_ok: bool = False):
        """Turn an SDK result into a value or an exception."""
        device = self._device(axis)
        if result == COMM_RX_TIMEOUT:
            raise DeviceTimeout(f"no reply to {what}", device=device)
        if result == COMM_RX_CORRUPT:
            raise ChecksumError(f"corrupted reply to {what}", device=device)
        if result != COMM_SUCCESS:
            raise DeviceError(f"{what} failed ({self.ph.getTxRxResult(result)})", device=device)
        if error & 0x80 and not alert_ok and what != f"read {HARDWARE_ERROR}":
            status = self._read(axis, HARDWARE_ERROR, 1)
            names = ", ".join(n for bit, n in HARDWARE_BITS.items() if status & bit) or f"0x{status:02x}"
            raise HardwareAlarm(
                f"hardware error ({names}) during {what}; torque is off until a reboot",
                device=device,
                status=status,
            )
        if error & 0x7F:
            code = error & 0x7F
            raise DeviceFault(
                f"{what} refused: {ERROR_NAMES.get(code, f'error {code}')}", device=device, code=code
            )
        return value

    def _retry(self, operation: Callable[[], T]) -> T:
        """Repeat an exchange on a timeout or corrupted reply, with growing pauses; then give up
        (:func:`drivers.retrying.retried`)."""

        def before_retry(_: BaseException) -> None:
            self.retried += 1
            with self._transaction():
                self.port.clearPort()  # a late reply must not be taken for the next one

        return retried(
            operation,
            retries=self.config.retries,
            backoff_s=self.config.backoff_s,
            on=(DeviceTimeout, ChecksumError),
            log=log,
            before_retry=before_retry,
        )

    def _device(self, axis: Axis) -> str:
        return f"gantry {axis.label} (id {axis.servo_id}) on {self.config.port}"
