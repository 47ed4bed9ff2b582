"""What the acquisition runner needs from devices: small structural Protocols, satisfied by real and
simulated devices alike (no inheritance needed)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Positioner(Protocol):
    """Axes that move to a goal (device units), report where they are, and can be stopped."""

    def move_to(self, goal: tuple[int, ...]) -> None: ...

    def wait_settled(self, timeout_s: float) -> tuple[int, ...]: ...

    def position(self) -> tuple[int, ...]: ...

    def stop(self) -> None: ...


@runtime_checkable
class Switch(Protocol):
    """Something on or off (the lamp)."""

    def set(self, on: bool) -> None: ...

    def get(self) -> bool: ...


@runtime_checkable
class Thermometer(Protocol):
    """A device that reports its temperatures (°C by part name), for the frames' sidecars."""

    def temperatures(self) -> dict[str, float]: ...


@runtime_checkable
class Clock(Protocol):
    """The rig's time: seconds from any origin, and a wait in them. The wall clock on a real rig; a
    simulated world's own (faster, and still while it renders) on a simulated one."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One raw frame as the sensor counted it, and what the camera says about it."""

    pixels: np.ndarray  # (H, W, C) unsigned integers: the sensor's digital numbers, before any calibration
    bits: int  # bit depth of the values (8, 10, 12, 16)
    exposure_s: float
    gain_db: float
    captured_at: float  # Unix time when the frame arrived
    meta: dict = field(default_factory=dict)  # device-specific (the simulator: where its axes were)


@runtime_checkable
class Camera(Protocol):
    """Manual exposure and gain, one raw frame at a time."""

    def set_exposure(self, seconds: float) -> None: ...

    def set_gain(self, gain_db: float) -> None: ...

    def capture(self) -> RawFrame: ...

    def close(self) -> None: ...
