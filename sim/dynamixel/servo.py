"""One simulated X-series servo: its control table with the device's access rules, and its motion.

Motion follows the trapezoidal profile of Profile Velocity / Profile Acceleration (0 = as fast as the
velocity limit / no ramp), evaluated lazily from a clock, so no thread ticks in the background. Time is
the bus's clock: real time × the speed factor. In Velocity Control Mode (1) the axis turns at Goal
Velocity (no ramp).

What the e-manual (XM430-W350) says and the servo does:
* Present Position is brought within one turn (0–4095, Homing Offset applied) when Operating Mode is
  changed to Position Control Mode (3) and when torque is enabled in that mode ("Present Position(132)",
  note); a change of Operating Mode also resets Profile Velocity and Profile Acceleration to 0 and Goal
  PWM / Goal Current to their limits ("Operating Mode(11)", note).
* Indirect Data n reads and writes the control-table byte that Indirect Address n names, with that
  byte's field's size, range and access ("Indirect Address, Indirect Data"): a multi-byte field is
  written whole, through consecutive Indirect Data bytes naming its consecutive addresses. (An Indirect
  Address naming Indirect Data itself answers an Access Error here.)
* Clear Multi-Turn is refused only while the axis really moves.
* Bus Watchdog (98), 1–127 × 20 ms: with torque on, a silence on the bus longer than that stops the axis
  where it is (no profile) and sets Bus Watchdog to −1; Goal PWM, Current, Velocity and Position then
  answer a Data Range Error until Bus Watchdog is written 0 ("Bus Watchdog(98)"). Every instruction
  packet the servo hears restarts the timer (the e-manual counts "all the Instruction Packet"), whoever
  it is addressed to.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from sim.dynamixel.control_table import (
    ACCELERATION_UNIT_TICKS_PER_S2,
    BAUD_RATES,
    BUS_WATCHDOG_UNIT_S,
    BY_ADDRESS,
    BY_NAME,
    EEPROM_END,
    FIELDS,
    GOAL_VALUES,
    INDIRECT_OF_DATA,
    OPERATING_MODES,
    TABLE_SIZE,
    TICKS_PER_REV,
    VELOCITY_UNIT_TICKS_PER_S,
    Field,
)
from sim.dynamixel.protocol import Error

VELOCITY_MODE = 1
POSITION_MODES = (3, 4, 5)  # position, extended position, current-based position
# Hardware Error Status bits
OVERHEATING = 0x04
OVERLOAD = 0x20


@dataclass
class _Profile:
    start: float
    goal: float
    t0: float
    v_max: float  # ticks/s
    accel: float  # ticks/s², inf for no ramp

    @classmethod
    def held(cls, position: float, t: float) -> _Profile:
        """The axis standing at ``position`` from ``t`` on."""
        return cls(position, position, t, 1.0, math.inf)

    def timing(self) -> tuple[float, float, float]:
        """(ramp time, peak speed, total time)."""
        d = abs(self.goal - self.start)
        if d == 0:
            return 0.0, 0.0, 0.0
        if math.isinf(self.accel):
            return 0.0, self.v_max, d / self.v_max
        ramp = self.v_max / self.accel
        if d < self.v_max * ramp:  # triangular: never reaches v_max
            ramp = math.sqrt(d / self.accel)
            return ramp, self.accel * ramp, 2 * ramp
        return ramp, self.v_max, 2 * ramp + (d - self.v_max * ramp) / self.v_max

    def state(self, t: float) -> tuple[float, float]:
        """(position, velocity) at time t, in ticks and ticks/s."""
        ramp, peak, total = self.timing()
        s = max(0.0, t - self.t0)
        sign = 1.0 if self.goal >= self.start else -1.0
        if s >= total:
            return self.goal, 0.0
        a = self.accel
        if s < ramp:
            return self.start + sign * 0.5 * a * s * s, sign * a * s
        cruise = total - 2 * ramp
        ramp_dist = 0.5 * peak * ramp if ramp > 0 else 0.0
        if s < ramp + cruise:
            return self.start + sign * (ramp_dist + peak * (s - ramp)), sign * peak
        r = total - s
        return self.goal - sign * 0.5 * a * r * r, sign * a * r

    def done(self, t: float) -> bool:
        return t - self.t0 >= self.timing()[2]


@dataclass
class _Spin:
    """Velocity Control Mode: from ``start`` at ``velocity`` ticks/s since ``t0``, until told otherwise."""

    start: float
    velocity: float
    t0: float

    def state(self, t: float) -> tuple[float, float]:
        return self.start + self.velocity * max(0.0, t - self.t0), self.velocity

    def done(self, t: float) -> bool:
        return self.velocity == 0


class SimServo:
    def __init__(
        self,
        servo_id: int,
        clock: Callable[[], float],
        *,
        model_number: int = 1020,
        firmware: int = 48,
        position: int = 2048,
    ):
        self.clock = clock
        self.table = bytearray(TABLE_SIZE)
        self._defaults = {f.name: f.default for f in FIELDS}
        self._defaults.update(model_number=model_number, firmware_version=firmware, id=servo_id)
        for f in FIELDS:
            self._put(f, self._defaults[f.name])
        self._put(BY_NAME["goal_position"], position)
        self._profile = _Profile.held(position, clock())
        self._registered: tuple[int, bytes] | None = None
        self.stuck = False  # an injected fault: the axis does not follow its profile
        self.temperature_c = 30.0  # at rest; torque adds a little heat
        self.on_goal: Callable[[SimServo, int], None] = lambda _servo, _goal: None  # hears every goal sent
        self.line_baud: int | None = None  # once Baud Rate is written, the only speed it hears
        self.input_voltage_dv = 120  # 12.0 V
        self._heard_at = clock()  # the last instruction packet heard (the bus watchdog's timer)

    def heard(self) -> None:
        """An instruction packet reached the servo: the bus watchdog judges the silence before it, then its
        timer restarts."""
        now = self.clock()
        self._watch(now)
        self._heard_at = now

    def _watch(self, now: float) -> None:
        """Expire the bus watchdog if the bus has been silent longer than it allows, with torque on: the
        axis stops where it was at that moment."""
        if not self.has(BY_NAME["bus_watchdog"]):
            return
        allowed = self.get("bus_watchdog") * BUS_WATCHDOG_UNIT_S
        if allowed <= 0 or not self.get("torque_enable") or now - self._heard_at <= allowed:
            return
        expired = self._heard_at + allowed
        self._profile = _Profile.held(self._profile.state(expired)[0], expired)
        self._put(BY_NAME["bus_watchdog"], -1)

    # -- table access -------------------------------------------------------------------------
    @property
    def id(self) -> int:
        return self.get("id")

    def has(self, f: Field) -> bool:
        """Whether this servo's firmware has ``f`` (the e-manual adds some fields in later versions)."""
        return self.get("firmware_version") >= f.since_firmware

    def get(self, name: str) -> int:
        f = BY_NAME[name]
        return int.from_bytes(self.table[f.address : f.end], "little", signed=f.signed)

    def _put(self, f: Field, value: int) -> None:
        self.table[f.address : f.end] = int(value).to_bytes(f.size, "little", signed=f.signed or value < 0)

    @property
    def alert(self) -> int:
        return Error.ALERT if self.get("hardware_error_status") else 0

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error, data): ``length`` bytes from ``address``, Indirect Data resolved. Beyond the table is
        an Access Error with no data (the e-manual, Protocol 2.0 status errors: "read a value in an
        Address that ... has not been defined")."""
        if length < 1 or address < 0 or address + length > TABLE_SIZE:
            return Error.ACCESS | self.alert, b""
        self._refresh()
        data = bytearray(self.table[address : address + length])
        for a in range(address, address + length):
            if a in INDIRECT_OF_DATA:
                target = self._indirect_target(a)
                if target is None:
                    return Error.ACCESS | self.alert, b""
                data[a - address] = self.table[target]
        return self.alert, bytes(data)

    def _indirect_target(self, data_address: int) -> int | None:
        """The control-table address Indirect Data at ``data_address`` stands for (None: itself indirect)."""
        target = self.get(INDIRECT_OF_DATA[data_address].name)
        return None if target in INDIRECT_OF_DATA else target

    def write(self, address: int, data: bytes, *, apply: bool = True) -> int:
        """Check a write against the device's rules; apply it unless ``apply`` is False (reg write)."""
        error, values = self._checked(address, data, sent=apply)
        if error:
            return error | self.alert
        if apply:
            for f, value in values:
                self._apply(f, value)
        return self.alert

    def _checked(self, address: int, data: bytes, *, sent: bool) -> tuple[int, list[tuple[Field, int]]]:
        """(error, the (field, value) pairs to apply) of a write, Indirect Data resolved to its targets;
        ``sent``: a write being carried out (not a REG_WRITE held for ACTION), whose goals are heard."""
        fields, error = self._fields_covering(address, len(data))
        if error:
            return error, []
        values: list[tuple[Field, int]] = []
        through: list[tuple[int, int]] = []  # (target address, byte) written through Indirect Data
        for f in fields:
            raw = data[f.address - address : f.end - address]
            if f.address in INDIRECT_OF_DATA:
                target = self._indirect_target(f.address)
                if target is None:
                    return Error.ACCESS, []
                through.append((target, raw[0]))
                continue
            value = int.from_bytes(raw, "little", signed=f.signed)
            if sent and f.name == "goal_position":
                self.on_goal(self, value)
            if not f.writable or not self.has(f):
                return Error.ACCESS, []  # read-only, or a field this firmware does not have
            if f.address < EEPROM_END and self.get("torque_enable"):
                return Error.ACCESS, []  # EEPROM is locked while torque is on
            if not f.low <= value <= f.high or (f.name == "operating_mode" and value not in OPERATING_MODES):
                return Error.DATA_RANGE, []
            if (
                f.name == "goal_position"
                and self.get("operating_mode") == 3
                and not (self.get("min_position_limit") <= value <= self.get("max_position_limit"))
            ):
                return Error.DATA_LIMIT, []
            if f.name == "goal_velocity" and abs(value) > self.get("velocity_limit"):
                return Error.DATA_LIMIT, []
            if f.name in GOAL_VALUES and self.get("bus_watchdog") == -1:
                return Error.DATA_RANGE, []  # read-only until Bus Watchdog is written 0
            if f.name == "torque_enable" and value == 1 and self.get("hardware_error_status"):
                return Error.RESULT_FAIL, []  # after a shutdown only a reboot restores torque
            values.append((f, value))
        k = 0
        while k < len(through):  # runs of consecutive target addresses, each a write of its own
            run = 1
            while k + run < len(through) and through[k + run][0] == through[k][0] + run:
                run += 1
            error, more = self._checked(through[k][0], bytes(b for _, b in through[k : k + run]), sent=sent)
            if error:
                return error, []
            values += more
            k += run
        return Error.NONE, values

    def _fields_covering(self, address: int, length: int) -> tuple[list[Field], int]:
        if length < 1 or address + length > TABLE_SIZE:
            return [], Error.ACCESS
        fields, a = [], address
        while a < address + length:
            f = BY_ADDRESS.get(a)
            if f is None:
                return [], Error.ACCESS  # not the start of a field: undefined or mid-field
            if f.end > address + length:
                return [], Error.DATA_LENGTH
            fields.append(f)
            a = f.end
        return fields, Error.NONE

    def _apply(self, f: Field, value: int) -> None:
        mode = self.get("operating_mode")
        if f.name == "operating_mode" and value != mode:
            resets = {"profile_velocity": 0, "profile_acceleration": 0, "goal_pwm": self.get("pwm_limit"),
                      "goal_current": self.get("current_limit")}  # fmt: skip
            for name, reset in resets.items():
                self._put(BY_NAME[name], reset)
        if f.name == "torque_enable" and value == 0:
            self._freeze()
        self._put(f, value)
        if f.name == "baud_rate":
            self.line_baud = BAUD_RATES[value]
        if f.name == "goal_position" and mode in POSITION_MODES:
            self._start_motion(value)
        if (f.name == "operating_mode" and value == 3 and value != mode) or (
            f.name == "torque_enable" and value == 1 and mode == 3
        ):
            self._within_one_turn()
        if mode == VELOCITY_MODE and (
            f.name == "goal_velocity" or (f.name == "torque_enable" and value == 1)
        ):
            self._spin()

    def _within_one_turn(self) -> None:
        """Present Position brought to 0–4095 (Homing Offset applied), the axis where it is."""
        here, _ = self._profile.state(self.clock())
        offset = self.get("homing_offset")
        turned = (round(here) + offset) % TICKS_PER_REV - offset
        self._profile = _Profile.held(turned, self.clock())

    # -- motion -------------------------------------------------------------------------------
    def _start_motion(self, goal: int) -> None:
        now = self.clock()
        here, _ = self._profile.state(now)
        if not self.get("torque_enable"):
            return  # the goal is stored; nothing moves without torque
        v = self.get("profile_velocity") or self.get("velocity_limit") or 1
        a = self.get("profile_acceleration")
        self._profile = _Profile(
            here,
            goal,
            now,
            v * VELOCITY_UNIT_TICKS_PER_S,
            a * ACCELERATION_UNIT_TICKS_PER_S2 if a else math.inf,
        )

    def _spin(self) -> None:
        """Velocity Control Mode with torque on: turn at Goal Velocity from where the axis is."""
        if not self.get("torque_enable"):
            return
        now = self.clock()
        here, _ = self._profile.state(now)
        self._profile = _Spin(here, self.get("goal_velocity") * VELOCITY_UNIT_TICKS_PER_S, now)

    def _freeze(self) -> None:
        here, _ = self._profile.state(self.clock())
        self._profile = _Profile.held(here, self.clock())

    def _refresh(self) -> None:
        now = self.clock()
        self._watch(now)
        if self.stuck:
            self._profile.t0 = now  # the profile never advances
            pos, vel, moving = self._profile.start, 0.0, True
        else:
            pos, vel = self._profile.state(now)
            moving = not self._profile.done(now)
        present = round(pos) + self.get("homing_offset")
        self._put(BY_NAME["present_position"], present)
        self._put(BY_NAME["present_velocity"], round(vel / VELOCITY_UNIT_TICKS_PER_S))
        self._put(BY_NAME["position_trajectory"], round(pos))
        self._put(BY_NAME["moving"], int(moving))
        in_position = abs(self.get("goal_position") - present) <= self.get("moving_threshold")
        trapezoid = 0x30 if self.get("profile_velocity") and self.get("profile_acceleration") else 0
        self._put(
            BY_NAME["moving_status"], int(in_position and not moving) | (0x02 if moving else 0) | trapezoid
        )
        self._put(
            BY_NAME["present_current"],
            400 if self.stuck else (120 if moving else 5) * self.get("torque_enable"),
        )
        self._put(BY_NAME["realtime_tick"], int(now * 1000) % 32768)
        self._put(BY_NAME["present_temperature"], round(self.temperature_c) + 3 * self.get("torque_enable"))
        self._put(BY_NAME["present_input_voltage"], self.input_voltage_dv)

    def present_position(self) -> int:
        self._refresh()
        return self.get("present_position")

    # -- instructions beyond read/write ----------------------------------------------------------
    def reg_write(self, address: int, data: bytes) -> int:
        error = self.write(address, data, apply=False)
        if error & 0x7F == 0:
            self._registered = (address, bytes(data))
            self._put(BY_NAME["registered_instruction"], 1)
        return error

    def action(self) -> int:
        if self._registered is None:
            return Error.INSTRUCTION | self.alert
        address, data = self._registered
        self._registered = None
        self._put(BY_NAME["registered_instruction"], 0)
        return self.write(address, data)

    def reboot(self) -> None:
        """Torque off, RAM back to defaults, hardware errors cleared; EEPROM and position kept."""
        here = self.present_position()
        for f in FIELDS:
            if f.address >= EEPROM_END and f.writable:
                self._put(f, self._defaults[f.name])
        self._put(BY_NAME["hardware_error_status"], 0)
        self._put(BY_NAME["goal_position"], here)
        self._profile = _Profile.held(here, self.clock())
        self._registered = None
        self._put(BY_NAME["registered_instruction"], 0)

    def factory_reset(self, option: int) -> int:
        keep = {0x01: ("id",), 0x02: ("id", "baud_rate")}.get(option, ())
        if option not in (0x01, 0x02, 0xFF):
            return Error.DATA_RANGE | self.alert
        if self.get("torque_enable"):
            return Error.ACCESS | self.alert
        for f in FIELDS:
            if f.writable and f.name not in keep:
                self._put(f, self._defaults[f.name] if f.name != "id" else 1)
        if self.line_baud is not None and "baud_rate" not in keep:  # back at the factory 57 600
            self.line_baud = BAUD_RATES[self.get("baud_rate")]
        return self.alert

    def clear_multi_turn(self) -> int:
        if not self._profile.done(self.clock()):  # the axis itself, not a Moving byte last read
            return Error.RESULT_FAIL | self.alert
        here = self.present_position() % TICKS_PER_REV
        self._profile = _Profile.held(here, self.clock())
        return self.alert

    def slip(self, ticks: int, *, hold_s: float = math.inf) -> None:
        """An injected fault: the axis is knocked ``ticks`` away from where it is (a slipping coupling, a
        bump) and stays there for ``hold_s`` of the bus's time before its position loop, if torque is on,
        brings it back to the goal along its profile."""
        now = self.clock()
        here, _ = self._profile.state(now)
        p = self._profile
        if isinstance(p, _Spin):
            self._profile = _Spin(here + ticks, p.velocity, now + hold_s)
            return
        self._profile = _Profile(here + ticks, p.goal, now + hold_s, p.v_max, p.accel)

    def hardware_fault(self, bits: int = OVERLOAD) -> None:
        """An injected fault (overload, overheating…): alert bit on, torque dropped until a reboot."""
        self._freeze()
        self._put(BY_NAME["hardware_error_status"], self.get("hardware_error_status") | bits)
        self._put(BY_NAME["torque_enable"], 0)

    def model_and_firmware(self) -> bytes:
        return self.get("model_number").to_bytes(2, "little") + bytes([self.get("firmware_version")])
