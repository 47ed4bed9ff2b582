"""The simulated world's clock: what its lamp drifts by, and what a run waiting on the lamp must read.

World time is wall time × the speed factor, less the wall time the simulator spends rendering: a real
camera takes its exposure and a few milliseconds of readout, not a render's second, so a frame must not
age the lamp by a speed-factor multiple of the host's rendering speed (that made a warm-up end at a
different point of the lamp's curve on a slower machine). The motors keep their own wall-time clocks;
nothing moves while a frame is rendered.

A wait on this clock (``sleep``: a warm-up's minute between two readings of the lamp, the only wait hlr-lab
takes on the world's own clock) passes at once: world time jumps by it. Nothing else in the world moves
while hlr-lab waits on the lamp, and the lamp's output is a function of world time, so the readings are
those of a real-time wait, without the wall time (a 30-minute warm-up at ×40 was 45 s of sleeping).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator


class WorldClock:
    """Simulated seconds since the world started (``now``); ``sleep`` moves it on by simulated seconds at
    once; ``paused()`` holds the clock still for the block's wall time (rendering)."""

    def __init__(self, speed_factor: float = 1.0):
        self.speed_factor = speed_factor
        self._started = time.monotonic()
        self._paused_s = 0.0  # wall seconds held still so far
        self._slept_s = 0.0  # world seconds jumped by waits
        self._pause_began: float | None = None
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            wall = self._pause_began if self._pause_began is not None else time.monotonic()
            return (wall - self._started - self._paused_s) * self.speed_factor + self._slept_s

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self._slept_s += max(0.0, seconds)

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
