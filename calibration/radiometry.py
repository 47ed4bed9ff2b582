"""The camera's radiometry and the lamp's power from dark frames and a white reference
(docs/calibration.md, "calibrate radiometric").

The model hlr-lab fits with (``[sensor]``, ``[light]``): a pixel reads

    DN = S · g · t · L + black + noise,   L = R · Φ · cos θ / d²   (a Lambertian surface under a point lamp)

with S the sensitivity (DN per radiance unit and second at 0 dB), g the analogue gain, t the exposure, R
the reflectance, Φ the lamp's power, θ the angle of incidence and d the lamp's distance. Only S · Φ is
measurable (and only it matters: it makes the fitted R absolute). Noise: read noise σ_r (DN) and photon
noise of variance K · (DN − black), K the conversion gain in DN per electron.

* **Dark frames** (lamp off, pairs at each exposure): the black level is their mean per channel; the
  read noise is the spread of a pair's difference over √2 (fixed pattern cancels). A camera whose black
  level sits at 0 DN clips half its dark noise there: the mean then lies above the black level (0.59 DN
  at σ_r 1.5) and the spread below the read noise (by 40 %). Where more than ``CLIPPED_DARK`` of the
  dark pixels read 0, both come from a censored fit instead: the integer values' histogram under a
  normal of mean ``black`` and spread σ_r, rounded, everything below ½ DN read as 0 (maximum
  likelihood).
* **Photon transfer** (the white reference at several exposures, in pairs): the variance of a pair's
  difference over 2, less σ_r², against the mean signal: the slope is K. The means against the exposures
  (each divided by a reference frame taken just before it, so a lamp that drifts does not look like a
  non-linear camera) give the worst deviation from linear.
* **White reference** at several lamp positions: every pixel of its middle gives S · Φ = (DN − black) ·
  d² / (g · t · R · cos θ); over the lamp positions, their spread is how well the lamp follows 1/d².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.charuco import CalibrationError

LINEAR_WITHIN = 0.02  # a response further than this from linear is refused
CLIPPED_DARK = 0.001  # dark frames with more than this share of pixels at 0 DN are clipped there
INVERSE_SQUARE_WITHIN = 0.02  # a lamp whose S·Φ spreads more than this over the positions is flagged


def _channels(frame: np.ndarray) -> np.ndarray:
    """(H, W[, C]) → (H, W, C) float64."""
    f = np.asarray(frame, np.float64)
    return f[..., None] if f.ndim == 2 else f


@dataclass(frozen=True)
class Dark:
    """Dark statistics: black level per channel (C,) and read noise, in DN."""

    black_level_dn: np.ndarray  # (C,) per channel
    read_noise_dn: float
    # the rig file's one black level (the channels' mean): its standard error, with each channel's offset
    # from it (the fit takes that one number for every channel)
    black_level_se_dn: float = 0.0


def dark_statistics(pairs: list[tuple[np.ndarray, np.ndarray]]) -> Dark:
    """Black level per channel and read noise from pairs of dark frames (H, W[, C]), each pair at one
    exposure."""
    if not pairs:
        raise CalibrationError("no dark frames: take them with the lamp off")
    frames = np.array([_channels(f).mean(axis=(0, 1)) for pair in pairs for f in pair])  # (F, C)
    means = frames.mean(axis=0)
    spreads = [np.std(_channels(a) - _channels(b)) / np.sqrt(2) for a, b in pairs]
    read_noise = float(np.sqrt(np.mean(np.square(spreads))))
    counts = _histograms([f for pair in pairs for f in pair])  # (C, K) dark values per channel
    if np.mean(counts[:, 0] / counts.sum(axis=1)) > CLIPPED_DARK:  # clipped at 0: see the docstring
        fits = [censored_dark(c) for c in counts]
        censored = np.array([b for b, _ in fits])
        frames = frames - means + censored  # each frame's wander kept, about the censored level
        means, read_noise = censored, float(np.sqrt(np.mean([s**2 for _, s in fits])))
    # the frames' means wander (a black level that drifts with time or exposure) beyond what the read noise
    # over all their pixels gives: the larger of the two is the mean's standard error
    pixels = frames.shape[0] * np.prod(np.shape(pairs[0][0])[:2])
    wander = np.std(frames, axis=0, ddof=1) / np.sqrt(len(frames))
    se = np.maximum(wander, read_noise / np.sqrt(pixels))
    offset = means - means.mean()
    return Dark(means, read_noise, float(np.sqrt(np.mean(se**2) + np.mean(offset**2))))


def censored_dark(counts: np.ndarray) -> tuple[float, float]:
    """Black level and read noise (DN) from the histogram ``counts`` (K,) of integer dark values 0…K−1 that
    the sensor clipped at 0: the maximum-likelihood normal (mean, σ) of the values before rounding and
    clipping, every value below ½ DN read as 0, with the mean bounded at 0 — a black level is an offset
    the sensor adds, never below 0 DN (a rig file refuses one), and with a true level of 0 the free fit
    lands below it half the time (−0.02 DN at 640 × 480)."""
    from scipy.optimize import minimize
    from scipy.stats import norm

    counts = np.asarray(counts, np.float64)
    k = np.arange(len(counts), dtype=np.float64)
    total = counts.sum()

    def cost(x: np.ndarray) -> float:
        black, sigma = x[0], np.exp(x[1])
        upper = norm.cdf((k + 0.5 - black) / sigma)
        lower = np.where(k == 0, 0.0, norm.cdf((k - 0.5 - black) / sigma))
        return -float(counts @ np.log(np.maximum(upper - lower, 1e-300))) / total

    mean = float(counts @ k / total)
    spread = float(np.sqrt(max(counts @ (k - mean) ** 2 / total, 0.09)))
    x = minimize(cost, np.array([mean, np.log(spread)]), method="Nelder-Mead",
                 options={"xatol": 1e-6, "fatol": 1e-9}).x  # fmt: skip
    if x[0] < 0:  # the bound: the likeliest σ with the mean at 0
        log_sigma = minimize(lambda v: cost(np.array([0.0, v[0]])), x[1:], method="Nelder-Mead",
                             options={"xatol": 1e-6, "fatol": 1e-9}).x[0]  # fmt: skip
        return 0.0, float(np.exp(log_sigma))
    return float(x[0]), float(np.exp(x[1]))


def _histograms(frames: list[np.ndarray]) -> np.ndarray:
    """(C, K) how many pixels of ``frames`` read each integer value 0…K−1, per channel."""
    rows = [[np.bincount(np.clip(np.round(c[..., i]), 0, None).astype(np.int64).ravel()) for i in range(c.shape[-1])]
            for c in map(_channels, frames)]  # fmt: skip
    size = max(len(h) for row in rows for h in row)
    return np.sum([[np.pad(h, (0, size - len(h))) for h in row] for row in rows], axis=0)


@dataclass(frozen=True)
class PhotonTransfer:
    """The photon transfer: conversion gain (DN per electron) and the pairs' signal and variance it came from."""

    conversion_gain_dn_per_e: float
    signal_dn: np.ndarray  # (N,) mean signal of each pair (black off), all channels pooled
    variance_dn2: np.ndarray  # (N,) photon variance of each pair (read noise off)
    worst_nonlinearity: float  # max |signal / (k · t) − 1| over the levels, k fitted through the origin


def photon_transfer(
    pairs: list[tuple[np.ndarray, np.ndarray]],
    exposures_s: np.ndarray,
    reference_dn: np.ndarray,
    dark: Dark,
    top: int,
) -> PhotonTransfer:
    """Conversion gain and linearity from pairs of frames (N, each (M, C): the reference's pixels) at
    ``exposures_s`` (N,), each level's ``reference_dn`` (N,): the mean of a frame at one fixed exposure
    taken just before it. Levels within 10 % of ``top`` are left out (clipping bends them)."""
    black = dark.black_level_dn
    signal, variance, used = [], [], []
    for i, (a, b) in enumerate(pairs):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        if max(a.max(), b.max()) >= 0.9 * top:
            continue
        level = 0.5 * (a + b).mean(axis=0) - black  # (C,)
        spread = np.var(a - b, axis=0) / 2 - dark.read_noise_dn**2  # (C,)
        signal.append(level)
        variance.append(spread)
        used.append(i)
    if len(used) < 3:
        raise CalibrationError(
            f"only {len(used)} unclipped photon-transfer levels (need 3): the reference is too bright for "
            "the shortest exposures; lower the lamp's power or raise it further from the reference"
        )
    s, v = np.concatenate(signal), np.concatenate(variance)
    gain = float((s @ v) / (s @ s))  # through the origin: variance ∝ signal
    relative = np.array([sig.mean() for sig in signal]) / (np.asarray(reference_dn)[used] - black.mean())
    per_second = relative / np.asarray(exposures_s)[used]
    k = float(np.median(per_second))
    worst = float(np.max(np.abs(per_second / k - 1)))
    if worst > LINEAR_WITHIN:
        raise CalibrationError(
            f"the camera's response is {100 * worst:.1f} % from linear (hlr-lab needs {100 * LINEAR_WITHIN:g} "
            "%): switch it to a raw, linear output (no gamma, tone curve or auto gain) and calibrate again"
        )
    return PhotonTransfer(gain, s, v, worst)


@dataclass(frozen=True)
class LampSensitivity:
    """Sensitivity × lamp power S · Φ per channel, from every lamp position, and how well 1/d² held."""

    sensitivity_times_power: np.ndarray  # (C,) S · Φ per channel, over all positions
    per_position: np.ndarray  # (K, C) S · Φ from each lamp position
    inverse_square_residual: float  # max |per position / overall − 1|

    @property
    def follows_inverse_square(self) -> bool:
        return self.inverse_square_residual <= INVERSE_SQUARE_WITHIN

    def relative_se(self, reflectance_se: float = 0.0) -> float:
        """The relative standard error of the rig file's one S · Φ (the channels' mean): the positions'
        scatter over √K, each channel's offset from that mean (the fit takes one number for all), and the
        white reference's own reflectance uncertainty (relative, from its certificate)."""
        ratio = self.per_position / self.sensitivity_times_power  # (K, C)
        k = len(ratio)
        scatter = float(np.mean(np.std(ratio, axis=0, ddof=1) ** 2) / k) if k > 1 else 0.0
        channel = self.sensitivity_times_power / self.sensitivity_times_power.mean() - 1
        return float(np.sqrt(scatter + np.mean(channel**2) + reflectance_se**2))


def lamp_sensitivity(
    pixels: list[np.ndarray],
    exposures_s: np.ndarray,
    gains_db: np.ndarray,
    irradiance_factor: list[np.ndarray],
    reflectance: np.ndarray,
    dark: Dark,
) -> LampSensitivity:
    """S · Φ from the white reference at K lamp positions: ``pixels`` (K, each (M, C)) its values,
    ``exposures_s`` and ``gains_db`` (K,), ``irradiance_factor`` (K, each (M,)): cos θ / d² of each
    pixel's point (m⁻²), ``reflectance`` (C,)."""
    per_position = []
    for dn, t, g, geo in zip(pixels, exposures_s, gains_db, irradiance_factor, strict=True):
        signal = np.asarray(dn, np.float64) - dark.black_level_dn  # (M, C)
        scale = t * 10 ** (g / 20) * np.asarray(geo)[:, None] * np.asarray(reflectance)[None, :]
        per_position.append(np.median(signal / scale, axis=0))
    per_position = np.array(per_position)
    overall = np.median(per_position, axis=0)
    return LampSensitivity(overall, per_position, float(np.max(np.abs(per_position / overall - 1))))
