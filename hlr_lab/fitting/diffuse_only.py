"""A region's diffuse colour where its highlight was not measured: Rd by least squares over the pixels far
from any highlight (I = L·Rd·cos α), its standard error counting surface patches, and how far from the
highlight "far" has to be (docs/fitting.md, "A diffuse colour without a highlight").

A lobe no pixel measured still reaches past any fixed β: a lobe of n = 15 gives cos¹⁵ 40° ≈ 2 % of its Rs
at 40°, and Spot's region of n 15 came out 0.9 % bright (4.7 σ) from its pixels beyond 35°. Its tail can
only add light, and less the further from the mirror direction, so :func:`diffuse_cutoff` starts at
``BETA_DEG`` and moves the cutoff out, a ``STEP_DEG`` at a time, while the Rd from the nearer pixels is
brighter than the Rd from farther ones by more than ``TAIL_Z`` standard errors of their difference — the
smallest cutoff whose Rd agrees with every farther one (Lepski's rule, one-sided) — and, where a tail was
seen, one step further, since what the rule cannot see at the first cutoff that agrees is still there. A
region without a tail keeps ``BETA_DEG`` and all its pixels; one with a tail pays in pixels only as far as
the tail reaches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BETA_DEG = 35.0  # the first cutoff: the fit's own θc reaches no further on any lobe measured
STEP_DEG = 5.0
# Nested cutoffs' differences in standard errors above which the nearer pixels are taken to hold a tail:
# one-sided, over up to 3 channels × a few farther cutoffs, 3 σ raises the cutoff of a region without a
# tail rarely, and a raise costs only pixels, never bias
TAIL_Z = 3.0


@dataclass(frozen=True)
class DiffuseCutoff:
    """Where a region's diffuse-only pixels start: ``beta_deg`` (degrees); when moved out from BETA_DEG,
    how much brighter (``brighter_pct``, per cent of the channel, the worst) the pixels from BETA_DEG made
    Rd, in standard errors of the difference (``z``)."""

    beta_deg: float
    brighter_pct: float | None = None
    z: float | None = None

    def note(self) -> str | None:
        """What the cutoff says of the region, or None where it stayed at BETA_DEG."""
        if self.brighter_pct is None:
            return None
        return (
            f"Rd from its pixels beyond β = {self.beta_deg:g}°: from {BETA_DEG:g}° they gave it "
            f"{self.brighter_pct:.2g} % more ({self.z:.1f} σ), the tail of the lobe no pixel measured"
        )


def least_squares_rd(x: np.ndarray, intensity: np.ndarray) -> np.ndarray:
    """(C,) Rd = Σ x·I / Σ x² for x = L·cos α (N,) and the pixels' intensity (N, C), not held at 0."""
    return (x[:, None] * intensity).sum(axis=0) / max(float(x @ x), 1e-300)


def rd_standard_error(x: np.ndarray, resid: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """(C,) the standard error of :func:`least_squares_rd` (x (N,), its residuals (N, C)): the larger of
    the pixels' and the surface patches' (``patch`` (N,) int; docs/fitting.md, "Standard errors")."""
    sigma2 = (resid**2).sum(axis=0) / max(len(x) - 1, 1)
    return np.maximum(np.sqrt(sigma2 / max(float(x @ x), 1e-300)), patch_rd_se(x, resid, patch))


def patch_rd_se(x: np.ndarray, resid: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """(C,) the cluster-robust standard error of the least-squares Rd = Σ x·I / Σ x² (x (M,), its residuals
    (M, C)), the pixels of a patch (``patch`` (M,) int) summed before squaring: (Σ_g (Σ_g x·r)²)^½ / Σ x²,
    times √(G/(G − 1)); 0 with fewer than 2 patches (docs/fitting.md, "Standard errors")."""
    groups, index = np.unique(patch, return_inverse=True)
    if len(groups) < 2:
        return np.zeros(resid.shape[1])
    scores = np.stack([np.bincount(index, weights=x * r, minlength=len(groups)) for r in resid.T], axis=1)
    return np.sqrt((scores**2).sum(axis=0) * len(groups) / (len(groups) - 1)) / (x @ x)


def diffuse_cutoff(
    x: np.ndarray, intensity: np.ndarray, cos_beta: np.ndarray, patch: np.ndarray, min_pixels: int
) -> DiffuseCutoff:
    """The β beyond which a region's pixels give its Rd without a lobe's tail (see the module's docstring):
    ``x`` (N,) L·cos α, ``intensity`` (N, C), ``cos_beta`` (N,), ``patch`` (N,) int; a cutoff keeps at least
    ``min_pixels`` pixels (BETA_DEG when even it does not)."""
    beta = np.degrees(np.arccos(np.clip(cos_beta, -1.0, 1.0)))
    cuts, rds, ses, weights, counted = [], [], [], [], -1
    for cut in np.arange(BETA_DEG, 90.0, STEP_DEG):
        far = beta > cut
        count = int(far.sum())
        if count < min_pixels:
            break
        if count == counted:
            continue  # the same pixels as the nearer cutoff: nothing to compare
        counted = count
        rd = least_squares_rd(x[far], intensity[far])
        cuts.append(float(cut))
        rds.append(rd)
        ses.append(rd_standard_error(x[far], intensity[far] - x[far, None] * rd, patch[far]))
        weights.append(float(x[far] @ x[far]))
    if not cuts:
        return DiffuseCutoff(BETA_DEG)
    rd, se, w = np.array(rds), np.array(ses), np.array(weights)  # (K, C), (K, C), (K,)
    # z[i, j]: how much brighter cutoff i's Rd is than a farther j's, in standard errors of the difference —
    # nested least squares: Var(Rd_j − Rd_i) = Var(Rd_j)·(1 − W_j/W_i), W the Σ x² of each
    share = np.sqrt(np.clip(1.0 - w[None, :] / w[:, None], 0.0, None))  # (K, K)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = ((rd[:, None, :] - rd[None, :, :]) / (se[None, :, :] * share[:, :, None])).max(axis=2)
    z = np.where(np.triu(np.ones_like(z, bool), k=1), np.nan_to_num(z, nan=0.0, posinf=0.0), 0.0)
    agrees = int(np.argmax((z <= TAIL_Z).all(axis=1)))  # the last cutoff has nothing farther: found
    if agrees == 0:
        return DiffuseCutoff(cuts[0])
    # a tail seen from the nearer cutoffs is still there, unseen, at the first that agrees: a lobe of n 15
    # whose Rd was 60 σ bright at 35° was still +0.3 σ (mean) where the rule stopped; a step further, 0.1 σ
    chosen = min(agrees + 1, len(cuts) - 1)
    brighter = 100 * (rd[0] - rd[chosen]) / np.maximum(np.abs(rd[chosen]), 1e-12)
    return DiffuseCutoff(cuts[chosen], float(brighter.max()), float(z[0, chosen]))
