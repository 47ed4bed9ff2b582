"""The turntable (a Modbus rotary stage: an Oriental Motor AZ driver's direct data operation) and the lamp
relay, over pymodbus.

The register map is :class:`StageMap`: by default an AZ series driver's (Oriental Motor, AZ Series
Function Edition HM-60262E, "Modbus RTU control"; the simulator serves the same map,
``sim/turntable/register_map.py``); the rig file's ``[turntable] registers = {…}`` moves any address or
bit for another drive. 32-bit values span two registers, the upper word first. A move is one FC16 write
of the direct data (position, speed, rates, current) with its trigger set to 1, which starts it; ZHOME,
STOP and ALM-RST are driver input command bits acting on their rising edge. Reads and writes are retried
with backoff (reconnecting after a dropped link), each retry logged with ``RETRY``. Repeating a write is
safe because every write here sets a value: an absolute target (a repeated start goes where the first
went), a coil state, or a command word pulsed clear-set-clear whose bit acts on its rising edge (so a repeated
"set" never acts twice). pymodbus types never leave this module.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar, cast

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.errors import (
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
EXCEPTIONS = {1: "illegal function", 2: "illegal address", 3: "illegal value", 4: "device failure", 6: "busy"}


@dataclass(frozen=True)
class StageMap:
    """Where the drive keeps what the driver uses (register numbers, 0-based) and which bits mean what;
    the defaults are an AZ series driver's (module docstring)."""

    unit: int = 1
    op_type: int = 0x5A  # direct data operation: operation type …
    target: int = 0x5C  # … position …
    speed: int = 0x5E  # … operating speed (steps/s) …
    acceleration: int = 0x60  # … starting/changing rate (steps/s²) …
    deceleration: int = 0x62  # … stopping rate …
    current: int = 0x64  # … operating current (0.1 %) …
    trigger: int = 0x66  # … and its trigger (1: start with all of it)
    command: int = 0x7C  # driver input command
    status: int = 0x7E  # driver output status
    alarm: int = 0x80  # present alarm
    position: int = 0xCC  # feedback position
    home_bit: int = 0x10  # ZHOME
    stop_bit: int = 0x20  # STOP
    alarm_reset_bit: int = 0x80  # ALM-RST
    ready_bit: int = 0x20  # READY
    move_bit: int = 0x2000  # MOVE
    in_position_bit: int = 0x4000  # IN-POS
    alarm_bit: int = 0x80  # ALM-A
    absolute: int = 1  # operation type: absolute positioning
    start: int = 1  # trigger value that starts the operation


@dataclass(frozen=True)
class DriveReport:
    """What the turntable drive says of itself: ready, in position, its alarm code and position (steps)."""

    ready: bool
    in_position: bool
    alarm: int  # the drive's alarm code, 0 when none
    position: int  # steps


@dataclass(frozen=True)
class StageConfig:
    """How to reach and drive the turntable: its Modbus address, the travel allowed (steps), its
    register map, speed (steps/s) and acceleration (steps/s²)."""

    address: str  # "host:port" (TCP) or a serial device path (RTU)
    min_steps: int
    max_steps: int
    map: StageMap = StageMap()
    baudrate: int = 115_200
    speed: int = 4000  # steps/s
    acceleration: int = 8000  # steps/s²
    current: int = 500  # per mille
    tolerance_steps: int = 1
    timeout_s: float = 1.0
    retries: int = 3
    backoff_s: float = 0.02
    reset_alarm: bool = False  # only when the operator allowed it


def _client(address: str, baudrate: int, timeout: float):
    if address.startswith("/") or address.startswith("COM"):
        return ModbusSerialClient(address, baudrate=baudrate, timeout=timeout, retries=0)
    host, _, port = address.removeprefix("tcp://").rpartition(":")
    return ModbusTcpClient(host, port=int(port), timeout=timeout, retries=0)


@dataclass
class ModbusStage:
    """The turntable's drive over Modbus (TCP or RTU): a :class:`~drivers.protocols.Positioner` of one
    axis in steps. Every exchange is retried by the retry policy; one that keeps failing raises
    :class:`~drivers.errors.DeviceTimeout` naming the drive."""

    config: StageConfig
    retried: int = field(default=0, init=False)

    def __post_init__(self):
        self.client = _client(self.config.address, self.config.baudrate, self.config.timeout_s)
        if not self.client.connect():
            raise DeviceError(
                "cannot connect; check the address in the rig file and that the drive is powered",
                device=self.name,
            )
        self._goal: int | None = None

    @property
    def name(self) -> str:
        return f"turntable on {self.config.address}"

    def connect(self) -> None:
        """Refuse a drive in alarm (or reset it if allowed), then load the operation data in one write."""
        status, alarm, _ = self._state()
        if status & self.config.map.alarm_bit:
            if not self.config.reset_alarm:
                raise HardwareAlarm(
                    f"the drive is in alarm (code 0x{alarm:02x}); find the cause, then allow an alarm reset",
                    device=self.name,
                    status=alarm,
                )
            self._command(self.config.map.alarm_reset_bit)
        m = self.config.map
        self._write_fields([(m.op_type, m.absolute), (m.speed, self.config.speed),
                            (m.acceleration, self.config.acceleration), (m.deceleration, self.config.acceleration),
                            (m.current, self.config.current)])  # fmt: skip

    def move_to(self, goal: tuple[int, ...]) -> None:
        (steps,) = goal
        if not self.config.min_steps <= steps <= self.config.max_steps:
            raise LimitError(
                f"goal {steps} steps is outside [{self.config.min_steps}, {self.config.max_steps}]; "
                "nothing was sent",
                device=self.name,
            )
        m = self.config.map
        c = self.config
        self._write_fields([(m.op_type, m.absolute), (m.target, int(steps)), (m.speed, c.speed),
                            (m.acceleration, c.acceleration), (m.deceleration, c.acceleration),
                            (m.current, c.current), (m.trigger, m.start)])  # fmt: skip  # one write: it starts
        self._goal = int(steps)

    def home(self, timeout_s: float) -> None:
        self._command(self.config.map.home_bit)
        self._goal = 0
        self.wait_settled(timeout_s)

    def position(self) -> tuple[int, ...]:
        return (self._state()[2],)

    def wait_settled(self, timeout_s: float) -> tuple[int, ...]:
        deadline = time.monotonic() + timeout_s
        m = self.config.map
        while True:
            status, alarm, position = self._state()
            if status & m.alarm_bit:
                raise HardwareAlarm(
                    f"the drive raised alarm 0x{alarm:02x} while moving", device=self.name, status=alarm
                )
            if (
                status & m.in_position_bit
                and status & m.ready_bit
                and (self._goal is None or abs(position - self._goal) <= self.config.tolerance_steps)
            ):
                return (position,)
            if time.monotonic() > deadline:
                raise SettleTimeout(
                    f"not in position after {timeout_s:g} s (at {position}, goal {self._goal})",
                    device=self.name,
                )
            time.sleep(0.002)

    def stop(self) -> None:
        self._command(self.config.map.stop_bit)

    def halt(self, timeout_s: float = 5.0) -> str:
        """The safe-state step: STOP, then wait until the drive reports it is not moving (MOVE clear).
        Returns what the drive confirmed; raises :class:`DeviceError` when it did not."""
        self.stop()
        deadline = time.monotonic() + timeout_s
        while True:
            status, _, position = self._state()
            if not status & self.config.map.move_bit:
                return f"stopped at {position} steps (read back)"
            if time.monotonic() > deadline:
                raise SettleTimeout(
                    f"still moving {timeout_s:g} s after STOP (at {position})", device=self.name
                )
            time.sleep(0.01)

    def reconnect(self) -> None:
        """A fresh link: nothing of an exchange cut short (a late reply) can be taken for the next one."""
        self.client.close()
        if not self.client.connect():
            raise DeviceTimeout(
                "cannot reconnect; check the cable and that the drive is powered", device=self.name
            )

    def inspect(self) -> DriveReport:
        """The drive's status, alarm code and position; writes nothing (``hlr-lab doctor``)."""
        status, alarm, position = self._state()
        m = self.config.map
        return DriveReport(
            ready=bool(status & m.ready_bit),
            in_position=bool(status & m.in_position_bit),
            alarm=alarm if status & m.alarm_bit else 0,
            position=position,
        )

    def close(self) -> None:
        self.client.close()

    # -- transport ------------------------------------------------------------------------------------
    def _command(self, bit: int) -> None:
        """A pulse of one input bit: clear, set (its rising edge acts), clear again (an AZ driver starts
        nothing while STOP is held, and a held bit could not rise for the next command)."""
        for word in (0, bit, 0):
            self._write(self.config.map.command, [word])

    def _write(self, address: int, values: list[int]) -> None:
        """``values`` as consecutive int32 fields from ``address``, in one FC16 write."""
        registers = [
            r for v in values for r in self.client.convert_to_registers(int(v), self.client.DATATYPE.INT32)
        ]
        self._retry(
            lambda: self._check(
                self._io(
                    lambda: self.client.write_registers(address, registers, device_id=self.config.map.unit)
                ),
                f"write at {address}",
            )
        )

    def _write_fields(self, fields: list[tuple[int, int]]) -> None:
        """(address, int32 value) fields, in order: each run of adjacent ones in one write (on an AZ
        driver the whole direct data is one run, so a move is one write whose trigger starts it)."""
        run: list[tuple[int, int]] = []
        for address, value in fields:
            if run and address != run[-1][0] + 2:
                self._write(run[0][0], [v for _, v in run])
                run = []
            run.append((address, value))
        if run:
            self._write(run[0][0], [v for _, v in run])

    def _state(self) -> tuple[int, int, int]:
        """(status, alarm code, position), in as few reads as the map allows (an AZ: status and alarm
        are adjacent, the position is not)."""
        m = self.config.map
        if m.alarm == m.status + 2 and m.position == m.alarm + 2:
            status, alarm, position = self._read(m.status, 3)
            return status, alarm, position
        if m.alarm == m.status + 2:
            status, alarm = self._read(m.status, 2)
        else:
            (status,), (alarm,) = self._read(m.status, 1), self._read(m.alarm, 1)
        (position,) = self._read(m.position, 1)
        return status, alarm, position

    def _read(self, address: int, n: int) -> list[int]:
        """n int32 values from ``address``, retried on link faults."""

        def read():
            rr = self._check(
                self._io(
                    lambda: self.client.read_holding_registers(
                        address, count=2 * n, device_id=self.config.map.unit
                    )
                ),
                f"read at {address}",
            )
            int32 = self.client.DATATYPE.INT32  # converts to one int (the union is over all data types)
            return [
                cast(int, self.client.convert_from_registers(rr.registers[2 * i : 2 * i + 2], int32))
                for i in range(n)
            ]

        return self._retry(read)

    def _retry(self, operation: Callable[[], T]) -> T:
        """Repeat an exchange whose reply was lost (or whose link dropped), with growing pauses, on a link
        connected again if it dropped (:func:`drivers.retrying.retried`)."""

        def count(_: BaseException) -> None:
            self.retried += 1

        def reconnect_if_dropped() -> None:
            if not self.client.connected:
                self.client.connect()

        return retried(
            operation,
            retries=self.config.retries,
            backoff_s=self.config.backoff_s,
            on=(DeviceTimeout,),
            log=log,
            before_retry=count,
            after_pause=reconnect_if_dropped,
        )

    def _io(self, call):
        try:
            return call()
        except (ConnectionException, OSError) as exc:  # pymodbus does not wrap every socket or serial error
            self.client.close()
            raise DeviceTimeout(f"the link dropped ({exc})", device=self.name) from exc
        except ModbusIOException as exc:
            raise DeviceTimeout(f"no reply ({exc})", device=self.name) from exc
        except ModbusException as exc:
            raise DeviceError(f"Modbus error ({exc})", device=self.name) from exc

    def _check(self, response, what: str):
        if response.isError():
            code = getattr(response, "exception_code", 0)
            raise DeviceFault(
                f"{what} refused: exception {code} ({EXCEPTIONS.get(code, 'unknown')})",
                device=self.name,
                code=code,
            )
        return response


@dataclass
class ModbusRelay:
    """The lamp: one coil of a Modbus relay module (it may share the stage's link)."""

    client_owner: ModbusStage
    unit: int = 2
    coil: int = 0

    def set(self, on: bool) -> None:
        stage = self.client_owner
        stage._retry(
            lambda: stage._check(
                stage._io(lambda: stage.client.write_coil(self.coil, bool(on), device_id=self.unit)),
                "lamp switch",
            )
        )

    def get(self) -> bool:
        stage = self.client_owner
        rr = stage._retry(
            lambda: stage._check(
                stage._io(lambda: stage.client.read_coils(self.coil, count=1, device_id=self.unit)),
                "lamp read",
            )
        )
        return bool(rr.bits[0])

    def switch_off(self) -> str:
        """The safe-state step: coil off, then read back; raises :class:`DeviceError` if it stays on."""
        self.set(False)
        if self.get():
            raise DeviceFault(
                f"coil {self.coil} still reads on after switching it off", device=self.name, code=0
            )
        return "off (read back)"

    @property
    def name(self) -> str:
        return f"lamp relay (device {self.unit}, coil {self.coil}) on {self.client_owner.config.address}"
