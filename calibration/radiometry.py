"""The camera's radiometry and the lamp's power from dark frames and a white reference
(docs/calibration.md, "calibrate radiometric").

The model hlr-lab fits with (``[sensor]``, ``[light]``): a pixel reads

    DN = S · g · t · L + black + noise,   L = R · Φ · cos θ / d²   (a Lambertian surface under a point lamp)

with S the sensitivity (DN per radiance unit and second at 0 dB), g the analogue gain, t the exposure, R
the reflectance, Φ the lamp's power, θ the angle of incidence and d the lamp's distance. Only S · Φ is
measurable (and only it matters: it makes the fitted R absolute). Noise: read noise σ_r (DN) and photon
noise of variance K · (DN − black), K the conversion gain in DN per electron.

* **Dark frames** (lamp off, pairs at each exposure): the black level is their mean per channel; the
  read noise is the spread of a pair's difference over √2 (fixed pattern cancels).
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


def dark_statistics(pairs: list[tuple[np.ndarray, np.ndarray]]) -> Dark:
    """Black level per channel and read noise from pairs of dark frames (H, W[, C]), each pair at one
    exposure."""
    if not pairs:
        raise CalibrationError("no dark frames: take them with the lamp off")
    means = np.mean([[_channels(f).mean(axis=(0, 1)) for f in pair] for pair in pairs], axis=(0, 1))
    spreads = [np.std(_channels(a) - _channels(b)) / np.sqrt(2) for a, b in pairs]
    return Dark(means, float(np.sqrt(np.mean(np.square(spreads)))))


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
