"""Kinematics between what plans speak (light positions, turntable degrees) and what devices move
(servo ticks, stage steps), from the rig file.

Gantry: the lamp at ``centre + R·F·(cos el cos az, cos el sin az, sin el)``; azimuth and
elevation servos read ``zero + direction · angle · ticks_per_rev / 360`` ticks. F is the gantry's own
frame (:func:`gantry_frame`): its azimuth axis ``a`` (the rig file's ``gantry.azimuth_axis``, world +z
on a rig built to its drawing), azimuth 0 along world +x projected onto the plane perpendicular to
``a``, elevation measured from that plane. With ``a`` = +z, F is the identity (docs/calibration.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hlr_lab.geometry.sphere import azimuth_elevation, direction


def gantry_frame(azimuth_axis) -> np.ndarray:
    """(3, 3) world ← gantry rotation: columns are the gantry's azimuth-0 direction, the azimuth-90°
    direction and its azimuth axis (unit), all in world coordinates."""
    a = np.asarray(azimuth_axis, float)
    a = a / np.linalg.norm(a)
    x = np.array([1.0, 0.0, 0.0]) - a[0] * a  # world +x projected onto the plane perpendicular to a
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("the gantry's azimuth axis lies along world x: azimuth 0 is undefined")
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(a, x), a], axis=1)


@dataclass(frozen=True, eq=False)
class GantryKinematics:
    """The light gantry: servo ticks ↔ azimuth and elevation ↔ the lamp's position (m, world frame)."""

    centre: np.ndarray  # (3,) m
    arm_radius: float
    # azimuth, elevation servo readings at 0° (whole ticks in a rig file; fractional where the systematic
    # uncertainty moves them, hlr_lab.reflectance.systematic)
    zero_ticks: tuple[float, float]
    directions: tuple[int, int] = (1, 1)  # +1: ticks grow with the angle
    ticks_per_rev: int = 4096
    azimuth_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)  # world direction of the azimuth axis

    @property
    def frame(self) -> np.ndarray:
        """(3, 3) world ← gantry rotation (:func:`gantry_frame`)."""
        return gantry_frame(self.azimuth_axis)

    def unit_direction(self, azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
        """Gantry angles (radians, any shape) → (…, 3) world unit vectors from the centre to the lamp."""
        return direction(azimuth, elevation) @ self.frame.T

    def direction_angles(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(…, 3) world unit vectors from the centre → gantry azimuth and elevation, radians."""
        return azimuth_elevation(np.asarray(d, float) @ self.frame)

    def ticks_for(self, azimuth_deg: float, elevation_deg: float) -> tuple[int, int]:
        """Servo goals for gantry angles (degrees), rounded to the nearest tick."""
        per_deg = self.ticks_per_rev / 360.0
        return (
            round(self.zero_ticks[0] + self.directions[0] * azimuth_deg * per_deg),
            round(self.zero_ticks[1] + self.directions[1] * elevation_deg * per_deg),
        )

    def angles_for(self, ticks: tuple[Any, Any]) -> tuple[Any, Any]:
        """Azimuth and elevation (degrees) at servo readings ``ticks`` (ints, or (N,) arrays of them)."""
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
        (az_lo, az_hi), (el_lo, el_hi) = self.tick_span(azimuth_limits_deg, elevation_limits_deg)
        return (max(az_lo, 0), min(az_hi, top)), (max(el_lo, 0), min(el_hi, top))

    def light_position(self, ticks: tuple[float, float]) -> np.ndarray:
        """(3,) world position of the lamp for servo readings — the *measured* light of a frame."""
        az, el = np.radians(self.angles_for(ticks))
        return np.asarray(self.centre) + self.arm_radius * self.unit_direction(az, el)

    def angles_of(self, position: np.ndarray) -> tuple[float, float]:
        """Gantry angles (degrees) that put the lamp at a world position on its sphere."""
        d = np.asarray(position, float) - np.asarray(self.centre)
        az, el = self.direction_angles(d / np.linalg.norm(d))
        return float(np.degrees(az)), float(np.degrees(el))


@dataclass(frozen=True)
class TurntableKinematics:
    """The turntable: stage steps ↔ degrees."""

    steps_per_degree: float
    zero_steps: int = 0

    def steps_for(self, degrees: float) -> int:
        return round(self.zero_steps + degrees * self.steps_per_degree)

    def degrees_for(self, steps: int) -> float:
        return (steps - self.zero_steps) / self.steps_per_degree
