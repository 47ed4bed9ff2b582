"""An exposure bracket → linear radiance, never using a clipped value or one drowned in dark noise.

With a linear sensor, DN = k·t·R + black + noise (k: sensitivity × analogue gain, t: exposure). For
each pixel the radiance is the maximum-likelihood estimate under photon noise over the frames where the
pixel is usable: R = Σ(DN − black − dark) / Σ(k·t), per channel. A frame is unusable at a pixel where
any channel clipped (the true value is unknown). Of the others, the longest is always used; a shorter
channel value only where the longest predicts it above ``noise_floor`` read-noise σ (below, it is
mostly noise, and biased where the sensor clips at zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NOISE_FLOOR = 5.0  # read-noise σ below which a value is dark-noise dominated
CLIP_MARGIN_DN = 1  # codes within this of the top count as clipped (an ADC's top codes are unreliable)


@dataclass(frozen=True, eq=False)
class BracketFrame:
    pixels: np.ndarray  # (H, W, 3) or (H, W, 1) raw DN, unsigned integers
    exposure_s: float
    gain_db: float
    bits: int
    dark: np.ndarray | None = None  # the same exposure with the lamp off (ambient), or None


@dataclass(frozen=True, eq=False)
class Radiance:
    value: np.ndarray  # (H, W, C) float32, linear radiance (NaN where no frame was usable)
    usable: np.ndarray  # (H, W) bool: some frame was usable
    frames_used: np.ndarray  # (H, W) uint8: how many frames went into the value


def merge_bracket(
    frames: list[BracketFrame],
    *,
    sensitivity: float,
    black_level_dn: float = 0.0,
    read_noise_dn: float = 1.5,
    noise_floor: float = NOISE_FLOOR,
) -> Radiance:
    """Merge one pose's bracket; ``sensitivity`` in DN per (radiance · s) at 0 dB."""
    by_length = sorted(frames, key=lambda f: f.exposure_s * 10 ** (f.gain_db / 20))  # shortest first
    shape = by_length[0].pixels.shape
    for f in by_length:
        if f.pixels.shape != shape:
            raise ValueError(f"frames of one bracket differ in size: {f.pixels.shape} and {shape}")
    kts = [sensitivity * 10 ** (f.gain_db / 20) * f.exposure_s for f in by_length]
    signals = [_signal(f, black_level_dn) for f in by_length]
    clipped = [
        (f.pixels >= (1 << f.bits) - 1 - CLIP_MARGIN_DN).any(axis=-1, keepdims=True) for f in by_length
    ]
    # the longest unclipped frame is always used; a shorter one only where the longest predicts it above
    # the noise floor. Deciding from another frame's value, never from the value itself: thresholding a
    # noisy value on its own noise would bias the mean (upwards near the floor)
    rough = np.full(shape, np.nan)
    longest = np.full((*shape[:2], 1), -1)
    for i in range(len(by_length)):
        fresh = ~clipped[i]
        rough = np.where(fresh, signals[i] / kts[i], rough)  # ends with the longest unclipped frame's value
        longest = np.where(fresh, i, longest)
    total_dn = np.zeros(shape, np.float64)
    total_kt = np.zeros(shape, np.float64)
    used = np.zeros(shape[:2], np.uint8)
    for i, (signal, kt, clip) in enumerate(zip(signals, kts, clipped, strict=True)):
        with np.errstate(invalid="ignore"):
            take = ~clip & ((longest == i) | (rough * kt >= noise_floor * read_noise_dn))
        total_dn += np.where(take, signal, 0.0)
        total_kt += np.where(take, kt, 0.0)
        used += take.any(axis=-1)
    usable = (total_kt > 0).all(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = (total_dn / total_kt).astype(np.float32)
    value[~usable] = np.nan
    return Radiance(value, usable, used)


def _signal(f: BracketFrame, black_level_dn: float) -> np.ndarray:
    signal = f.pixels.astype(np.float64) - black_level_dn
    if f.dark is not None:
        signal -= f.dark.astype(np.float64) - black_level_dn
    return signal
