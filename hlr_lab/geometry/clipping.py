"""One definition of a clipped value, for the adaptive bracketing that decides to take a shorter exposure
and the HDR merge that leaves clipped values out: were they to differ, bracketing could stop while values
sit that the merge then throws away (top and top − 1 once)."""

from __future__ import annotations

import numpy as np

CLIP_MARGIN_DN = 1  # codes within this of the top count as clipped (an ADC's top codes are unreliable)


def clip_level(bits: int) -> int:
    """The lowest code that counts as clipped on a ``bits``-bit sensor."""
    return (1 << bits) - 1 - CLIP_MARGIN_DN


def clipped(values: np.ndarray, bits: int, *, channels: bool) -> np.ndarray:
    """Raw values → bool, True where clipped: with ``channels``, the last axis holds a pixel's channels and
    any channel at or above :func:`clip_level` clips the pixel ((…, C) → (…)); without, value by value."""
    at = np.asarray(values) >= clip_level(bits)
    return np.any(at, axis=-1) if channels else at
