"""Colour conversions: 8-bit sRGB as meshes store it → linear RGB → CIELAB, and back.

Pure numpy functions on ``(..., 3)`` arrays. sRGB primaries with a D65 white (IEC 61966-2-1).
"""

from __future__ import annotations

import numpy as np

# linear sRGB → CIE XYZ (D65)
_RGB_TO_XYZ = np.array(
    [
        [0.4124564, 0.3575761, 0.1804375],
        [0.2126729, 0.7151522, 0.0721750],
        [0.0193339, 0.1191920, 0.9503041],
    ]
)
_D65_WHITE = _RGB_TO_XYZ.sum(axis=1)  # XYZ of linear RGB (1, 1, 1)


def srgb8_to_linear(srgb8: np.ndarray) -> np.ndarray:
    """``(..., 3)`` 8-bit sRGB (uint8 or 0–255 floats) → linear RGB in [0, 1], float64."""
    c = np.asarray(srgb8, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    """``(..., 3)`` linear RGB → 8-bit sRGB, uint8 (values outside [0, 1] are clipped)."""
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def linear_to_lab(linear: np.ndarray) -> np.ndarray:
    """``(..., 3)`` linear RGB → CIELAB ``(..., 3)`` (L* in [0, 100]), D65 white."""
    xyz = np.asarray(linear, dtype=np.float64) @ _RGB_TO_XYZ.T / _D65_WHITE
    eps, kappa = 216 / 24389, 24389 / 27
    f = np.where(xyz > eps, np.cbrt(xyz), (kappa * xyz + 16) / 116)
    return np.stack(
        [116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1
    )


def srgb8_to_lab(srgb8: np.ndarray) -> np.ndarray:
    """``(..., 3)`` 8-bit sRGB → CIELAB: the perceptual space the segmentation clusters in."""
    return linear_to_lab(srgb8_to_linear(srgb8))


def delta_e(lab_a: np.ndarray, lab_b: np.ndarray) -> np.ndarray:
    """CIE76 colour difference ΔE*ab between broadcastable ``(..., 3)`` Lab arrays.

    ΔE ≈ 2.3 is a just-noticeable difference; colours of different materials differ by tens.
    """
    return np.linalg.norm(np.asarray(lab_a) - np.asarray(lab_b), axis=-1)
