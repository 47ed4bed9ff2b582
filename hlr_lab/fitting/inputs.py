"""Checking and holding the per-pixel samples of one region (the boundary of the numerical core)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from hlr_lab.errors import HlrLabError, InputError

MIN_DIFFUSE = 20  # diffuse-only pixels needed for Rd (3 values) with outlier rejection
MIN_HIGHLIGHT = 20  # highlight pixels needed for Rs (3 values) and n
MIN_BETA_SPAN_DEG = 1.0  # n is the lobe's fall-off: the highlight pixels must span some range of β


def normal_mad(x: np.ndarray, axis: int = 0, center: Callable[..., object] = np.median) -> np.ndarray:
    """The median absolute deviation scaled to a normal σ (÷ Φ⁻¹(¾) ≈ 0.6745): a scale 50 % of outliers
    cannot move. ``x`` (N, …) → the shape of ``x`` without ``axis``."""
    # imported here: scipy.stats costs ~0.3 s at import, which every command would pay (plan, acquire, doctor)
    from scipy.stats import median_abs_deviation

    # scipy takes scale="normal"; its type stubs allow only a float there
    return np.asarray(median_abs_deviation(x, axis=axis, center=center, scale="normal"))  # pyright: ignore[reportArgumentType]


class InsufficientSamples(HlrLabError):
    """Too few diffuse-only or highlight pixels to fit; ``kind``, ``count`` and ``needed`` say which."""

    def __init__(self, kind: str, count: int, needed: int, theta_c_deg: float):
        self.kind, self.count, self.needed, self.theta_c_deg = kind, count, needed, theta_c_deg
        where = "β ≤ θc" if kind == "highlight" else "β > θc"
        super().__init__(
            f"only {count} {kind} pixels ({where}, θc = {theta_c_deg:.3g}°) but {needed} are needed; "
            "plan more lights for this region or change θc"
        )


class DegenerateSamples(HlrLabError):
    """The pixels cannot determine a parameter (e.g. every highlight pixel at the same β)."""


@dataclass(frozen=True, eq=False)
class Samples:
    """One region's pixels: intensity (N, 3), irradiance (N, 1) or (N, 3), cos_alpha (N,), cos_beta (N,) at
    the pixel centre, and ``footprint`` (N, K): log cos β at K quadrature nodes over each pixel's area, whose
    mean lobe is the one the pixel saw (None: every pixel a point sample); ``patch`` (N,) int ≥ 0: the patch
    of surface each pixel saw — what the model gets wrong on a patch it gets wrong in all of that patch's
    pixels, so the standard errors count patches, not pixels, where that is the larger (None: every pixel
    on its own)."""

    intensity: np.ndarray
    irradiance: np.ndarray
    cos_alpha: np.ndarray
    cos_beta: np.ndarray
    footprint: np.ndarray | None = None
    patch: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.cos_alpha)

    @cached_property
    def channels(self) -> np.ndarray:
        """(3, N) intensity, one contiguous row per channel (the fitting passes read channel by channel)."""
        return np.ascontiguousarray(self.intensity.T)

    @cached_property
    def log_cos_beta(self) -> np.ndarray:
        """(N,) log cos β at the pixel centre (its mean over the pixel's nodes when those are known)."""
        return np.log(self.cos_beta) if self.footprint is None else self.footprint.mean(axis=1)

    @cached_property
    def _spread(self) -> np.ndarray:
        """(N,) bool: the pixels whose nodes differ (elsewhere one value serves)."""
        assert self.footprint is not None
        return np.ptp(self.footprint, axis=1) > 0

    def lobe(self, n: float, which: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """The lobe as the pixels ``which`` saw it — cosⁿβ, or its mean over each pixel's nodes — and its
        log-derivative in n (log cos β, or the nodes' lobe-weighted mean of it), (M,) each."""
        m = self.log_cos_beta[which]
        e = np.exp(n * m)
        if self.footprint is None:
            return e, m
        spread = self._spread[which]
        nodes = self.footprint[which][spread]  # (K, nodes)
        lobes = np.exp(n * nodes)
        e[spread] = lobes.mean(axis=1)
        slope = m.copy()
        with np.errstate(invalid="ignore", divide="ignore"):  # a lobe 0 at every node: its centre's slope
            weighted = (nodes * lobes).mean(axis=1) / e[spread]
        slope[spread] = np.where(e[spread] > 0, weighted, m[spread])
        return e, slope

    def subset(self, which: np.ndarray) -> Samples:
        return Samples(
            self.intensity[which],
            self.irradiance[which],
            self.cos_alpha[which],
            self.cos_beta[which],
            None if self.footprint is None else self.footprint[which],
            None if self.patch is None else self.patch[which],
        )


def check_samples(intensity, irradiance, cos_alpha, cos_beta, footprint=None, patch=None) -> Samples:
    """Convert and validate; one InputError naming the argument and how many values are wrong.
    ``footprint``: (N, K) log cos β at K nodes over each pixel's area, or None; ``patch``: (N,) the surface
    patch of each pixel (integers ≥ 0), or None."""
    i = _array("intensity", intensity)
    if i.ndim != 2 or i.shape[1] != 3:
        raise InputError(f"must have shape (N, 3), got {i.shape}", field="intensity")
    n = len(i)
    ca, cb = _array("cos_alpha", cos_alpha), _array("cos_beta", cos_beta)
    for name, a in (("cos_alpha", ca), ("cos_beta", cb)):
        if a.shape != (n,):
            raise InputError(f"must have shape ({n},) like intensity, got {a.shape}", field=name)
    irr = _array("irradiance", irradiance)
    if irr.shape == (n,):
        irr = irr[:, None]
    elif irr.shape != (n, 3):
        raise InputError(f"must have shape ({n},) or ({n}, 3), got {irr.shape}", field="irradiance")
    _count_bad("irradiance", ~np.all(irr > 0, axis=1), "≤ 0 (unlit pixels do not belong in a fit)")
    _count_bad("cos_alpha", ~((ca > 0) & (ca <= 1 + 1e-9)), "outside (0, 1] (the light must be in front)")
    _count_bad("cos_beta", ~((cb > 0) & (cb <= 1 + 1e-9)), "outside (0, 1]")
    nodes = None
    if footprint is not None:
        nodes = _array("footprint", footprint)
        if nodes.ndim != 2 or len(nodes) != n or nodes.shape[1] == 0:
            raise InputError(f"must have shape ({n}, K) like intensity, got {nodes.shape}", field="footprint")
        _count_bad("footprint", np.any(nodes > 1e-9, axis=1), "above 0 (a log cos β)")
        nodes = np.minimum(nodes, 0.0)
    patches = None
    if patch is not None:
        patches = np.asarray(patch)
        if patches.shape != (n,) or not np.issubdtype(patches.dtype, np.integer):
            raise InputError(f"must be ({n},) integers like intensity, got {patches.dtype} {patches.shape}",
                             field="patch")  # fmt: skip
        _count_bad("patch", patches < 0, "below 0 (a patch is an index)")
    return Samples(i, irr, np.minimum(ca, 1.0), np.minimum(cb, 1.0), nodes, patches)


def _array(name: str, value) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"is not numeric ({exc})", field=name) from exc
    bad = int(np.size(a) - np.isfinite(a).sum())
    if bad:
        raise InputError(f"{bad} values are NaN or infinite", field=name)
    return a


def _count_bad(name: str, bad: np.ndarray, what: str) -> None:
    if bad.any():
        raise InputError(f"{int(bad.sum())} of {len(bad)} values are {what}", field=name)
