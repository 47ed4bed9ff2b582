"""What the acquisition runner needs from devices: small structural Protocols, satisfied by real and
simulated devices alike (no inheritance needed)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Positioner(Protocol):
    """Axes that move to a goal (device units), report where they are, and can be stopped."""

    def move_to(self, goal: tuple[int, ...]) -> None:
        """Start moving every axis to ``goal`` (one value per axis, device units: stage steps, servo
        ticks) and return without waiting. A goal outside the configured limits raises
        :class:`~drivers.errors.LimitError` before anything is sent."""
        ...

    def wait_settled(self, timeout_s: float) -> tuple[int, ...]:
        """Wait until every axis is at its goal and still; return where they are (device units). Not
        there within ``timeout_s`` seconds: :class:`~drivers.errors.SettleTimeout` (the axes are not
        stopped by it: the caller decides); a device that faults while moving:
        :class:`~drivers.errors.HardwareAlarm`."""
        ...

    def position(self) -> tuple[int, ...]:
        """Where the axes are now, device units. A device that does not answer within its reply timeout
        (and its retries): :class:`~drivers.errors.DeviceTimeout`."""
        ...

    def stop(self) -> None:
        """Stop every axis where it is (decelerating as the device does)."""
        ...


@runtime_checkable
class Switch(Protocol):
    """Something on or off (the lamp)."""

    def set(self, on: bool) -> None:
        """Switch on or off, and return once the device has acknowledged it."""
        ...

    def get(self) -> bool:
        """Whether it is on, as the device reports it."""
        ...


@runtime_checkable
class Thermometer(Protocol):
    """A device that reports its temperatures (°C by part name), for the frames' sidecars."""

    def temperatures(self) -> dict[str, float]:
        """°C by part name (e.g. ``{"servo 1": 38.0}``)."""
        ...


@runtime_checkable
class StreamCounters(Protocol):
    """A camera whose transport counts its packets (GigE Vision and USB3 Vision through Aravis): what a
    run journals of its link, beside the frames (docs/sessions.md, "The journal")."""

    def statistics(self) -> dict[str, int]:
        """The stream's counters since the camera was opened, by Aravis's names (``n_received_packets``,
        ``n_resent_packets``, ``n_missing_packets``, …); {} before it streams."""
        ...


@runtime_checkable
class Clock(Protocol):
    """The rig's time: seconds from any origin, and a wait in them. The wall clock on a real rig; a
    simulated world's own (faster, and still while it renders) on a simulated one."""

    def now(self) -> float:
        """The rig's time, seconds."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of the rig's time."""
        ...


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

    def set_exposure(self, seconds: float) -> None:
        """Set the exposure of the next frames, seconds (the camera may round it: each frame's
        :attr:`RawFrame.exposure_s` says what it used)."""
        ...

    def set_gain(self, gain_db: float) -> None:
        """Set the analogue gain of the next frames, dB."""
        ...

    def capture(self) -> RawFrame:
        """Take one frame at the current settings and return it once it has arrived. No frame within the
        exposure plus the camera's timeout: :class:`~drivers.errors.DeviceTimeout`; a frame cut short or
        corrupted on the link: :class:`~drivers.errors.ChecksumError` (both worth a retry)."""
        ...

    def close(self) -> None:
        """Release the camera (idempotent)."""
        ...
