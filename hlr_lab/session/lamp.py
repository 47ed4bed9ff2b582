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

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.protocols import Clock
from hlr_lab.rig.file import Rig
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

# A rig whose radiometric calibration saw its lamp this far below warm at its warm-up's first reading
# (LampFigures.when_lit) has runs warm it up and watch it unless told otherwise: an unwatched cold lamp is
# per cents off the sensitivity × power the calibration measured warm, and moves between a run's poses
WARM_UP_WORTH = 0.005
# … or saw the warm lamp move by this much over its white frames (lamp_drift_over_white_frames): watched
DRIFT_WORTH = 0.002
CALIBRATED_WARM_UP_S = 30 * 60.0  # the warm-up's most, where the calibration's record asks for one
CALIBRATED_EVERY = 5  # poses between reference frames, where it asks for a watch


# the warm-up's exponential's time constant, searched from a quarter of a step to this many times the
# readings' span: a longer one cannot be told from a straight line through them, and extrapolates a
# flickering line's slope without end (measured: six readings of a 0.5 % rise with 0.1 % flicker, searched
# to 100 steps, gave 19-22 % short of warm for a truth of ~0.5 %)
LONGEST_TIME_CONSTANT = 2.0


def short_of_warm(levels: np.ndarray) -> float:
    """How far below its warm output a lamp still was at the last of ``levels`` (K,), readings of its
    output one warm-up step apart, as a fraction of that last reading: the exponential approach
    A − B·exp(−k/τ) fitted by least squares (τ searched from 0.25 steps to :data:`LONGEST_TIME_CONSTANT`
    × the K − 1 steps the readings span, A and B linear), A over the last reading − 1; 0 for a lamp not
    warming (B ≤ 0) or fewer than four readings. With 0.1 % flicker and six to eight readings it comes
    within about a factor of two of the truth, and a straight rise gives at most about twice its own
    size (tests/test_lamp_watch.py)."""
    levels = np.asarray(levels, np.float64)
    if len(levels) < TREND_READINGS:
        return 0.0
    k = np.arange(len(levels))
    best = (np.inf, 0.0, 0.0)
    for tau in np.geomspace(0.25, LONGEST_TIME_CONSTANT * (len(levels) - 1), 200):
        design = np.column_stack([np.ones(len(k)), -np.exp(-k / tau)])
        (a, b), *_ = np.linalg.lstsq(design, levels, rcond=None)
        misfit = float(np.sum((design @ (a, b) - levels) ** 2))
        if misfit < best[0]:
            best = (misfit, float(a), float(b))
    _, warm, rise = best
    return max(warm / levels[-1] - 1.0, 0.0) if rise > 0 else 0.0


@dataclass(frozen=True)
class LampFigures:
    """What the rig's radiometric calibration saw of its lamp, as fractions (0 for what it did not record):
    its change while warming up (``lamp_warm_up_change``), how far short of warm it still was then
    (``lamp_short_of_warm``: :func:`short_of_warm`), and the warm lamp's move over the white frames
    (``lamp_drift_over_white_frames``)."""

    warm_up_change: float = 0.0
    short_of_warm: float = 0.0
    drift: float = 0.0

    @property
    def when_lit(self) -> float:
        """How far below warm the lamp was at the warm-up's first reading, a fraction: its change over the
        warm-up and what it still lacked then. Not the change alone: how much of the warm-up the first
        reading saw depends on how long the lamp was on before it (measured: 1.0 % on a quiet machine,
        0.5 % on a loaded one, the same simulated lamp)."""
        return (1 + self.warm_up_change) * (1 + self.short_of_warm) - 1

    @classmethod
    def of(cls, rig: Rig) -> LampFigures:
        record = rig.file.calibration.radiometric
        extra = {} if record is None else (record.model_extra or {})

        def figure(key: str) -> float:
            value = extra.get(key)
            return float(value) if isinstance(value, int | float) and math.isfinite(value) else 0.0

        return cls(figure("lamp_warm_up_change"), figure("lamp_short_of_warm"),
                   figure("lamp_drift_over_white_frames"))  # fmt: skip


def lamp_watch_for(
    rig: Rig,
    *,
    every: int | None = None,
    warm_up_s: float | None = None,
    stable_per_min: float = LampWatch.stable_per_min,
) -> tuple[LampWatch, str | None]:
    """How a run on ``rig`` watches its lamp: ``every`` and ``warm_up_s`` as given; each one not given
    (None) as the rig's radiometric calibration says of its lamp — a warm-up of at most
    :data:`CALIBRATED_WARM_UP_S` where it saw the lamp :data:`WARM_UP_WORTH` or more below warm when
    first lit (:attr:`LampFigures.when_lit`), and a reference frame every :data:`CALIBRATED_EVERY` poses
    where it saw that or the warm lamp move by :data:`DRIFT_WORTH` over its white frames (not where a
    white reference lies beside the object: that measures the lamp in every pose) — else none. Returns
    the watch and, when the record chose any of it, why, in a sentence (None otherwise)."""
    seen = LampFigures.of(rig)
    warms = seen.when_lit >= WARM_UP_WORTH
    drifts = warms or abs(seen.drift) >= DRIFT_WORTH
    reference = rig.file.calibration.white_reference
    beside = reference is not None and reference.run_place_m is not None
    chosen = []
    if warm_up_s is None:
        warm_up_s = CALIBRATED_WARM_UP_S if warms else 0.0
        if warms:
            chosen.append(f"warmed up (at most {CALIBRATED_WARM_UP_S / 60:.0f} min)")
    if every is None:
        every = CALIBRATED_EVERY if drifts and not beside else 0
        if every:
            chosen.append(f"watched every {every} poses")
    watch = LampWatch(every=every, warm_up_s=warm_up_s, stable_per_min=stable_per_min,
                      black_level_dn=rig.file.sensor.black_level_dn)  # fmt: skip
    if not chosen:
        return watch, None
    what = (f"{100 * seen.when_lit:.1f} % below warm when first lit" if warms
            else f"moved by {100 * seen.drift:+.2f} % over its white frames")  # fmt: skip
    return watch, (
        f"the lamp is {' and '.join(chosen)}: its radiometric calibration saw it {what} "
        "(--warm-up 0 --lamp-every 0: neither)"
    )


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
