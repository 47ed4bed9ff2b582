"""The rotary stage's mechanics: trapezoidal moves in steps, homing, soft limits, alarms, and the lamp.

Pure state evaluated from a clock (real time × speed factor); the Modbus server reads and drives it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from sim.turntable import register_map as rm


@dataclass
class _Move:
    start: float
    goal: float
    t0: float
    speed: float
    accel: float
    decel: float

    def timing(self) -> tuple[float, float, float, float]:
        """(accelerating, cruising, decelerating) durations and peak speed."""
        d = abs(self.goal - self.start)
        if d == 0:
            return 0.0, 0.0, 0.0, 0.0
        v = self.speed
        ta, td = v / self.accel, v / self.decel
        ramps = 0.5 * v * (ta + td)
        if ramps > d:  # never reaches full speed
            v = math.sqrt(2 * d * self.accel * self.decel / (self.accel + self.decel))
            ta, td = v / self.accel, v / self.decel
            return ta, 0.0, td, v
        return ta, (d - ramps) / v, td, v

    def state(self, t: float) -> tuple[float, float]:
        ta, tc, td, v = self.timing()
        s = max(0.0, t - self.t0)
        sign = 1.0 if self.goal >= self.start else -1.0
        if s >= ta + tc + td:
            return self.goal, 0.0
        if s < ta:
            return self.start + sign * 0.5 * self.accel * s * s, sign * self.accel * s
        if s < ta + tc:
            return self.start + sign * (0.5 * v * ta + v * (s - ta)), sign * v
        r = ta + tc + td - s
        return self.goal - sign * 0.5 * self.decel * r * r, sign * self.decel * r

    def done(self, t: float) -> bool:
        ta, tc, td, _ = self.timing()
        return t - self.t0 >= ta + tc + td


class RotaryStage:
    def __init__(
        self,
        clock: Callable[[], float],
        *,
        limits: tuple[int, int] = (-18_000, 18_000),
        max_speed: int = 20_000,
        position: int = 0,
    ):
        self.clock = clock
        self.limits = limits
        self.max_speed = max_speed
        self.data = {  # the direct data operation's fields, as a fresh drive holds them
            rm.DATA_NO: 0,
            rm.OP_TYPE: rm.ABSOLUTE,
            rm.TARGET: 0,
            rm.SPEED: 2000,
            rm.ACCELERATION: 4000,
            rm.DECELERATION: 4000,
            rm.CURRENT: 500,
            rm.FORWARDING: 0,
        }
        self.trigger = 0  # a negative trigger: the item whose next write starts a move
        self.command = 0
        self.maintenance = dict.fromkeys(rm.MAINTENANCE, 0)  # each command acts as it goes from 0 to 1
        self.alarm = 0
        self.homed = False
        self.excited = True
        self.lamp = False
        self.moves: list[int] = []  # every target a START/trigger commanded, as received
        self._move = _Move(position, position, clock(), 1.0, 1.0, 1.0)

    # -- what the server reads ---------------------------------------------------------------------
    def position(self) -> float:
        return self._move.state(self.clock())[0]

    def velocity(self) -> float:
        return self._move.state(self.clock())[1]

    def moving(self) -> bool:
        return not self._move.done(self.clock())

    def status(self) -> int:
        """Driver output status, lower word (register_map)."""
        moving = self.moving()
        bits = 0 if moving or self.alarm else rm.READY
        if moving:
            bits |= rm.MOVE
        elif not self.alarm:
            bits |= rm.IN_POS
        if self.homed:
            bits |= rm.HOME_END
        if self.alarm:
            bits |= rm.ALARM
        return bits

    # -- what the server writes --------------------------------------------------------------------
    def valid(self, address: int, value: int) -> bool:
        return {
            rm.DATA_NO: 0 <= value <= 255,
            rm.OP_TYPE: value in (rm.ABSOLUTE, rm.INCREMENTAL, rm.INCREMENTAL_FEEDBACK),
            rm.SPEED: 0 < value <= self.max_speed,
            rm.ACCELERATION: value > 0,
            rm.DECELERATION: value > 0,
            rm.CURRENT: 0 <= value <= 1000,
            rm.TARGET: True,
            rm.TRIGGER: -7 <= value <= 1,
            rm.FORWARDING: value in (0, 1),
        }.get(address, address not in rm.MAINTENANCE or value in (0, 1))

    def set_command(self, bits: int) -> None:
        rising = bits & ~self.command
        self.command = bits
        if rising & rm.ALARM_RESET:
            self.alarm = 0
        if rising & rm.STOP:
            self.stop()
        if rising & rm.FREE:
            self.stop()
            self.excited = False
        elif not bits & rm.FREE:
            self.excited = True
        if rising & rm.ZHOME:
            self._go(0, homing=True)
        if rising & rm.START:
            self.start()

    def maintain(self, address: int, value: int) -> None:
        """A maintenance command written (register_map): executed when it goes from 0 to 1."""
        rising = value == 1 and self.maintenance[address] == 0
        self.maintenance[address] = value
        if rising and address == rm.MAINTENANCE_ALARM_RESET:
            self.alarm = 0
        if rising and address == rm.MAINTENANCE_P_PRESET and not self.moving():
            self._move = _Move(0, 0, self.clock(), 1.0, 1.0, 1.0)  # the preset position, 0
            self.homed = True

    def start(self) -> None:
        """Start the direct operation held in the data registers."""
        here = round(self.position())
        incremental = self.data[rm.OP_TYPE] in (rm.INCREMENTAL, rm.INCREMENTAL_FEEDBACK)
        target = self.data[rm.TARGET] + (here if incremental else 0)
        self.moves.append(target)
        self._go(target)

    def _go(self, target: int, homing: bool = False) -> None:
        if self.alarm or not self.excited:
            return  # a drive in alarm, or de-energised, does not move
        if not self.limits[0] <= target <= self.limits[1]:
            self.alarm = rm.ALARM_OVERTRAVEL
            return
        now = self.clock()
        here = self._move.state(now)[0]
        self._move = _Move(
            here, target, now, self.data[rm.SPEED], self.data[rm.ACCELERATION], self.data[rm.DECELERATION]
        )
        if homing:
            self.homed = True

    def stop(self) -> None:
        here = self.position()
        self._move = _Move(here, here, self.clock(), 1.0, 1.0, 1.0)

    def fault(self, code: int = rm.ALARM_OVERLOAD) -> None:
        """An injected drive fault: motion stops and the alarm is raised until ALM-RST."""
        self.stop()
        self.alarm = code
