"""The default estimator: robust weighted least squares on the full model (1), all pixels at once.

1. Start: with Rd from the median of I/(L cos α) over the diffuse-only pixels, n from a line fit of
   log(Is/L) against log cos β over the highlight pixels.
2. Variable projection on a stratified subsample: for fixed n the model is linear in (Rd, Rs) per
   channel, so n is a 1-D search over a profile (grid, then Brent).
3. Noise model from the residuals: var = a + b·μ (read noise + photon noise, μ the model value),
   estimated robustly per bin of μ.
4. Newton on all pixels for (Rd[3], Rs[3], n) on the Huber cost (k = 1.345) of the residuals
   standardised by that noise model (held at the starting fit): inter-reflections and the odd bad pixel
   lose their pull instead of biasing Rd, and no division by cosⁿβ ever amplifies noise. From the
   subsample's start one pass usually suffices (see ``_gauss_newton``).
5. Standard errors from the sandwich covariance H⁻¹ (Σ ψ² J Jᵀ/σ²) H⁻¹ — or, where the pixels' surface
   patches are known and that is the larger, the same with each patch's scores summed before squaring
   (what the model misses on a patch it misses in all its pixels: ``_patch_se``); the answer's response to
   moved inputs (a rig quantity believed a little wrong: docs/fitting.md, "Systematic uncertainty") by the
   implicit function theorem, δp = H⁻¹ δg, the gradient's change at the answer (:class:`Linearised`).
6. Rd and Rs are reflectances: a channel that comes out below 0 (a near-black surface, whose noise
   straddles 0) is held at 0 and the others fitted again (an active set: the bounded least-squares
   solution); its standard error stays the unbounded fit's, the scale of what the pixels can tell.

Every full pass runs in chunks (memory beyond the inputs stays constant) and does its 3×3 blocks per
channel with BLAS; the starting values and the n search use the subsample only.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from hlr_lab.fitting.inputs import Samples, normal_mad
from hlr_lab.fitting.paper import Estimate

HUBER_K = 1.345  # 95 % efficiency under Gaussian noise
_CHUNK = 1 << 14  # 128 KB arrays stay in cache: 1.6× faster than 2 MB chunks (measured)
_SUBSAMPLE = 100_000
_MAX_PASSES = 4
_MAX_HALVINGS = 6
_ONE_PASS_SE = 10.0  # a Newton step this small (in standard errors) needs no checking pass …
_ONE_PASS_RELATIVE = 1e-3  # … nor one this small relative to the parameters: Newton's error after a step
# is second order in the start's error, so a start within 0.1 % lands within ~1e-6
_NOISE_BINS = 12
_MAX_GRID_MOVES = 4  # the n search's grid spans a factor 12 either side of its centre; moved this often
_MAX_RESTARTS = 3  # Newton again, the noise model at its answer, while n moves more than …
_RESTART_N = 1e-3  # … this fraction from where the noise model was taken


def fit_robust(s: Samples, highlight: np.ndarray, n_range: tuple[float, float], seed: int = 0) -> Estimate:
    """Fit (Rd, Rs, n) to ``s`` by the module's steps; ``highlight``: (N,) bool, the pixels within θc;
    n is kept within ``n_range``; ``seed`` fixes the subsample."""
    sub, sub_weight, sub_highlight = _subsample(s, highlight, seed)
    n0 = _start_n(sub, sub_highlight, n_range)
    n1, rd1, rs1 = _profile_n(sub, sub_weight, n0, n_range)
    noise = _noise_model(sub, rd1, rs1, n1)
    start = np.concatenate([rd1, rs1, [n1]])
    variance = _Variance(noise, start, s)
    p, cov, rms = _gauss_newton(s, start, variance, n_range)
    for _ in range(_MAX_RESTARTS):
        # the noise model is the start's: from a start far off (a sharp lobe whose first guess was a
        # broad one) its σ at the peak is wrong, Huber's weights with it, and n ends biased (measured: +4 %
        # at n = 485, 15 of its standard errors); taken again where Newton ended, it is right
        if abs(p[6] - variance.p[6]) <= _RESTART_N * variance.p[6]:
            break
        variance = _Variance(_noise_model(sub, p[:3], p[3:6], p[6]), p.copy(), s)
        p, cov, rms = _gauss_newton(s, p, variance, n_range)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    held, held_z = np.zeros(7, bool), np.full(6, np.nan)
    while np.any(p[:6] < 0) and not held[:6].all():  # each pass holds at least one more channel
        below = np.flatnonzero(p[:6] < 0)
        held_z[below] = p[below] / np.maximum(se[below], 1e-300)
        held[below] = True
        p, cov, rms = _gauss_newton(s, np.where(held, 0.0, p), variance, n_range, held=held)
        se = np.where(held, se, np.sqrt(np.clip(np.diag(cov), 0, None)))
    if s.patch is not None:
        se = np.where(held, se, np.maximum(se, _patch_se(s, p, variance, held)))
    response = Linearised(s, p, variance, held)
    # the noise at the lobe's peak; a lobe fitted below zero (no highlight seen) has none: the floor's
    mu_peak = max(float(np.mean(p[3:6]) * np.median(s.irradiance)), 0.0)
    sigma = float(np.sqrt(max(noise[0] + noise[1] * mu_peak, 0.0)))
    return Estimate(
        p[:3],
        p[3:6],
        float(p[6]),
        se[:3],
        se[3:6],
        float(se[6]),
        int((~highlight).sum()),
        int(highlight.sum()),
        sigma,
        rms,
        held_z,
        response,
    )


class Linearised:
    """The fit's first-order response to its pixels' inputs moved (the same pixels, in the same order):
    at the answer p the cost's gradient is 0; inputs moved by a little change it by δg, and the answer
    moves by H⁻¹ δg (the implicit function theorem; H the Hessian with ψ', the held channels left out).
    The noise model stays the fit's: what moves is the geometry or the radiometry believed, not the pixels'
    noise. Exact to first order in the move; one pass over the pixels per call (and one, once, for the
    fitted inputs' own gradient, which a converged fit leaves near but not exactly at 0)."""

    def __init__(self, s: Samples, p: np.ndarray, variance: _Variance, held: np.ndarray):
        self._s, self._p, self._variance = s, p.copy(), variance
        self._free = (~held).astype(float)
        self._at_answer: tuple[np.ndarray, np.ndarray] | None = None  # H⁻¹ and the gradient, when first asked

    def shift(self, moved: Samples) -> np.ndarray:
        """(7,) the change of (Rd[3], Rs[3], n) that ``moved`` (the fitted pixels, their inputs moved)
        asks for."""
        if len(moved) != len(self._s):
            raise ValueError(f"moved inputs of {len(moved)} pixels for a fit of {len(self._s)}")
        if self._at_answer is None:
            hessian, _, grad, *_ = _normal_equations(self._s, self._p, self._variance)
            self._at_answer = np.linalg.pinv(hessian * np.outer(self._free, self._free)), grad
        h_inv, grad = self._at_answer
        moved_grad = _normal_equations(moved, self._p, self._variance)[2]
        return h_inv @ ((moved_grad - grad) * self._free)


def _start_n(s: Samples, highlight: np.ndarray, n_range) -> float:
    d = ~highlight
    rd0 = np.median(s.intensity[d] / (s.irradiance[d] * s.cos_alpha[d, None]), axis=0)
    h = s.subset(highlight)
    z = ((h.intensity - h.irradiance * h.cos_alpha[:, None] * rd0) / h.irradiance).mean(axis=1)
    ok = z > 0.05 * max(z.max(), 1e-12)
    if ok.sum() >= 5 and np.ptp(h.log_cos_beta[ok]) > 0:
        # log z = log Rs + n log cos β, weighted by z² (the noise on log z is σ/z)
        a = np.column_stack([np.ones(ok.sum()), h.log_cos_beta[ok]]) * z[ok, None]
        slope = np.linalg.lstsq(a, np.log(z[ok]) * z[ok], rcond=None)[0][1]
        if np.isfinite(slope):
            return float(np.clip(slope, *n_range))
    return 20.0  # the n search spans a factor 12 either side of its start


def _subsample(s: Samples, highlight: np.ndarray, seed: int) -> tuple[Samples, np.ndarray, np.ndarray]:
    """Every highlight pixel up to half the budget, diffuse ones to fill it; weights undo the sampling.

    Returns the subsample, its weights and its highlight mask."""
    rng = np.random.default_rng(seed)
    weight = np.ones(len(s))
    idx = []
    for part, budget in (
        (np.flatnonzero(highlight), _SUBSAMPLE // 2),
        (np.flatnonzero(~highlight), _SUBSAMPLE),
    ):
        if len(part) > budget:
            weight[part] = len(part) / budget
            part = rng.choice(part, budget, replace=False)
        idx.append(part)
    chosen = np.concatenate(idx)
    return s.subset(chosen), weight[chosen], highlight[chosen]


def _linear_given_n(s: Samples, w: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted LS for (Rd, Rs) per channel at fixed n; returns rd, rs (3,) and residuals (N, 3)."""
    e = s.lobe(n)[0]
    a, b = s.irradiance * s.cos_alpha[:, None], s.irradiance * e[:, None]  # (N, 3) each (broadcast)
    a, b = np.broadcast_to(a, s.intensity.shape), np.broadcast_to(b, s.intensity.shape)
    wa, wb = w[:, None] * a, w[:, None] * b
    saa, sab, sbb = (wa * a).sum(0), (wa * b).sum(0), (wb * b).sum(0)
    sya, syb = (wa * s.intensity).sum(0), (wb * s.intensity).sum(0)
    det = saa * sbb - sab * sab
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    rd = (sya * sbb - syb * sab) / det
    rs = (syb * saa - sya * sab) / det
    return rd, rs, s.intensity - a * rd - b * rs


def _about_zero(x: np.ndarray, axis: int | None = None) -> float:
    """The centre of residuals that are already about zero (MAD's centre, for a scale of residuals)."""
    return 0.0


def _profile_n(s: Samples, w: np.ndarray, n0: float, n_range) -> tuple[float, np.ndarray, np.ndarray]:
    """n minimising the Huber-weighted residuals with (Rd, Rs) solved for each n (variable projection)."""
    lo, hi = np.log(n_range[0]), np.log(n_range[1])
    # scale for the Huber weights from a first fit at n0
    _, _, r0 = _linear_given_n(s, w, n0)
    sigma = float(normal_mad(np.ravel(r0), center=_about_zero)) + 1e-12

    def cost(log_n: float) -> float:
        _, _, r = _linear_given_n(s, w, float(np.exp(log_n)))
        t = np.abs(r) / sigma
        rho = np.where(t <= HUBER_K, 0.5 * t * t, HUBER_K * t - 0.5 * HUBER_K**2)
        return float((w[:, None] * rho).sum())

    def search(centre: float) -> tuple[np.ndarray, int]:
        grid = np.linspace(max(lo, centre - 2.5), min(hi, centre + 2.5), 9)
        return grid, int(np.argmin([cost(g) for g in grid]))

    grid, k = search(np.log(n0))
    for _ in range(_MAX_GRID_MOVES):  # a minimum at the grid's edge lies beyond it: move the grid there
        if 0 < k < len(grid) - 1 or grid[k] in (lo, hi):
            break
        grid, k = search(grid[k])
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    # the full-data passes polish n; 0.1 % here is plenty
    log_n = (
        minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-3}).x
        if a < b
        else grid[k]
    )
    n = float(np.exp(log_n))
    rd, rs, _ = _linear_given_n(s, w, n)
    return n, rd, rs


def _noise_model(s: Samples, rd, rs, n) -> np.ndarray:
    """(a, b) of var = a + b·μ from the robust variance of residuals in bins of the model value μ."""
    e = s.lobe(n)[0]
    mu = (s.irradiance * (s.cos_alpha[:, None] * rd + e[:, None] * rs)).ravel()
    r = (s.intensity - mu.reshape(s.intensity.shape)).ravel()
    edges = np.quantile(mu, np.linspace(0, 1, _NOISE_BINS + 1))
    which = np.clip(np.searchsorted(edges, mu, side="right") - 1, 0, _NOISE_BINS - 1)
    rows, var = [], []
    for k in range(_NOISE_BINS):
        rk = r[which == k]
        if len(rk) >= 20:
            rows.append([1.0, float(np.median(mu[which == k]))])
            var.append(float(normal_mad(np.ravel(rk))) ** 2)
    if len(rows) < 2:
        return np.array([max(float(np.var(r)), 1e-12), 0.0])
    coef, _ = nnls(np.array(rows), np.array(var))
    floor = 1e-6 * max(float(np.median(var)), 1e-24)  # keep weights finite for noiseless data
    return np.array([max(coef[0], floor), coef[1]])


class _Variance:
    """Per-pixel noise variance a + b·μ, with μ the model at the starting parameters.

    Holding μ at the start (already close: the subsample's fit) keeps the weighted problem fixed, so
    Newton converges in a pass or two instead of chasing weights that move with every step. The start's
    lobe cosⁿ⁰β is kept (8 bytes a pixel) rather than recomputed every pass.
    """

    def __init__(self, noise: np.ndarray, p: np.ndarray, s: Samples):
        self.noise, self.p = noise, p
        self.lobe = s.lobe(float(p[6]))[0]

    def __call__(self, mu_start: np.ndarray) -> np.ndarray:
        return self.noise[0] + self.noise[1] * np.maximum(mu_start, 0.0)


def _gauss_newton(s: Samples, p: np.ndarray, noise: _Variance, n_range, held: np.ndarray | None = None):
    """Newton on the Huber cost Σ ρ(r/σ) from a close start; the parameters ``held`` (7,) bool keep their
    start's values (their rows and columns of the normal equations left out).

    Steps from Σ w(t) J Jᵀ/σ² with IRLS's weights w = ψ(t)/t (1 inside k, k/|t| beyond), gradient
    Σ ψ(t) J/σ: where most pixels lie inside k this is Newton's own step; where a start lies many σ from the
    data at the lobe's peak (noise-free data, a sharp bright lobe), ψ' = 0 there would drop those pixels
    from the step and leave n undetermined (measured: a noise-free n = 485 went to n = 1), while w keeps
    them, and the step still lowers the cost (the weighted quadratic majorises Huber's). A small step
    (``_ONE_PASS_SE`` standard errors, or ``_ONE_PASS_RELATIVE`` of the parameters) is taken without
    another pass; a larger one is checked by the next pass, halved while it raises the cost, and given up
    if halving does not help. Standard errors: the sandwich H⁻¹ (Σ ψ(t)² J Jᵀ/σ²) H⁻¹ with H = Σ ψ'(t) J
    Jᵀ/σ², right whatever the share of outliers.

    Returns p, the covariance, and the plain residual RMS.
    """
    free = np.ones(7) if held is None else (~held).astype(float)
    mask = np.outer(free, free)

    def along(step: np.ndarray) -> np.ndarray:  # p + step, n kept within its range
        trial = p + step
        trial[6] = float(np.clip(trial[6], *n_range))
        return trial

    sums = _normal_equations(s, p, noise)
    for _ in range(_MAX_PASSES):
        hessian, weighted, grad, cost, meat, rss = sums
        h_inv = np.linalg.pinv(hessian * mask)
        step = np.linalg.pinv(weighted * mask) @ (grad * free)
        se = np.sqrt(np.clip(np.diag(h_inv @ meat @ h_inv), 1e-300, None))
        trial = along(step)
        if np.all(np.abs(step) <= _ONE_PASS_SE * se) or np.all(
            np.abs(step) <= _ONE_PASS_RELATIVE * np.abs(p)
        ):
            p = trial
            break
        t = _normal_equations(s, trial, noise)
        for _halving in range(_MAX_HALVINGS):
            if t[3] <= cost * (1 + 1e-9):
                break
            step = step / 2
            trial = along(step)  # half of a step past the range can still be past it
            t = _normal_equations(s, trial, noise)  # the sums are always the trial's own
        if t[3] > cost * (1 + 1e-9):
            break  # no step along this direction lowers the cost: p is as good as it gets
        p, sums = trial, t
    hessian, _, _, _, meat, rss = sums
    h_inv = np.linalg.pinv(hessian * mask)
    return p, h_inv @ (meat * mask) @ h_inv, float(np.sqrt(rss / (3 * len(s))))


def _normal_equations(s: Samples, p: np.ndarray, noise: _Variance):
    """At ``p``: the Hessian with ψ' (7, 7), the same with IRLS weights ψ(t)/t (7, 7), gradient (7,),
    Huber cost, the sandwich's meat (7, 7) and the plain residual sum of squares — one pass over the pixels
    in chunks (memory stays flat)."""
    hess, weighted, meat = (np.zeros((3, 3, 3)) for _ in range(3))  # per channel, [a, e, n']
    grads = np.zeros((3, 3))
    cost = rss = 0.0
    for start in range(0, len(s), _CHUNK):
        h, hw, m, g, c, r = _chunk_sums(s, p, noise, slice(start, start + _CHUNK))
        hess, weighted, meat, grads = hess + h, weighted + hw, meat + m, grads + g
        cost, rss = cost + c, rss + r
    rs = p[3:6]
    return (_assemble(hess, rs), _assemble(weighted, rs), _assemble_vector(grads, rs), cost,
            _assemble(meat, rs), rss)  # fmt: skip


def _assemble(blocks: np.ndarray, rs: np.ndarray) -> np.ndarray:
    """Per-channel 3×3 blocks over (∂rd_c, ∂rs_c, ∂n ÷ rs_c) → the 7×7 matrix over (rd[3], rs[3], n)."""
    out = np.zeros((7, 7))
    for c in range(3):
        idx = [c, 3 + c]
        out[np.ix_(idx, idx)] = blocks[c, :2, :2]
        out[idx, 6] = out[6, idx] = rs[c] * blocks[c, :2, 2]  # ∂μ/∂n = rs · e · L · log cos β
        out[6, 6] += rs[c] ** 2 * blocks[c, 2, 2]
    return out


def _assemble_vector(grads: np.ndarray, rs: np.ndarray) -> np.ndarray:
    return np.concatenate([grads[:, 0], grads[:, 1], [float(rs @ grads[:, 2])]])


def _chunk_sums(s: Samples, p: np.ndarray, noise: _Variance, sl: slice):
    hess, weighted, meat = np.zeros((3, 3, 3)), np.zeros((3, 3, 3)), np.zeros((3, 3, 3))
    grads = np.zeros((3, 3))
    cost = rss = 0.0
    for c, jac, r, inv_var in _channels(s, p, noise, sl):
        t2 = r * r * inv_var
        t = np.sqrt(t2)
        beyond = np.maximum(t - HUBER_K, 0.0)
        cost += 0.5 * (float(t2.sum()) - float(np.dot(beyond, beyond)))  # Huber ρ = ½t² − ½(t − k)² beyond k
        with np.errstate(divide="ignore", invalid="ignore"):
            shrink = np.minimum(1.0, HUBER_K / t)  # ψ(t)/t (1 at t = 0: k/0 = inf)
        psi = r * inv_var * shrink  # ψ(t)/σ
        rss += float(np.dot(r, r))
        hess[c] = (jac * ((beyond == 0) * inv_var)) @ jac.T  # ψ'(t)/σ²
        weighted[c] = (jac * (shrink * inv_var)) @ jac.T  # ψ(t)/(t σ²)
        meat[c] = (jac * (psi * psi)) @ jac.T  # ψ(t)²/σ²
        grads[c] = jac @ psi
    return hess, weighted, meat, grads, cost, rss


def _channels(s: Samples, p: np.ndarray, noise: _Variance, sl: slice):
    """Per channel c of the pixels ``sl``: c, the Jacobian (3, M) over (∂rd_c, ∂rs_c, ∂n ÷ rs_c) — one
    buffer, valid until the next channel —, the residuals (M,) and the noise model's 1/σ² (M,)."""
    rd, rs, n = p[:3], p[3:6], p[6]
    rd0, rs0 = noise.p[:3], noise.p[3:6]
    ca = s.cos_alpha[sl]
    e, lb = s.lobe(n, sl)  # the lobe as the pixels see it, and d(log lobe)/dn
    shared_light = s.irradiance.shape[1] == 1
    jac = np.empty((3, len(ca)))
    lobe0 = np.empty(0)  # the start's lobe under this light: set at c = 0, and per channel if lights differ
    for c in range(3):
        if c == 0 or not shared_light:
            light = s.irradiance[sl, 0 if shared_light else c]
            np.multiply(light, ca, out=jac[0])  # ∂μ/∂rd
            np.multiply(light, e, out=jac[1])  # ∂μ/∂rs
            np.multiply(jac[1], lb, out=jac[2])  # ∂μ/∂n ÷ rs
            lobe0 = light * noise.lobe[sl]
        mu = rd[c] * jac[0] + rs[c] * jac[1]
        yield c, jac, s.channels[c, sl] - mu, 1.0 / noise(rd0[c] * jac[0] + rs0[c] * lobe0)


def _patch_se(s: Samples, p: np.ndarray, noise: _Variance, held: np.ndarray) -> np.ndarray:
    """(7,) standard errors counting the surface's patches (``s.patch``) rather than its pixels: the
    sandwich H⁻¹ (Σ_g u_g u_gᵀ) H⁻¹ · G/(G − 1), u_g the sum over patch g's pixels and channels of their
    ψ(t)/σ · J (the cluster-robust sandwich; G the patches). What the model misses in one patch it misses
    in each of its pixels alike — a shading normal a little off, a texel —, which the pixels' own sandwich
    counts as that many independent errors."""
    assert s.patch is not None
    patches, index = np.unique(s.patch, return_inverse=True)
    if len(patches) < 2:
        return np.zeros(7)
    scores = np.zeros((len(patches), 7))
    rs = p[3:6]
    for start in range(0, len(s), _CHUNK):
        sl = slice(start, start + _CHUNK)
        where = index[sl]
        for c, jac, r, inv_var in _channels(s, p, noise, sl):
            t = np.sqrt(r * r * inv_var)
            with np.errstate(divide="ignore", invalid="ignore"):
                psi = r * inv_var * np.minimum(1.0, HUBER_K / t)  # ψ(t)/σ
            for k, column in ((c, 0), (3 + c, 1)):
                scores[:, k] += np.bincount(where, weights=psi * jac[column], minlength=len(patches))
            scores[:, 6] += rs[c] * np.bincount(where, weights=psi * jac[2], minlength=len(patches))
    free = ~held
    hessian = _normal_equations(s, p, noise)[0]
    h_inv = np.linalg.pinv(hessian * np.outer(free, free))
    scores *= free
    cov = h_inv @ (scores.T @ scores) @ h_inv * len(patches) / (len(patches) - 1)
    return np.sqrt(np.clip(np.diag(cov), 0, None))
