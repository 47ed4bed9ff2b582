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
    by_length = sorted(frames, key=lambda f: f.exposure_s * 10 ** (f.gain_db / 20))  # shortest first
    shape = by_length[0].pixels.shape
    for f in by_length:
        if f.pixels.shape != shape:
            raise ValueError(f"frames of one bracket differ in size: {f.pixels.shape} and {shape}")
    where = np.ones(shape[:2], bool) if within is None else within
    kts = [sensitivity * 10 ** (f.gain_db / 20) * f.exposure_s for f in by_length]
    signals = [_signal(f, black_level_dn, where) for f in by_length]  # (N, C) float32 each
    clips = [clipped(f.pixels[where], f.bits, channels=f.pixels.ndim == 3) for f in by_length]  # (N,) each
    # the longest unclipped frame is always used; a shorter one only where the longest predicts it above
    # the noise floor. Deciding from another frame's value, never from the value itself: thresholding a
    # noisy value on its own noise would bias the mean (upwards near the floor)
    longest = np.full(len(clips[0]), -1)
    for i, clip in enumerate(clips):
        longest[~clip] = i
    rough = np.full(signals[0].shape, np.nan, np.float32)  # radiance from the longest unclipped frame
    for i, (signal, kt) in enumerate(zip(signals, kts, strict=True)):
        rough[longest == i] = signal[longest == i] / kt
    total_dn = np.zeros(signals[0].shape, np.float32)
    total_kt = np.zeros(signals[0].shape, np.float32)
    used = np.zeros(len(longest), np.uint8)
    for i, (signal, kt, clip) in enumerate(zip(signals, kts, clips, strict=True)):
        with np.errstate(invalid="ignore"):
            take = ~clip[:, None] & ((longest == i)[:, None] | (rough * kt >= noise_floor * read_noise_dn))
        total_dn += signal * take
        total_kt += kt * take
        used += take.any(axis=-1)
    ok = np.all(total_kt > 0, axis=-1)
    value = np.full(shape, np.nan, np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        value[where] = np.where(ok[:, None], total_dn / total_kt, np.nan)
    usable = np.zeros(shape[:2], bool)
    usable[where] = ok
    frames_used = np.zeros(shape[:2], np.uint8)
    frames_used[where] = used
    return Radiance(value, usable, frames_used)


def _signal(f: BracketFrame, black_level_dn: float, where: np.ndarray) -> np.ndarray:
    signal = f.pixels[where].astype(np.float32) - np.float32(black_level_dn)
    if f.dark is not None:
        signal -= f.dark[where].astype(np.float32) - np.float32(black_level_dn)
    return signal
