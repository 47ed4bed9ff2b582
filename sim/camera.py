"""The simulated camera as a device: it photographs the world where the simulated axes actually are.

The light position comes from the servos' *present* positions and the turntable angle from the stage's
present (encoder) position — not from what was commanded — so kinematic and timing bugs in the
drivers show up in the frames, as they would on the real rig. The lamp is the relay's coil.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sim.clock import WorldClock
from sim.dynamixel.bus import SimBus
from sim.lamp import LampModel
from sim.render.sensor import SensorModel
from sim.turntable.server import TurntableServer

if TYPE_CHECKING:  # the renderer imports Mitsuba: only when a camera is really made
    from sim.render.renderer import Renderer


@dataclass(frozen=True)
class GantryGeometry:
    """The physical truth of the light gantry: arm about ``centre``, servo ticks → angles, and the
    direction of the azimuth axis (azimuth 0 along world +x projected onto the plane perpendicular to
    it, elevation from that plane; +z on a gantry built to its drawing)."""

    centre: tuple[float, float, float] = (0.0, 0.0, 0.07)
    arm_radius: float = 0.30
    azimuth_servo: int = 1
    elevation_servo: int = 2
    zero_ticks: tuple[int, int] = (2048, 1024)  # ticks at azimuth 0° and elevation 0°
    ticks_per_rev: int = 4096
    directions: tuple[int, int] = (1, 1)  # +1: ticks grow with the angle
    azimuth_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def light_position(self, azimuth_ticks: int, elevation_ticks: int) -> np.ndarray:
        per_rad = self.ticks_per_rev / (2 * np.pi)
        az = (azimuth_ticks - self.zero_ticks[0]) / (self.directions[0] * per_rad)
        el = (elevation_ticks - self.zero_ticks[1]) / (self.directions[1] * per_rad)
        up = np.asarray(self.azimuth_axis, float) / np.linalg.norm(self.azimuth_axis)
        ahead = np.array([1.0, 0.0, 0.0]) - up[0] * up  # azimuth 0: world x, in the plane of the arm
        ahead /= np.linalg.norm(ahead)
        side = np.cross(up, ahead)
        arm = np.cos(el) * (np.cos(az) * ahead + np.sin(az) * side) + np.sin(el) * up
        return np.asarray(self.centre) + self.arm_radius * arm


@dataclass(frozen=True)
class StageGeometry:
    steps_per_degree: float = 100.0
    zero_steps: int = 0  # the stage's reading where the plate is at 0°

    def degrees(self, steps: float) -> float:
        return (steps - self.zero_steps) / self.steps_per_degree


@dataclass
class SimCamera:
    renderer: Renderer
    sensor: SensorModel
    bus: SimBus
    turntable: TurntableServer
    gantry: GantryGeometry = GantryGeometry()
    stage: StageGeometry = StageGeometry()
    seed: int = 0
    lamp: LampModel = field(default_factory=LampModel)
    clock: WorldClock = field(default_factory=WorldClock)  # the lamp drifts in the world's time
    frames: int = field(default=0, init=False)

    def pose(self) -> dict:
        """Where the axes are now: light position (m), turntable angle (degrees), lamp."""
        g = self.gantry
        az = self.bus.servo(g.azimuth_servo).present_position()
        el = self.bus.servo(g.elevation_servo).present_position()
        stage = self.turntable.stage
        return {
            "light_position_m": g.light_position(az, el).tolist(),
            "servo_ticks": [az, el],
            "turntable_deg": float(self.stage.degrees(stage.position())),
            "lamp": bool(stage.lamp),
        }

    def capture(self, exposure_s: float, gain_db: float = 0.0) -> tuple[np.ndarray, dict]:
        """One raw frame (H, W, 3) uint16 and what the simulator knows about it."""
        pose = self.pose()
        light = np.asarray(pose["light_position_m"])
        if (
            self.renderer.spec.light == "directional"
        ):  # a distant lamp: light travels from it toward the object
            light = np.asarray(self.gantry.centre) - light
        lamp_output = self.lamp.output(self.clock.now(), np.random.default_rng([self.seed, self.frames, 1]))
        with self.clock.paused():  # the exposure is taken now; rendering it is not the world's time
            radiance = self.renderer.render(
                pose["turntable_deg"], light, lamp_on=pose["lamp"], seed=self.seed + self.frames
            )
        rng = np.random.default_rng([self.seed, self.frames])
        self.frames += 1
        frame = self.sensor.expose(radiance * lamp_output, exposure_s, rng, gain_db)
        truth = {
            "exposure_s": exposure_s,
            "gain_db": gain_db,
            "bits": self.sensor.bits,
            "lamp_output": lamp_output,
        }
        return frame, {**pose, **truth}
