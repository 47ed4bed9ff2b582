"""Kinematics between what plans speak (light positions, turntable degrees) and what devices move
(servo ticks, stage steps), from the rig file.

Gantry (DESIGN §3): the lamp at ``centre + R·(cos el cos az, cos el sin az, sin el)``; azimuth and
elevation servos read ``zero + direction · angle · ticks_per_rev / 360`` ticks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.sphere import azimuth_elevation, direction


@dataclass(frozen=True, eq=False)
class GantryKinematics:
    centre: np.ndarray  # (3,) m
    arm_radius: float
    zero_ticks: tuple[int, int]  # azimuth, elevation servo readings at 0°
    directions: tuple[int, int] = (1, 1)  # +1: ticks grow with the angle
    ticks_per_rev: int = 4096

    def ticks_for(self, azimuth_deg: float, elevation_deg: float) -> tuple[int, int]:
        """Servo goals for gantry angles (degrees), rounded to the nearest tick."""
        per_deg = self.ticks_per_rev / 360.0
        return (
            round(self.zero_ticks[0] + self.directions[0] * azimuth_deg * per_deg),
            round(self.zero_ticks[1] + self.directions[1] * elevation_deg * per_deg),
        )

    def angles_for(self, ticks: tuple[int, int]) -> tuple[float, float]:
        per_deg = self.ticks_per_rev / 360.0
        return (
            (ticks[0] - self.zero_ticks[0]) / (self.directions[0] * per_deg),
            (ticks[1] - self.zero_ticks[1]) / (self.directions[1] * per_deg),
        )

    def tick_span(
        self, azimuth_limits_deg: tuple[float, float], elevation_limits_deg: tuple[float, float]
    ) -> tuple[tuple[int, int], tuple[int, int]]:
        """Per axis, the (lowest, highest) servo ticks that the angle limits map to (may leave the servo's
        range: the rig file's check uses this)."""
        lo = self.ticks_for(azimuth_limits_deg[0], elevation_limits_deg[0])
        hi = self.ticks_for(azimuth_limits_deg[1], elevation_limits_deg[1])
        return (min(lo[0], hi[0]), max(lo[0], hi[0])), (min(lo[1], hi[1]), max(lo[1], hi[1]))

    def servo_limits(
        self, azimuth_limits_deg: tuple[float, float], elevation_limits_deg: tuple[float, float]
    ) -> tuple[tuple[int, int], tuple[int, int]]:
        """The tick limits the servos are configured with and every goal is checked against.

        Position mode spans one turn, 0 … ticks_per_rev − 1, so a full-circle azimuth [−180°, 180°] loses
        its last tick: the two ends are the same place, reachable at −180°.
        """
        top = self.ticks_per_rev - 1
        span = self.tick_span(azimuth_limits_deg, elevation_limits_deg)
        return tuple((max(lo, 0), min(hi, top)) for lo, hi in span)

    def light_position(self, ticks: tuple[int, int]) -> np.ndarray:
        """(3,) world position of the lamp for servo readings — the *measured* light of a frame."""
        az, el = np.radians(self.angles_for(ticks))
        return np.asarray(self.centre) + self.arm_radius * direction(az, el)

    def angles_of(self, position: np.ndarray) -> tuple[float, float]:
        """Gantry angles (degrees) that put the lamp at a world position on its sphere."""
        d = np.asarray(position, float) - np.asarray(self.centre)
        az, el = azimuth_elevation(d / np.linalg.norm(d))
        return float(np.degrees(az)), float(np.degrees(el))


@dataclass(frozen=True)
class TurntableKinematics:
    steps_per_degree: float
    zero_steps: int = 0

    def steps_for(self, degrees: float) -> int:
        return round(self.zero_steps + degrees * self.steps_per_degree)

    def degrees_for(self, steps: int) -> float:
        return (steps - self.zero_steps) / self.steps_per_degree
