"""How far a plan is from the fewest lights: the choice of lights as a set multicover.

Region r needs ``target[r]`` samples and candidate light j gives it ``counts[j, r]``; the fewest lights
whose counts add up to every target is an integer programme:

    minimise Σ_j x_j   subject to   Σ_j min(counts[j, r], target[r]) x_j ≥ target[r],   x_j ∈ {0, 1}.

Capping each count at its region's target changes no cover (a light never needs to give a region more
than it needs) and tightens the relaxation. Its LP relaxation (0 ≤ x_j ≤ 1) is solved over every
candidate by column generation — HiGHS on a few hundred columns at a time, every other column priced by
one matrix product — so its optimum L is a true lower bound: no cover has fewer than ⌈L⌉ lights.

The integer programme itself is solved (HiGHS branch and bound) only on the columns that can be in a
cover better than the incumbent: a column with LP reduced cost d is in no cover of fewer than L + d
lights (reduced-cost fixing), so with an incumbent of U lights only columns with d ≤ U − 1 − L matter.
That keeps the programme small and its proof valid for all the candidates. The search deepens from the
bound: a cover of k lights uses only columns with d ≤ k − L, few near the bound, so k = ⌈L⌉, ⌈L⌉ + 1, …
are each settled exactly on those (:func:`_deepened`). Every programme also says that only a cover of
fewer lights than the incumbent is wanted (Σ x ≤ incumbent − 1), which HiGHS prunes on (:func:`_solve`).

The search is bounded by work, not by time — HiGHS's branch-and-bound nodes (MILP_NODE_LIMIT), the pairs
tried (MAX_PAIR_KINDS) — so that the same inputs give the same plan on a fast machine and a loaded one.
The time budget is only a guard against an instance whose nodes are slow; when it ends the search, the
status says so (and that plan can differ on another machine). See docs/planning.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, linprog, milp

_EPS = 1e-6
_SEED_PER_REGION = 64  # columns per region that start the column generation
_ADD_PER_ROUND = 2_000  # most negative reduced costs added per round
_PAIR_BLOCK = 4_000_000  # pairs tried at once at most (×R×8 bytes)
_FIRST_PAIR_BLOCK = 65_536  # pairs tried in the first block (each next one twice as many)
# Beyond this many distinct columns the integer programme keeps those of least reduced cost (and proves
# nothing): HiGHS overran a 3 s limit by 8 s on 20 000 (its root node), and finds the same covers on 1 000.
MAX_MILP_COLUMNS = 2_000
# Work limits that make the search repeatable: HiGHS's nodes per programme (bench plan's cases are solved
# at the root node; random 400-candidate, 14-region covers proven within 2 000), and the distinct columns
# whose every pair is tried (K² pairs: 4 000 is 16 M, ~0.3 s with 14 regions)
MILP_NODE_LIMIT = 2_000
# A cover of the bound's size is sought among the cheapest this many columns before all those it could
# use (the paper's bunny counted in vertices: 64 of 8 629 held an 11-cover for its bound of 11, in 25 ms,
# where the 2 000 cheapest took 0.5 s; 4 000 random candidates: a 7-cover among 64 of 899)
_FEW_COLUMNS = (64, 256)
# ... each try asked only for a cover of k lights, within this many nodes: it is a shortcut, and the
# programme over every column a cover of k lights can use settles k after it (a 64-column try that proved
# its own best 11 for a bound of 10 took 452 nodes, 0.5 s, on a painted bunny counted in vertices)
_FEW_NODES = 50
# ... and each k is settled within this many nodes, or the deepening ends and the search goes on as it did
# without it (the rounded proof, the 2 000 cheapest columns): a programme over every column a cover of k
# lights can use is not always quick (1 981 columns of a painted bunny: 124 nodes, 4.6 s, where the
# cheapest 256 held a cover of k), and the deepening should cost little where it does not help
_DEEP_NODES = 100
MAX_PAIR_KINDS = 4_000
TIME_GUARD = "time budget reached"  # the status when the wall-clock guard, not the work limits, ended it
QUANTA = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)  # roundings of the proof, as fractions of the largest target


@dataclass(frozen=True, eq=False)
class CoverOptimum:
    """What the set multicover says about a plan with ``incumbent`` lights.

    ``lp_value``: the LP relaxation's optimum (fractional lights); ``lower_bound``: fewest lights any cover
    can have (⌈lp_value⌉, raised by the integer programme when it proves more); ``cover``: indices of the
    candidates of a cover with fewer lights than the incumbent, or None when none was found;
    ``proven``: the fewest is known (it is ``len(cover)``, or the incumbent when ``cover`` is None);
    ``status``: how the integer programme ended, in words; ``seconds``: the time taken.
    """

    lp_value: float
    lower_bound: int
    cover: np.ndarray | None
    proven: bool
    status: str
    seconds: float


def minimum_cover(
    counts: np.ndarray,
    target: np.ndarray,
    incumbent: int,
    budget_s: float,
    *,
    pairs_among: np.ndarray | None = None,
) -> CoverOptimum:
    """The LP bound of the multicover and, within ``budget_s`` seconds, a cover smaller than ``incumbent``.

    Parameters
    ----------
    counts
        (N, R) samples each candidate gives each region (non-negative, any unit).
    target
        (R,) samples each region needs; a region with 0 is not asked for. Every target must be reachable
        (``min(counts, target).sum(0) ≥ target``): pass what the candidates can give at most.
    incumbent
        Lights of a known cover (the greedy's); the integer programme looks only for fewer.
    budget_s
        Wall-clock guard on the integer programmes, seconds (0: the LP bound only). The work limits end
        the search first on the instances measured; a search the guard ends has status TIME_GUARD.
    pairs_among
        (N,) bool: the candidates among which, with an LP bound of 2, a covering pair is sought before any
        integer programme (milliseconds against ~0.1 s); None: all of them. The pair search favours the
        largest totals, and where counts are estimates those are the likeliest to be too high: a caller
        whose cover fell short when counted exactly passes the candidates it has counted exactly. Where
        none of their pairs covers, a pair among all of them is sought next, still before any programme:
        with a bound of 2 the programme's proof would only repeat the bound (on the paper's bunny a
        programme took 85 ms of its 0.17 s search).
    """
    start = time.perf_counter()
    target = np.asarray(target, dtype=np.float64)
    rows = np.flatnonzero(target > _EPS)
    if len(rows) == 0:
        return CoverOptimum(0.0, 0, None, incumbent == 0, "nothing to cover", time.perf_counter() - start)
    capped = np.minimum(np.asarray(counts, dtype=np.float64)[:, rows], target[rows])  # (N, R')
    need = target[rows]
    if np.any(capped.sum(axis=0) < need - _EPS):
        raise ValueError("a target exceeds what all the candidates give together; pass a reachable target")
    lp_value, reduced = _lp_relaxation(capped, need)
    lower = math.ceil(lp_value - _EPS)

    deadline = start + budget_s

    def result(lower: int, cover: np.ndarray | None, proven: bool, status: str) -> CoverOptimum:
        """The outcome; one not proven when the guard has passed may owe its end to the clock: said so."""
        now = time.perf_counter()
        guarded = not proven and now > deadline and budget_s > 0
        return CoverOptimum(lp_value, lower, cover, proven, TIME_GUARD if guarded else status, now - start)

    if incumbent <= lower:
        return result(lower, None, True, "the incumbent meets the LP bound")
    if budget_s <= 0:
        return result(lower, None, False, "not run (no time budget)")
    # only columns with reduced cost d ≤ incumbent − 1 − L can be in a cover of fewer lights
    useful = np.flatnonzero(reduced <= incumbent - 1 - lp_value + _EPS)
    if lower == 2 < incumbent:  # a covering pair is the fewest outright: try them first
        # among those given first (exact counts), then among all: still a pair, where the programme's
        # proof (~0.1 s) would only say what the LP bound already does
        firsts = [] if pairs_among is None else [useful[pairs_among[useful]]]
        for among in [*firsts, useful]:
            if (pair := _pair_cover(capped, among, reduced, need, deadline)) is not None:
                return result(lower, pair, True, "optimal")
    pairs_tried = lower == 2 < incumbent
    # 1. Covers of k lights, from the bound up, among the few columns they can use: exact, and at once
    deep = _deepened(capped, useful, reduced, lp_value, need, lower, incumbent, deadline)
    lower = deep.lower

    def searched(lower: int) -> CoverOptimum:
        """Where the search ends without a smaller cover: the deepening's (above the bound), or none."""
        if deep.cover is not None:
            return result(lower, deep.cover, False, "a smaller cover; not proven the fewest")
        return result(lower, None, False, "no smaller cover found within the node limit")

    if deep.cover is not None and len(deep.cover) <= lower:
        return result(lower, deep.cover, True, "optimal")
    if lower >= incumbent:
        return result(incumbent, None, True, "no cover smaller than the incumbent")
    if deep.whole:  # its programme was over every column that could beat the incumbent: no more to try
        return searched(lower)
    # 2. The proof, on counts rounded up to a quantum of the largest target: every cover is still one, so
    #    the rounded programme's minimum bounds the true one from below. Rounding merges columns into few
    #    kinds, each an integer variable bounded by how many columns it stands for.
    rounded = _rounded_kinds(capped[useful], need.max())
    kinds, inverse, multiplicity = _unique_rows(capped[useful])
    # rounded to a quantum of 0 (few kinds already), the proof is the programme step 3 would solve again
    true_solved = False
    if rounded is not None and _may_raise(rounded[0], rounded[2], need, lower):
        true_solved = np.array_equal(rounded[0], kinds)
        proof = _solve(rounded[0], rounded[2], need, deadline, most=incumbent - 1)
        if proof.status == 2:  # not even the rounded counts have a cover here: none is smaller
            return result(incumbent, None, True, "no cover smaller than the incumbent")
        if proof.status == 0:
            lower = max(lower, round(proof.fun))
        elif getattr(proof, "mip_dual_bound", None) is not None and np.isfinite(proof.mip_dual_bound):
            lower = max(lower, min(incumbent, math.ceil(proof.mip_dual_bound - _EPS)))
        if lower >= incumbent:
            return result(incumbent, None, True, "no cover smaller than the incumbent")
        cover = _cover_of(proof, rounded[1], useful, capped, need)
        if cover is not None and len(cover) < incumbent:
            proven = len(cover) <= lower
            return result(lower, cover, proven, "optimal" if proven else "node limit reached")
    if time.perf_counter() > deadline:
        return result(lower, None, False, TIME_GUARD)
    # 3. A cover of the true counts: of two lights by trying every pair (the rounding can merge a pair
    #    that falls just short with one that covers), else among the distinct columns of least reduced cost.
    if not pairs_tried and lower <= 2 < incumbent:
        pairs_tried = True
        if (pair := _pair_cover(capped, useful, reduced, need, deadline)) is not None:
            return result(lower, pair, True, "optimal")
    every_pair = pairs_tried and len(kinds) <= MAX_PAIR_KINDS and time.perf_counter() < deadline
    if every_pair and lower == 2 and incumbent == 3:  # no pair covers, and 3 lights do
        return result(incumbent, None, True, "no cover smaller than the incumbent")
    if true_solved:  # its cover, if any, was no smaller than the incumbent
        return searched(lower)
    if len(kinds) > MAX_MILP_COLUMNS:
        kinds, multiplicity, inverse, useful = _cheapest_columns(
            kinds, multiplicity, inverse, useful, reduced, MAX_MILP_COLUMNS
        )
    found = _solve(kinds, multiplicity, need, deadline, most=incumbent - 1)
    if found.x is not None:
        cover = _members(inverse, useful, np.round(found.x).astype(np.int64))
        if len(cover) < incumbent:
            proven = len(cover) <= lower
            return result(
                lower, cover, proven, "optimal" if proven else "a smaller cover; not proven the fewest"
            )
    return searched(lower)


@dataclass(frozen=True, eq=False)
class _Deepened:
    """What :func:`_deepened` found: the bound it proved, the smallest cover it saw (or None), and whether
    its last programme was over every column that can beat the incumbent (nothing left to search)."""

    lower: int
    cover: np.ndarray | None
    whole: bool = False


def _deepened(
    capped: np.ndarray,
    useful: np.ndarray,
    reduced: np.ndarray,
    lp_value: float,
    need: np.ndarray,
    lower: int,
    incumbent: int,
    deadline: float,
) -> _Deepened:
    """The fewest lights by iterative deepening on the LP's reduced costs: a cover of k lights uses only
    columns of reduced cost d ≤ k − L (``lp_value``), so for k from ``lower`` up, while those columns are at
    most MAX_MILP_COLUMNS distinct ones, the programme over them alone is exact for k. Its minimum at or
    below k is the fewest; above k (or no cover at all) no cover of k lights exists anywhere, and k + 1 is
    a bound. Near the bound those columns are few (the paper's bunny counted in vertices: 86 of 11 369 for
    L = 9.9 and k = 10, an 8 ms programme that proved 11 and gave a cover of 11, where the 2 000 cheapest
    columns took 0.4–0.55 s and proved nothing beyond them).

    ``capped`` (N, R), ``useful`` (n,) the columns that can be in a cover smaller than ``incumbent``,
    ``reduced`` (N,) their reduced costs, ``need`` (R,). Ends where the columns grow past the limit, the
    programme stops on its node limit without settling k, or k reaches ``incumbent``."""
    best: np.ndarray | None = None
    k = lower

    def smaller(cover: np.ndarray | None) -> np.ndarray | None:
        """The smaller of ``cover`` (if it beats the incumbent) and the best so far."""
        if cover is None or len(cover) >= incumbent or (best is not None and len(best) <= len(cover)):
            return best
        return cover

    while k < incumbent:
        if best is not None and len(best) <= k:  # k is the bound (L's, or no cover of fewer was found)
            return _Deepened(k, best)
        if time.perf_counter() > deadline:
            break
        columns = useful[reduced[useful] <= k - lp_value + _EPS]
        kinds, inverse, multiplicity = _unique_rows(capped[columns])
        # a cover of k lights among the cheapest few (a quarter of them at most) is the fewest already (k is
        # the bound): often there
        for few in (f for f in _FEW_COLUMNS if 4 * f <= len(kinds)):
            some = _cheapest_columns(kinds, multiplicity, inverse, columns, reduced, few)
            found = _solve(
                some[0], some[1], need, deadline, most=incumbent - 1, nodes=min(_FEW_NODES, MILP_NODE_LIMIT)
            )
            best = smaller(_cover_of(found, some[2], some[3], capped, need))
            if best is not None and len(best) <= k:
                return _Deepened(k, best)
        if len(kinds) > MAX_MILP_COLUMNS:  # too many to settle k
            break
        found = _solve(
            kinds, multiplicity, need, deadline, most=incumbent - 1, nodes=min(_DEEP_NODES, MILP_NODE_LIMIT)
        )
        best = smaller(_cover_of(found, inverse, columns, capped, need))
        if best is not None and len(best) <= k:
            return _Deepened(k, best)
        settled = found.status in (0, 2)  # optimal, or no cover among them at all
        dual = getattr(found, "mip_dual_bound", None)
        if not settled and not (dual is not None and np.isfinite(dual) and math.ceil(dual - _EPS) > k):
            return _Deepened(k, best, whole=len(columns) == len(useful))  # the node limit left k open
        k += 1  # no cover of k lights
    return _Deepened(k, best)


def _cover_of(
    found: Any, inverse: np.ndarray, columns: np.ndarray, capped: np.ndarray, need: np.ndarray
) -> np.ndarray | None:
    """The columns (from ``columns``, each of kind ``inverse``) of the programme's solution ``found``
    when it has one that reaches ``need`` on ``capped`` (N, R); else None."""
    if found.x is None:
        return None
    cover = _members(inverse, columns, np.round(found.x).astype(np.int64))
    return cover if np.all(capped[cover].sum(axis=0) >= need - _EPS) else None


def _pair_cover(
    capped: np.ndarray, useful: np.ndarray, reduced: np.ndarray, need: np.ndarray, deadline: float
) -> np.ndarray | None:
    """Two of the columns ``useful`` of ``capped`` (N, R) that together reach ``need`` (R,), searched among
    the MAX_PAIR_KINDS distinct columns of least ``reduced`` cost (N,), or None."""
    kinds, inverse, multiplicity = _unique_rows(capped[useful])
    tried = _cheapest(kinds, inverse, reduced[useful], MAX_PAIR_KINDS)
    pair = _covering_pair(kinds[tried], multiplicity[tried], need, deadline)
    if pair is None:
        return None
    return _members(inverse, useful, np.bincount(tried[pair], minlength=len(kinds)))


def _cheapest_columns(
    kinds: np.ndarray,
    multiplicity: np.ndarray,
    inverse: np.ndarray,
    columns: np.ndarray,
    reduced: np.ndarray,
    most: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The programme cut to the ``most`` kinds of least reduced cost (:func:`_cheapest`): their rows (k, R)
    and multiplicities (k,), and of the ``columns`` (n,) of those kinds, each one's kind among them and
    the columns themselves (``inverse`` (n,) each column's kind; ``reduced`` (N,) every column's cost)."""
    keep = _cheapest(kinds, inverse, reduced[columns], most)
    mask = np.isin(inverse, keep)
    return kinds[keep], multiplicity[keep], np.searchsorted(keep, inverse[mask]), columns[mask]


def _cheapest(kinds: np.ndarray, inverse: np.ndarray, reduced: np.ndarray, most: int) -> np.ndarray:
    """Indices (ascending) of at most ``most`` of ``kinds`` (K, R) of least LP reduced cost — a kind's
    columns (``inverse`` (n,): each column's kind) share theirs, ``reduced`` (n,) — ties by index."""
    if len(kinds) <= most:
        return np.arange(len(kinds))
    cost = np.zeros(len(kinds))
    cost[inverse] = reduced
    return np.sort(np.argsort(cost, kind="stable")[:most])


def _rounded_kinds(columns: np.ndarray, top: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``columns`` (n, R) rounded up to the finest of QUANTA (× ``top``) that leaves at most
    MAX_MILP_COLUMNS distinct rows: (kinds, each column's kind, each kind's count), or None (a binary
    search: three tries, each sorting all n rows)."""
    found, lo, hi = None, 0, len(QUANTA) - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        step = QUANTA[mid] * top
        rounded = np.ceil(columns / step - _EPS) * step if step else columns
        kinds = _unique_rows(rounded)
        if len(kinds[0]) <= MAX_MILP_COLUMNS:
            found, hi = kinds, mid - 1
        else:
            lo = mid + 1
    return found


def _may_raise(kinds: np.ndarray, multiplicity: np.ndarray, need: np.ndarray, lower: int) -> bool:
    """Whether the rounded programme over ``kinds`` (K, R), each up to ``multiplicity`` (K,) times, can
    plausibly prove more than ``lower`` lights: its LP relaxation (milliseconds) exceeds ``lower`` − 1, so
    that a minimum less than two lights above the relaxation would reach ``lower`` + 1. Rounding up makes
    covers cheaper, and where it makes them much cheaper (vertex counts of a few tens, rounded to 10 % of
    M: LP 7.5 against the true 9.9) the programme's minimum would have to exceed its relaxation by two
    lights or more to say anything new, and HiGHS spent 0.2–0.4 s finding that it does not
    (docs/planning.md, "How far from the fewest")."""
    relaxed = linprog(
        np.ones(len(kinds)),
        A_ub=-sparse.csr_array(kinds.T),
        b_ub=-need,
        bounds=np.column_stack([np.zeros(len(kinds)), multiplicity]),
        method="highs",
    )
    return relaxed.status != 0 or relaxed.fun > lower - 1 + _EPS


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct rows of ``a`` (n, R) float: (kinds (K, R), each row's kind (n,), each kind's count (K,)).
    Rows are compared as bytes (5× faster than ``np.unique(axis=0)``); +0.0 makes −0.0 plain 0."""
    a = np.ascontiguousarray(a + 0.0)
    rows = a.view(np.dtype((np.void, a.dtype.itemsize * a.shape[1]))).ravel()
    _, first, inverse, counts = np.unique(rows, return_index=True, return_inverse=True, return_counts=True)
    return a[first], inverse.ravel(), counts


def _solve(
    kinds: np.ndarray,
    multiplicity: np.ndarray,
    need: np.ndarray,
    deadline: float,
    *,
    most: int,
    nodes: int | None = None,
):
    """HiGHS on: minimise Σ x_k with kinds (K, R)ᵀ x ≥ need and Σ x_k ≤ ``most``, x_k integer in
    [0, multiplicity_k], within ``nodes`` branch-and-bound nodes (default MILP_NODE_LIMIT; and, as a guard,
    until ``deadline``). Status 2 (infeasible): no cover of ``most`` lights or fewer among these kinds.

    The callers want only covers that beat the incumbent, and saying so lets HiGHS prune: on the paper's
    bunny counted in vertices, 86 kinds whose fewest is 11 took 42 ms without the row Σ x ≤ 11 and 8 ms
    with it, to the same optimum. (Asking for k lights, Σ x ≤ k, proves "no cover of 10" in 6 ms there, but
    a search within a node limit then finds fewer covers: it stops before any cover of k.)"""
    # scipy's stubs type lb and ub as float; they take arrays (one bound per row, per variable)
    lower: Any = np.append(need - _EPS, -np.inf)
    upper: Any = np.append(np.full(len(need), np.inf), most)
    rows = sparse.vstack([sparse.csr_array(kinds.T), sparse.csr_array(np.ones((1, len(kinds))))])
    bounds: Any = multiplicity
    return milp(
        np.ones(len(kinds)),
        constraints=LinearConstraint(rows, lb=lower, ub=upper),
        integrality=np.ones(len(kinds)),
        bounds=Bounds(0, bounds),
        options={
            "node_limit": MILP_NODE_LIMIT if nodes is None else nodes,
            "time_limit": max(deadline - time.perf_counter(), 0.05),
            "disp": False,
        },
    )


def _covering_pair(
    kinds: np.ndarray, multiplicity: np.ndarray, need: np.ndarray, deadline: float
) -> np.ndarray | None:
    """Two kinds (the same one twice if it stands for two columns) whose counts (capped at ``need``)
    together reach ``need``, or None; until ``deadline``.

    Only pairs whose totals can reach need's are compared: with the kinds in order of falling total, kind
    i's partner is among the first p_i (total ≥ Σ need − total_i), and p_i falls as i grows, so the search
    ends where p_i ≤ i. Blocks of rows, growing from _FIRST_PAIR_BLOCK pairs to _PAIR_BLOCK, find an
    early pair early and keep memory bounded."""
    totals = kinds.sum(axis=1)  # (K,)
    order = np.argsort(-totals, kind="stable")
    sorted_kinds, totals = kinds[order], totals[order]  # (K, R), (K,) falling
    partners = np.searchsorted(-totals, -(need.sum() - totals) + len(need) * _EPS, side="right")  # (K,) p_i
    a, pairs = 0, _FIRST_PAIR_BLOCK
    while a < len(kinds) and partners[a] > a:
        if time.perf_counter() > deadline:
            return None
        b = min(a + max(1, pairs // int(partners[a] - a)), len(kinds))
        pairs = min(2 * pairs, _PAIR_BLOCK)  # a pair is often among the first: small blocks first
        block = sorted_kinds[a:b]  # (b − a, R); partners among sorted_kinds[a : partners[a]]
        ok = np.all(block[:, None, :] + sorted_kinds[None, a : partners[a], :] >= need - _EPS, axis=2)
        i, j = np.nonzero(ok)
        i, j = i + a, j + a
        valid = (j >= i) & (j < partners[i]) & ((i != j) | (multiplicity[order[i]] >= 2))
        if valid.any():
            k = int(np.flatnonzero(valid)[0])
            return order[[i[k], j[k]]]
        a = b
    return None


def _members(kind_of: np.ndarray, index: np.ndarray, taken: np.ndarray) -> np.ndarray:
    """Indices (from ``index``) of ``taken[k]`` columns of each kind k (``kind_of``: each column's kind)."""
    order = np.argsort(kind_of, kind="stable")
    starts = np.searchsorted(kind_of[order], np.arange(len(taken)))
    return np.concatenate(
        [index[order[starts[k] : starts[k] + taken[k]]] for k in np.flatnonzero(taken)]
        or [np.zeros(0, np.int64)]
    )


def _lp_relaxation(capped: np.ndarray, need: np.ndarray) -> tuple[float, np.ndarray]:
    """The relaxation's optimum over all N columns of ``capped`` (N, R) and each column's reduced cost (N,).

    Column generation: solve on a subset, price every column with the duals y (reduced cost 1 − a_j·y),
    add the most negative, until none is: then the subset's optimum is the whole problem's.
    """
    n = len(capped)
    subset = np.zeros(n, bool)
    for r in range(capped.shape[1]):  # enough of each region's best columns to cover it: feasible at once
        order = _largest_first(capped[:, r], _SEED_PER_REGION)
        enough = int(np.searchsorted(np.cumsum(capped[order, r]), need[r] - _EPS)) + 1
        if enough > len(order):  # the largest few do not reach the target: all of them, in order
            order = np.argsort(-capped[:, r], kind="stable")
            enough = int(np.searchsorted(np.cumsum(capped[order, r]), need[r] - _EPS)) + 1
        subset[order[: max(enough, _SEED_PER_REGION)]] = True
    while True:
        cols = np.flatnonzero(subset)
        res = linprog(
            np.ones(len(cols)),
            A_ub=-sparse.csr_array(capped[cols].T),
            b_ub=-need,
            bounds=(0, 1),
            method="highs",
        )
        if res.status != 0:
            raise RuntimeError(f"the LP relaxation failed: {res.message}")
        duals = -np.asarray(res.ineqlin.marginals)  # (R,) ≥ 0
        reduced = 1.0 - capped @ duals
        entering = np.flatnonzero(~subset & (reduced < -_EPS))
        if len(entering) == 0:
            return float(res.fun), reduced
        subset[entering[np.argsort(reduced[entering], kind="stable")[:_ADD_PER_ROUND]]] = True


def _largest_first(values: np.ndarray, most: int) -> np.ndarray:
    """Indices of at least the ``most`` largest of ``values`` (n,), largest first, ties by index: the start of
    ``np.argsort(-values, kind="stable")`` — every value tied with the ``most``-th largest included — without
    sorting all n (the LP's seeding sorted 11 000 columns per region: 5 ms of the paper's set-up's 0.3 s)."""
    if len(values) <= most:
        return np.argsort(-values, kind="stable")
    threshold = np.partition(values, len(values) - most)[len(values) - most]
    top = np.flatnonzero(values >= threshold)  # ascending indices: a stable sort keeps ties by index
    return top[np.argsort(-values[top], kind="stable")]
