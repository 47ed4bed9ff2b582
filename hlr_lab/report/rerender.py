"""The fitted materials rendered back into a pose, from the session's own geometry, to set beside the
photograph: eq. (1) per pixel, zero where the lamp does not reach (shadow, facing away)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.fitting.model import predict
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.reflectance.views import PixelGeometry


@dataclass(frozen=True)
class Comparison:
    """A pose's photograph against the fitted materials rendered back, and their PSNR (dB) on the object."""

    captured: np.ndarray  # (H, W, C) radiance, NaN where unusable
    rendered: np.ndarray  # (H, W, C)
    mask: np.ndarray  # (H, W) bool: object pixels with usable radiance and a fitted material
    psnr_db: float


def rerender(geometry: PixelGeometry, materials: MaterialsFile, shape: tuple[int, int, int]) -> np.ndarray:
    """(H, W, 3) radiance the fitted materials give at this pose; NaN off the object and on regions
    without an entry. An unmeasured specular renders as diffuse only."""
    out = np.full(shape, np.nan, np.float64)
    by_id = {e.id: e for e in materials.regions}
    for rid in np.unique(geometry.region):
        entry = by_id.get(int(rid))
        if entry is None:
            continue
        m = geometry.region == rid
        rs = np.zeros(3) if entry.rs is None else np.array(entry.rs)
        n = 1.0 if entry.n is None else entry.n
        value = predict(
            np.array(entry.rd),
            rs,
            n,
            geometry.irradiance[m],
            np.clip(geometry.cos_alpha[m], 0, None),
            geometry.cos_beta[m],
        )
        value[~geometry.lit[m]] = 0.0
        x, y = geometry.pixel[m, 0], geometry.pixel[m, 1]
        out[y, x] = value
    return out


def compare(captured: np.ndarray, rendered: np.ndarray, within: np.ndarray | None = None) -> Comparison:
    """PSNR over the object's pixels where both exist (and ``within``, (H, W) bool, when given), peak =
    the brightest captured value there."""
    mask = np.all(np.isfinite(captured), axis=-1) & np.all(np.isfinite(rendered), axis=-1)
    if within is not None:
        mask &= within
    if not mask.any():
        return Comparison(captured, rendered, mask, float("nan"))
    a, b = captured[mask].astype(np.float64), rendered[mask]
    mse = float(np.mean((a - b) ** 2))
    peak = float(a.max())
    psnr = float("inf") if mse == 0 else 10 * np.log10(peak**2 / mse)
    return Comparison(captured, rendered, mask, psnr)
