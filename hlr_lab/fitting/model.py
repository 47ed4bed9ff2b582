"""The reflection model, eq. (1) of the paper, per RGB channel: I = L · (Rd · cos α + Rs · cosⁿ β)."""

from __future__ import annotations

import numpy as np


def predict(
    rd: np.ndarray,
    rs: np.ndarray,
    n: float,
    irradiance: np.ndarray,
    cos_alpha: np.ndarray,
    cos_beta: np.ndarray,
) -> np.ndarray:
    """(N, 3) model intensity; rd, rs (3,); irradiance (N,), (N, 1) or (N, 3); cosines (N,)."""
    irr = irradiance if irradiance.ndim == 2 else irradiance[:, None]
    return irr * (cos_alpha[:, None] * rd + cos_beta[:, None] ** n * rs)


def lobe_angle(rs_grey: float, n: float, irradiance: float, level: float) -> float:
    """β (radians) where the highlight L·Rs·cosⁿβ falls to ``level``; 0 when it never exceeds it."""
    peak = irradiance * rs_grey
    if peak <= level or n <= 0:
        return 0.0
    return float(np.arccos((level / peak) ** (1.0 / n)))
