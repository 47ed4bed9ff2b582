"""The paper's estimator (§3.3), faithful but for one necessary change.

Separation by θc; Rd (2)(3) = mean of I/(L cos α) over diffuse-only pixels after dropping values more
than 3 robust standard deviations from the median; n by the ratio criterion (6); Rs (7) = mean of
Is/(L cosⁿβ) over the highlight pixels.

The change: (6) on consecutive pixels sorted by β collapses to n ≈ 1 on quantised, noisy data — two
neighbours differ in β by a hair and their intensity ratio is 1 ± noise, which cosⁿβᵢ/cosⁿβᵢ₊₁ ≈ 1
matches for any small n. We aggregate first: the highlight pixels are split into equal-count bins by β,
and (6) compares the ratios of consecutive bins' mean Is/L with those of their mean cosⁿβ. Bins whose
mean Is is within three of its own standard errors of zero are left out: the ratio of two noise-level
means says nothing about n, yet dominates the sum once θc is wider than the lobe.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import minimize_scalar

from hlr_lab.fitting.inputs import Samples, normal_mad
from hlr_lab.fitting.model import predict

_REJECT_SIGMAS = 3.0  # "values that deviate strongly" (paper: inter-reflection and the like)
_PIXELS_PER_BIN = 100
_BINS = (5, 40)
_COS_PER_BIN = 256
_SIGNAL_SE = 3.0
_GRID = 400  # log-spaced n: 1.9 % steps over 1…2000, then Brent within a step


@dataclass(frozen=True)
class Estimate:
    """What an estimator returns: Rd, Rs (3,) linear, n, their standard errors, the pixels used."""

    rd: np.ndarray
    rs: np.ndarray
    n: float
    rd_se: np.ndarray
    rs_se: np.ndarray
    n_se: float
    n_diffuse: int
    n_highlight: int
    noise_sigma: float  # per-pixel noise at the highlight, intensity units (grey)
    residual_rms: float  # of I − model over all pixels, intensity units
    # (6,) the Rd, Rs channels held at 0 where the unbounded fit went below: its value there in its
    # standard errors (< 0), NaN where not held (None: the estimator does not bound them)
    held_at_zero: np.ndarray | None = None
    # the answer's first-order response to moved inputs (the robust estimator's; None: not linearised)
    response: Response | None = None


class Response(Protocol):
    """How an estimate moves when its pixels' inputs move a little (the same pixels, in the same order):
    ``shift(moved)`` → (7,) the change of (Rd[3], Rs[3], n), to first order."""

    def shift(self, moved: Samples) -> np.ndarray: ...


def fit_paper(s: Samples, highlight: np.ndarray, n_range: tuple[float, float]) -> Estimate:
    """``highlight`` (N,) bool: β ≤ θc. Caller guarantees enough pixels on both sides."""
    diffuse = ~highlight
    ratio = s.intensity[diffuse] / (s.irradiance[diffuse] * s.cos_alpha[diffuse, None])  # (Nd, 3)
    med = np.median(ratio, axis=0)
    mad = normal_mad(ratio)
    keep = (np.abs(ratio - med) <= _REJECT_SIGMAS * np.maximum(mad, 1e-12)).all(axis=1)
    rd = ratio[keep].mean(axis=0)
    rd_se = ratio[keep].std(axis=0, ddof=1) / np.sqrt(keep.sum())
    resid = s.intensity[diffuse][keep] - s.irradiance[diffuse][keep] * s.cos_alpha[diffuse][keep, None] * rd
    sigma = float(np.mean(normal_mad(resid)))

    h = s.subset(highlight)
    specular = (h.intensity - h.irradiance * h.cos_alpha[:, None] * rd) / h.irradiance  # Is / L, (Nh, 3)
    order = np.argsort(-h.cos_beta, kind="stable")  # β ascending
    bins = np.array_split(order, int(np.clip(len(order) // _PIXELS_PER_BIN, *_BINS)))
    grey = specular.mean(axis=1)
    signal = [b for b in bins if grey[b].mean() > _SIGNAL_SE * grey[b].std(ddof=1) / np.sqrt(len(b))]
    bins = signal if len(signal) >= 3 else bins[:3]
    criterion = _RatioCriterion(
        np.array([grey[b].mean() for b in bins]), [h.log_cos_beta[b] for b in bins], n_range
    )
    n = criterion.minimise()
    jack = np.array([criterion.minimise(leave_out=k, refine=False) for k in range(len(bins))])
    n_se = float(np.sqrt((len(bins) - 1) / len(bins) * np.sum((jack - jack.mean()) ** 2)))

    per_pixel_rs = specular / h.cos_beta[:, None] ** n  # eq. (7) before the mean
    rs = per_pixel_rs.mean(axis=0)
    rs_se = per_pixel_rs.std(axis=0, ddof=1) / np.sqrt(len(per_pixel_rs))
    model = predict(rd, rs, n, s.irradiance, s.cos_alpha, s.cos_beta)
    rms = float(np.sqrt(np.mean((s.intensity - model) ** 2)))
    return Estimate(rd, rs, n, rd_se, rs_se, n_se, int(keep.sum()), int(highlight.sum()), sigma, rms)


class _RatioCriterion:
    """Eq. (6) on bins: Σᵢ |ratioᵢ − m(n)ᵢ / m(n)ᵢ₊₁| with m(n) the bin mean of cosⁿβ, on a grid of n.

    Bins hold up to ``_COS_PER_BIN`` of their pixels' log cos β (evenly spaced in β order): the bin mean
    of cosⁿβ is smooth in β, and this keeps the grid × pixels matrix small for any region size.
    """

    def __init__(self, bin_is: np.ndarray, bin_log_cos: list[np.ndarray], n_range: tuple[float, float]):
        self.bin_is = bin_is
        self.bin_log_cos = [
            lc[np.linspace(0, len(lc) - 1, min(len(lc), _COS_PER_BIN)).astype(int)] for lc in bin_log_cos
        ]
        self.log_n = np.linspace(np.log(n_range[0]), np.log(n_range[1]), _GRID)
        self.means = self._means(self.log_n)  # (G, B)

    def _means(self, log_n: np.ndarray) -> np.ndarray:
        n = np.exp(np.atleast_1d(log_n))[:, None]
        return np.stack([np.exp(n * lc[None, :]).mean(axis=1) for lc in self.bin_log_cos], axis=1)

    def _values(self, means: np.ndarray, keep: np.ndarray) -> np.ndarray:
        m, b = means[:, keep], self.bin_is[keep]
        return np.abs(b[:-1] / b[1:] - m[:, :-1] / np.maximum(m[:, 1:], 1e-300)).sum(axis=1)

    def minimise(self, leave_out: int | None = None, refine: bool = True) -> float:
        keep = np.ones(len(self.bin_is), bool)
        if leave_out is not None:
            keep[leave_out] = False
        values = self._values(self.means, keep)
        k = int(np.argmin(values))
        lo, hi = self.log_n[max(k - 1, 0)], self.log_n[min(k + 1, len(self.log_n) - 1)]
        if not refine or lo == hi:
            return float(np.exp(self.log_n[k]))
        best = minimize_scalar(
            lambda x: float(self._values(self._means(x), keep)[0]), bounds=(lo, hi), method="bounded"
        )
        return float(np.exp(best.x))
