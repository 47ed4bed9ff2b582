"""What the acquisition runner needs from devices: small structural Protocols, satisfied by real and
simulated devices alike (no inheritance needed)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable


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
