"""An exposure bracket → linear radiance, never using a clipped value or one drowned in dark noise.

With a linear sensor, DN = k·t·R + black + noise (k: sensitivity × analogue gain, t: exposure). For
each pixel the radiance is the maximum-likelihood estimate under photon noise over the frames where the
pixel is usable: R = Σ(DN − black − dark) / Σ(k·t), per channel. A frame is unusable at a pixel where
any channel clipped (the true value is unknown). Of the others, the longest is always used; a shorter
channel value only where the longest predicts it above ``noise_floor`` read-noise σ (below, it is
mostly noise, and biased where the sensor clips at zero).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from hlr_lab.geometry.clipping import clipped

NOISE_FLOOR = 5.0  # read-noise σ below which a value is dark-noise dominated


@dataclass(frozen=True, eq=False)
class BracketFrame:
    """One frame of a pose's exposure bracket, with its dark frame when one was taken."""

    pixels: np.ndarray  # (H, W, 3) or (H, W, 1) raw DN, unsigned integers
    exposure_s: float
    gain_db: float
    bits: int
    dark: np.ndarray | None = None  # the same exposure with the lamp off (ambient), or None


@dataclass(frozen=True, eq=False)
class Radiance:
    """A bracket merged into linear radiance, with where it is usable and from how many frames."""

    value: np.ndarray  # (H, W, C) float32, linear radiance (NaN where no frame was usable)
    usable: np.ndarray  # (H, W) bool: some frame was usable
    frames_used: np.ndarray  # (H, W) uint8: how many frames went into the value
    agreement: tuple[PairAgreement, ...] = ()  # the bracket's frames compared (when the caller asked)
    # (H, W, C) float32: how the value moves per DN of black level believed higher (−frames / Σ k·t of the
    # frames without a dark frame subtracted; 0 where darks were: the black level cancels there)
    black_slope: np.ndarray | None = None


def merge_bracket(
    frames: list[BracketFrame],
    *,
    sensitivity: float,
    black_level_dn: float = 0.0,
    read_noise_dn: float = 1.5,
    noise_floor: float = NOISE_FLOOR,
    within: np.ndarray | None = None,
) -> Radiance:
    """Merge one pose's bracket; ``sensitivity`` in DN per (radiance · s) at 0 dB. ``within`` (H, W) bool
    limits the work to those pixels (the object's window): elsewhere the result is unusable."""
    by_length = sorted(frames, key=_kt)  # shortest first
    shape = by_length[0].pixels.shape
    for f in by_length:
        if f.pixels.shape != shape:
            raise ValueError(f"frames of one bracket differ in size: {f.pixels.shape} and {shape}")
    where = np.ones(shape[:2], bool) if within is None else within
    kts = [sensitivity * 10 ** (f.gain_db / 20) * f.exposure_s for f in by_length]
    signals = [_signal(f, black_level_dn, where) for f in by_length]  # (N, C) float32 each
    clips = [clipped(f.pixels[where], f.bits, channels=f.pixels.ndim == 3) for f in by_length]  # (N,) each
    # the longest unclipped frame is always used; a shorter one only where the pixel's neighbours, in their
    # longest unclipped frames, predict it above the noise floor. Never from the pixel's own values:
    # thresholding a noisy value on its own noise biases the mean (upwards near the floor), and so does
    # deciding from a frame that is then averaged in (it is given less weight where its noise is up:
    # measured 0.1 DN low, 0.3 % of a 30 DN value, where the longest frame decided)
    longest = np.full(len(clips[0]), -1)
    for i, clip in enumerate(clips):
        longest[~clip] = i
    rough = np.full(signals[0].shape, np.nan, np.float32)  # radiance from the longest unclipped frame
    for i, (signal, kt) in enumerate(zip(signals, kts, strict=True)):
        rough[longest == i] = signal[longest == i] / kt
    predicted = neighbour_mean(rough, where)
    predicted = np.where(np.isfinite(predicted), predicted, rough)  # a pixel without usable neighbours
    total_dn = np.zeros(signals[0].shape, np.float32)
    total_kt = np.zeros(signals[0].shape, np.float32)
    black_frames = np.zeros(signals[0].shape, np.float32)
    used = np.zeros(len(longest), np.uint8)
    for i, (signal, kt, clip) in enumerate(zip(signals, kts, clips, strict=True)):
        with np.errstate(invalid="ignore"):
            take = ~clip[:, None] & (
                (longest == i)[:, None] | (predicted * kt >= noise_floor * read_noise_dn)
            )
        total_dn += signal * take
        total_kt += kt * take
        if by_length[i].dark is None:
            black_frames += take
        used += take.any(axis=-1)
    ok = np.all(total_kt > 0, axis=-1)
    value = np.full(shape, np.nan, np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        value[where] = np.where(ok[:, None], total_dn / total_kt, np.nan)
    usable = np.zeros(shape[:2], bool)
    usable[where] = ok
    frames_used = np.zeros(shape[:2], np.uint8)
    frames_used[where] = used
    slope = np.zeros(shape, np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope[where] = np.where(ok[:, None], -black_frames / total_kt, 0.0)
    return Radiance(value, usable, frames_used, black_slope=slope)


def neighbour_mean(values: np.ndarray, where: np.ndarray) -> np.ndarray:
    """(N, C) values at the pixels of ``where`` (H, W) bool, in its row-major order → (N, C): at each pixel
    the mean of the finite values of its 8 neighbours (NaN where none has one). Pixel noise being
    independent, this predicts a pixel's value without its own noise."""
    ys, xs = np.nonzero(where)
    if len(ys) == 0:
        return values.copy()
    y, x = ys - ys.min() + 1, xs - xs.min() + 1  # a margin of one pixel all round
    shape = (int(y.max()) + 2, int(x.max()) + 2, values.shape[1])
    finite = np.isfinite(values)
    total, count = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    total[y, x] = np.where(finite, values, 0)
    count[y, x] = finite
    ring = np.ones((3, 3), np.float32)
    ring[1, 1] = 0  # the neighbours only
    # filter2D keeps up to 4 channels as they are, but returns one channel as (H, W): reshape
    s, n = (
        cv2.filter2D(a, -1, ring, borderType=cv2.BORDER_CONSTANT).reshape(shape)[y, x] for a in (total, count)
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / n, np.nan).astype(np.float32)


def _signal(f: BracketFrame, black_level_dn: float, where: np.ndarray) -> np.ndarray:
    signal = f.pixels[where].astype(np.float32) - np.float32(black_level_dn)
    if f.dark is not None:
        signal -= f.dark[where].astype(np.float32) - np.float32(black_level_dn)
    return signal


AGREEMENT_SIGNAL = 20.0  # read-noise σ: a value this far above the noise is within 5 % of its true radiance
AGREEMENT_PIXELS = 100  # fewer values than this tell nothing about a pair of frames


@dataclass(frozen=True)
class PairAgreement:
    """Two frames of one bracket (indices into it) compared: ``ratio``, the longer's radiance over the
    shorter's once the black level is allowed for (1 when the recorded exposures and gains are the ones
    taken); ``black_offset_dn``, how far the sensor's true black level lies above the one assumed (DN), as
    the bracket tells it."""

    longer: int
    shorter: int
    ratio: float
    black_offset_dn: float


def exposure_agreement(
    frames: list[BracketFrame],
    *,
    black_level_dn: float = 0.0,
    read_noise_dn: float = 1.5,
    within: np.ndarray | None = None,
) -> list[PairAgreement]:
    """Each frame of a bracket against the next shorter one (by recorded exposure × gain), over their
    common pixels: unclipped in both, where the longer predicts the shorter ``AGREEMENT_SIGNAL`` read-noise
    σ above black. With a linear sensor the shorter's signal (DN above the assumed black) is x = y/q +
    e·(1 − 1/q) in the longer's y, q the ratio of their exposures × gains and e the black level's error:
    the line through the pair spanning the widest range of values gives e from its intercept, and each
    pair's ratio is Σ(y − e) / (q · Σ(x − e)), which noise does not bias (a regression's slope would be
    flattened by it where the values span only a few times the noise). Two exposures a factor 4 apart
    swapped show as 4 and 1/16 against their neighbours. Pairs with fewer than ``AGREEMENT_PIXELS`` values
    are left out; an empty list when no pair can be told."""
    where = np.ones(frames[0].pixels.shape[:2], bool) if within is None else within
    order = sorted(range(len(frames)), key=lambda i: _kt(frames[i]))  # shortest first
    pairs = []  # (longer, shorter, q, x, y, spread of y, black-level error)
    for shorter, longer in itertools.pairwise(order):
        a, b = frames[shorter], frames[longer]
        q = _kt(b) / _kt(a)
        sa, sb = _signal(a, black_level_dn, where), _signal(b, black_level_dn, where)  # (N, C)
        both = ~clipped(a.pixels[where], a.bits, channels=a.pixels.ndim == 3)
        both &= ~clipped(b.pixels[where], b.bits, channels=b.pixels.ndim == 3)
        # chosen by what the longer frame predicts for the shorter, not by the shorter's own value: choosing
        # by a value keeps those that noise pushed up, and the shorter's relative noise is the larger
        strong = both[:, None] & (sb >= q * AGREEMENT_SIGNAL * read_noise_dn)  # (N, C)
        if strong.sum() < AGREEMENT_PIXELS or abs(q - 1) < 1e-6:
            continue
        x, y = sa[strong].astype(np.float64), sb[strong].astype(np.float64)
        # the shorter's signal regressed on the longer's: chosen by the longer, which does not bias this
        # regression; the longer's noise flattens it (errors in the regressor), less the wider its span
        spread = float(np.var(y))
        slope = float(np.mean((y - y.mean()) * (x - x.mean()))) / spread if spread > 0 else np.nan
        intercept = x.mean() - slope * y.mean()
        pairs.append((longer, shorter, q, x, y, spread, intercept * q / (q - 1)))
    if not pairs:
        return []
    widest = max(pairs, key=lambda p: p[5])  # the pair spanning the widest range tells the black level
    offset = float(widest[6]) if widest[5] > 0 else 0.0  # (every value alike: no line, no black level)
    # each pair's ratio from its sums once that black is allowed for: a sum is not biased by noise
    return [
        PairAgreement(longer, shorter, _ratio((y - offset).sum() / q, (x - offset).sum()), float(offset))
        for longer, shorter, q, x, y, _, _ in pairs
    ]


def _ratio(a: float, b: float) -> float:
    """a / b, or 0 where b is not above 0 (frames that cannot be compared: they disagree)."""
    return float(a / b) if b > 0 else 0.0


def _kt(f: BracketFrame) -> float:
    """The frame's exposure × analogue gain (the sensitivity is common to the bracket)."""
    return f.exposure_s * 10 ** (f.gain_db / 20)
