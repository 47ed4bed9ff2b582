"""Watching the lamp through a run: a reference pose photographed again and again, its brightness against
the first time (docs/sessions.md, "The lamp").

A lamp warms up, ages and flickers: over a night its output moves by per cents, and every reflectance
fitted under it with it. The run therefore returns to one pose — the plan's first, the same turntable
angle, lamp position and exposure each time — before the first pose, every ``every`` poses and at the
end. Each reference frame is kept (journal ``lamp_reference``) and compared with the first of the session
over the pixels that were well exposed in that first one: the ratio of their summed signals is the
lamp's output relative to the start (journal ``lamp``: time, output). ``fit`` divides each pose's light
by the output interpolated at the pose's time. A warm-up wait (``warm_up_s``) photographs the reference
until the output changes by less than ``stable_per_min`` per minute.

Time is the rig's (a :class:`drivers.protocols.Clock`): the wall clock on a real rig; on a simulated
one the world's own, where minutes of lamp drift pass in seconds, and so must the warm-up's minutes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.protocols import Clock
from hlr_lab.session.events import WarmUpLine

WELL_EXPOSED = (0.1, 0.8)  # of full scale, in the first reference frame: the values compared
WHITE_REFERENCE = (
    "white reference"  # the baseline of lamp lines measured on it (hlr_lab.acquisition.white_reference)
)
TREND_READINGS = 4  # a warm-up judges the lamp's trend over this many readings


class WallClock:
    """The rig's clock on a real rig: real time."""

    def now(self) -> float:
        """Seconds (any origin)."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


WALL_CLOCK = WallClock()


@dataclass(frozen=True)
class LampWatch:
    """How the run watches its lamp: a reference frame every ``every`` poses (0: never), and a warm-up of
    at most ``warm_up_s`` (rig seconds; 0: none) until the output is stable within ``stable_per_min``
    per minute, read every ``warm_up_step_s`` (:func:`warm_up`)."""

    every: int = 0
    warm_up_s: float = 0.0
    stable_per_min: float = 0.002
    warm_up_step_s: float = 60.0
    black_level_dn: float = 0.0  # the sensor's (the rig file's [sensor])

    @property
    def active(self) -> bool:
        return self.every > 0 or self.warm_up_s > 0


UNWATCHED = LampWatch()  # no warm-up, no reference frames


def compared_pixels(first: np.ndarray, bits: int, black_level_dn: float) -> np.ndarray:
    """(H, W[, C]) bool, as ``first``: the values of the first reference frame that lie well inside the
    sensor's range (:data:`WELL_EXPOSED`): neither noise nor near clipping. Per channel: a saturated
    colour's weak channel is left out, its strong one kept."""
    top = (1 << bits) - 1
    lo, hi = (black_level_dn + f * (top - black_level_dn) for f in WELL_EXPOSED)
    return (first >= lo) & (first <= hi)


def relative_output(
    frame: np.ndarray, first: np.ndarray, compared: np.ndarray, black_level_dn: float
) -> float:
    """The lamp's output when ``frame`` was taken relative to when ``first`` was (same pose and
    exposure): the ratio of their summed signals over ``compared`` (:func:`compared_pixels`)."""
    if not compared.any():
        raise ValueError("no well-exposed value in the first reference frame")
    now = np.asarray(frame, np.float64)[compared] - black_level_dn
    then = np.asarray(first, np.float64)[compared] - black_level_dn
    return float(now.sum() / then.sum())


def lamp_at(times: np.ndarray, outputs: np.ndarray, t: float) -> float:
    """The lamp's relative output at Unix time ``t``, linear between the reference frames (the first's or
    the last's outside them); 1 when the run measured none."""
    if len(times) == 0:
        return 1.0
    return float(np.interp(t, times, outputs))


@dataclass(frozen=True)
class WarmUp:
    """How a warm-up ended: ``stable`` (or out of time) after ``minutes`` of rig time, the output then
    changing by ``per_minute`` (a fraction) per minute."""

    stable: bool
    minutes: float
    per_minute: float

    def as_event(self) -> WarmUpLine:
        """The journal's ``warm_up`` line."""
        return WarmUpLine(event="warm_up", at=time.time(), stable=self.stable, minutes=self.minutes,
                          per_minute=self.per_minute)  # fmt: skip


def warm_up(
    brightness: Callable[[], float], watch: LampWatch, clock: Clock, progress: Callable[[str], None]
) -> WarmUp:
    """Measure ``brightness()`` (anything proportional to the lamp's output: the lamp kept on) every
    ``watch.warm_up_step_s`` of the rig's ``clock`` until its trend over the last :data:`TREND_READINGS` readings
    (a least-squares slope, relative to their mean) is within ``watch.stable_per_min`` per minute, or
    ``watch.warm_up_s`` have passed. A trend, not two readings: a lamp's flicker between two frames a
    minute apart looks like a slope of its size per minute."""
    started = clock.now()
    readings = [(0.0, brightness())]
    while True:
        progress(f"warming the lamp up ({readings[-1][0] / 60:.1f} min)")
        clock.sleep(watch.warm_up_step_s)
        readings.append(((clock.now() - started), brightness()))
        if len(readings) < TREND_READINGS:
            continue
        t, level = (np.array(v) for v in zip(*readings[-TREND_READINGS:], strict=True))
        per_minute = abs(np.polyfit(t / 60, level / level.mean(), 1)[0])
        stable = per_minute <= watch.stable_per_min
        if stable or t[-1] >= watch.warm_up_s:
            return WarmUp(bool(stable), float(t[-1] / 60), float(per_minute))
