"""The simulated world's clock: what its lamp drifts by, and what a run waiting on the lamp must read.

World time is wall time × the speed factor, less the wall time the simulator spends rendering: a real
camera takes its exposure and a few milliseconds of readout, not a render's second, so a frame must not
age the lamp by a speed-factor multiple of the host's rendering speed (that made a warm-up end at a
different point of the lamp's curve on a slower machine). The motors keep their own wall-time clocks;
nothing moves while a frame is rendered.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator


class WorldClock:
    """Simulated seconds since the world started (``now``); ``sleep`` waits simulated seconds;
    ``paused()`` holds the clock still for the block's wall time (rendering)."""

    def __init__(self, speed_factor: float = 1.0):
        self.speed_factor = speed_factor
        self._started = time.monotonic()
        self._paused_s = 0.0  # wall seconds held still so far
        self._pause_began: float | None = None
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            wall = self._pause_began if self._pause_began is not None else time.monotonic()
            return (wall - self._started - self._paused_s) * self.speed_factor

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds / self.speed_factor)

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        with self._lock:
            self._pause_began = time.monotonic()
        try:
            yield
        finally:
            with self._lock:
                self._paused_s += time.monotonic() - self._pause_began
                self._pause_began = None
