"""What a procedure drives: the rig's devices as the Protocols of :mod:`drivers.protocols`, so that the same
loop drives hardware or the simulator's endpoints."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.protocols import Camera, Clock, Positioner, Switch, Thermometer
from hlr_lab.session.lamp import WALL_CLOCK


@dataclass(frozen=True)
class Instruments:
    """What acquisition drives: device-unit positioners, a camera and the lamp."""

    turntable: Positioner  # one axis, stage steps
    gantry: Positioner  # azimuth and elevation servo ticks
    camera: Camera
    lamp: Switch
    thermometers: tuple[Thermometer, ...] = ()  # read once per pose, into the pose line and sidecars
    clock: Clock = WALL_CLOCK  # the rig's time: what a warm-up waits in (a simulated world's own)
