"""Fitting Phong parameters to one region's pixels (paper §3.3, and a better default).

```python
from hlr_lab.fitting import fit_region
fit = fit_region(intensity, irradiance, cos_alpha, cos_beta, theta_c_deg=20.0, method="robust")
fit.rd, fit.rs, fit.n, fit.theta_c_deg, fit.n_diffuse, fit.n_highlight, fit.rd_se, fit.rs_se, fit.n_se
```
intensity (N, 3) linear pixel values; irradiance (N,) or (N, 3), L at each pixel (Φ/d² for a point
light); cos_alpha, cos_beta (N,). ``theta_c_deg`` is a float or "auto"; ``method`` a name of
:data:`ESTIMATORS` (the one table of estimators: every command, file format and benchmark reads it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal, get_args

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.fitting.inputs import (
    MIN_BETA_SPAN_DEG,
    MIN_DIFFUSE,
    MIN_HIGHLIGHT,
    DegenerateSamples,
    InsufficientSamples,
    Samples,
    check_samples,
)
from hlr_lab.fitting.model import lobe_angle
from hlr_lab.fitting.paper import Estimate, Response, fit_paper
from hlr_lab.fitting.robust import fit_robust

__all__ = [
    "DEFAULT_ESTIMATOR",
    "ESTIMATORS",
    "DegenerateSamples",
    "EstimatorName",
    "InsufficientSamples",
    "RegionFit",
    "Response",
    "fit_region",
    "fit_shift",
]


@dataclass(frozen=True)
class Estimator:
    """One way of fitting a region: ``fit(samples, highlight mask (N,), n range) -> Estimate``;
    ``per_theta_c``: its estimate depends on θc (refitted as automatic θc moves), else one fit serves."""

    fit: Callable[..., Estimate]
    per_theta_c: bool
    summary: str


EstimatorName = Literal["robust", "paper"]
ESTIMATORS: dict[EstimatorName, Estimator] = {
    "robust": Estimator(fit_robust, per_theta_c=False,
                        summary="robust weighted least squares on the full model, all pixels at once (the default)"),
    "paper": Estimator(fit_paper, per_theta_c=True,
                       summary="the paper's §3.3: Rd from the diffuse-only pixels, n by the ratio criterion, then Rs"),
}  # fmt: skip
assert set(ESTIMATORS) == set(get_args(EstimatorName)), "EstimatorName names the table's rows"
DEFAULT_ESTIMATOR: EstimatorName = "robust"

N_RANGE = (1.0, 2000.0)  # plausible Blinn-Phong exponents
AUTO_START_DEG = 45.0  # "start wide"
AUTO_NOISE_LEVELS = 3.0  # θc where the fitted lobe falls to this many noise σ
AUTO_LIMITS_DEG = (0.5, 60.0)
AUTO_TOLERANCE_DEG = 0.1
AUTO_ITERATIONS = 12
AUTO_MIN_HIGHLIGHT_FRACTION = (
    0.005  # never narrow θc below what keeps this share of pixels (and 5× the minimum)
)


@dataclass(frozen=True)
class RegionFit:
    """One region's fitted Phong parameters with their standard errors and the pixels behind them."""

    rd: np.ndarray  # (3,) diffuse reflectance, linear
    rs: np.ndarray  # (3,) specular reflectance
    n: float  # sharpness (exponent of cos β, β between the normal and the half vector)
    theta_c_deg: float  # the θc used (given, or chosen when "auto")
    n_diffuse: int  # diffuse-only pixels used (β > θc)
    n_highlight: int  # highlight pixels used (β ≤ θc)
    rd_se: np.ndarray
    rs_se: np.ndarray
    n_se: float
    method: EstimatorName
    residual_rms: float  # RMS of I − model over all pixels, intensity units
    noise_sigma: float  # estimated per-pixel noise at the highlight
    # (6,) the Rd, Rs channels held at 0 because the unbounded fit went below (a near-black surface): the
    # unbounded value in its standard errors there, NaN elsewhere
    held_at_zero: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))
    # how (rd, rs, n) move when the inputs do (:class:`~hlr_lab.fitting.paper.Response`; the robust
    # estimator's), for the systematic uncertainty; None where the estimator has none
    response: Response | None = field(default=None, repr=False)


def fit_region(
    intensity,
    irradiance,
    cos_alpha,
    cos_beta,
    theta_c_deg: float | Literal["auto"] = 20.0,
    method: EstimatorName = DEFAULT_ESTIMATOR,
    footprint: np.ndarray | None = None,
    patch: np.ndarray | None = None,
) -> RegionFit:
    """Fit (Rd, Rs, n) of eq. (1) to one region's pixels; see the module docstring for the arguments.
    ``footprint``: (N, K) log cos β at K nodes over each pixel's area, so that the robust estimator fits
    the lobe as the pixels saw it, the mean of its values at the nodes; None: every pixel a point sample.
    The paper's estimator takes the pixel centre, as the paper does. ``patch``: (N,) int, the surface patch
    each pixel saw; the robust estimator's standard errors then count patches where that gives the larger
    (``fitting.robust``, step 5); None: every pixel on its own.

    Raises InputError for malformed input, InsufficientSamples when fewer than MIN_DIFFUSE diffuse-only
    or MIN_HIGHLIGHT highlight pixels remain, DegenerateSamples when the highlight pixels span too little
    of β to tell n; never returns NaN parameters.
    """
    if method not in ESTIMATORS:
        raise InputError(f"unknown method {method!r}; use one of {', '.join(ESTIMATORS)}", field="method")
    robust = method == "robust"
    s = check_samples(intensity, irradiance, cos_alpha, cos_beta, footprint if robust else None,
                      patch if robust else None)  # fmt: skip
    estimator = ESTIMATORS[method].fit
    if theta_c_deg == "auto":
        theta, est = _auto_theta_c(s, estimator, refit=ESTIMATORS[method].per_theta_c)
    else:
        try:
            theta = float(theta_c_deg)
        except (TypeError, ValueError) as exc:
            raise InputError(f"must be degrees or 'auto', got {theta_c_deg!r}", field="theta_c_deg") from exc
        if not 0 < theta < 90:
            raise InputError(f"must lie in (0, 90) degrees, got {theta}", field="theta_c_deg")
        est = _run(s, estimator, theta)
    params = np.concatenate([est.rd, est.rs, [est.n], est.rd_se, est.rs_se, [est.n_se]])
    if not np.isfinite(params).all():
        raise DegenerateSamples(
            f"the fit did not reach finite values ({est.n_highlight} highlight, "
            f"{est.n_diffuse} diffuse pixels); the pixels do not constrain the model"
        )
    return RegionFit(
        est.rd,
        est.rs,
        est.n,
        theta,
        est.n_diffuse,
        est.n_highlight,
        est.rd_se,
        est.rs_se,
        est.n_se,
        method,
        est.residual_rms,
        est.noise_sigma,
        np.full(6, np.nan) if est.held_at_zero is None else est.held_at_zero,
        est.response,
    )


def fit_shift(fit: RegionFit, intensity, irradiance, cos_alpha, cos_beta, footprint=None) -> np.ndarray:
    """(7,) how ``fit``'s (Rd[3], Rs[3], n) move, to first order, were its pixels' inputs these instead
    (the same pixels in the same order as fitted, shapes as :func:`fit_region`'s: a rig quantity believed
    a little differently). Raises ValueError for an estimator without a linearisation (the paper's)."""
    if fit.response is None:
        raise ValueError(f"the {fit.method} estimator gives no linearisation")
    return fit.response.shift(check_samples(intensity, irradiance, cos_alpha, cos_beta, footprint))


def _run(s: Samples, estimator, theta_c_deg: float) -> Estimate:
    highlight = s.cos_beta >= np.cos(np.radians(theta_c_deg))
    n_h = int(highlight.sum())
    if len(s) - n_h < MIN_DIFFUSE:
        raise InsufficientSamples("diffuse-only", len(s) - n_h, MIN_DIFFUSE, theta_c_deg)
    if n_h < MIN_HIGHLIGHT:
        raise InsufficientSamples("highlight", n_h, MIN_HIGHLIGHT, theta_c_deg)
    beta = np.degrees(np.arccos(np.percentile(s.cos_beta[highlight], [5, 95])))
    if beta[0] - beta[1] < MIN_BETA_SPAN_DEG:
        raise DegenerateSamples(
            f"the {n_h} highlight pixels all lie within {beta[0] - beta[1]:.2f}° of β = "
            f"{beta[1]:.1f}°, so the lobe's sharpness n cannot be told from them; they must span "
            f"at least {MIN_BETA_SPAN_DEG}° (photograph the region under more light positions)"
        )
    return estimator(s, highlight, N_RANGE)


def _auto_theta_c(s: Samples, estimator, refit: bool) -> tuple[float, Estimate]:
    """The paper's open point: θc from the data. Start wide, fit, move θc to where the fitted lobe
    L·Rs·cosⁿβ falls to AUTO_NOISE_LEVELS noise σ, refit; stop when θc moves less than the tolerance.

    ``refit=False`` for an estimator that uses every pixel whatever θc (robust): θc then only splits the
    pixels for the counts and chooses the fit's start, and one fit serves every iteration; a second start
    from the θc so found is kept when it fits better (docs/fitting.md, "θc from the data").
    """
    # start wide, but not so wide that too few pixels are left beyond θc to tell the diffuse part (a
    # small region seen only near its highlight)
    keep_diffuse = min(len(s), 5 * MIN_DIFFUSE)
    widest = 0.999 * float(np.degrees(np.arccos(np.sort(s.cos_beta)[keep_diffuse - 1])))
    theta = min(AUTO_START_DEG, max(widest, AUTO_LIMITS_DEG[0]))
    irradiance = float(np.median(s.irradiance))
    # a poor first fit (the paper's estimator at a wide θc) may ask for a θc that holds no pixels at all
    keep = min(len(s), max(5 * MIN_HIGHLIGHT, int(AUTO_MIN_HIGHLIGHT_FRACTION * len(s))))
    narrowest = float(np.degrees(np.arccos(np.sort(s.cos_beta)[::-1][keep - 1])))
    est = _run(s, estimator, theta)

    def settle(theta: float, est: Estimate) -> tuple[float, Estimate]:
        for _ in range(AUTO_ITERATIONS):
            level = AUTO_NOISE_LEVELS * max(est.noise_sigma, 1e-12)
            new = np.degrees(lobe_angle(float(np.mean(est.rs)), est.n, irradiance, level))
            new = float(np.clip(max(new, narrowest), *AUTO_LIMITS_DEG))
            if new < theta / 2:  # damp big jumps: they come from a fit made with a θc far from the answer
                new = float(np.sqrt(new * theta))
            if abs(new - theta) < AUTO_TOLERANCE_DEG:
                break
            theta = new
            if refit:
                est = _run(s, estimator, theta)
        return theta, est

    theta, est = settle(theta, est)
    if not refit:
        # One fit serves every θc, but it started from the widest θc's pixels: among millions of diffuse
        # pixels a dim narrow lobe can leave that start in a minimum without a lobe (Rs 0, n ~1: the pebble
        # with n = 1500, Rs 0.05 under 64 lights). A second start from the θc the first chose is kept when
        # its residuals are smaller (there: Rs 0.049, n 1499), and θc settles again from it.
        try:
            again = _run(s, estimator, theta)
        except (InsufficientSamples, DegenerateSamples):  # the first start's θc leaves too few: keep it
            again = None
        if again is not None and again.residual_rms < est.residual_rms:
            theta, est = settle(theta, again)
        n_h = int((s.cos_beta >= np.cos(np.radians(theta))).sum())
        est = replace(est, n_diffuse=len(s) - n_h, n_highlight=n_h)
    return theta, est
