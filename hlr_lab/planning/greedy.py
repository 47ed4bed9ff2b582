"""Greedy light selection (paper §3.2 steps 4–6) with lazy exact evaluation.

Each step takes the candidate whose highlights serve the regions that still need samples best. Scores
come from per-view estimates; the top candidate is evaluated exactly (cone, grazing, shadows) and
re-scored, and a candidate is accepted once its exact score is within ``TOLERANCE`` of every remaining
estimate (or after ``MAX_EVALUATIONS`` tries, the best exact one): the counts of a chosen light are always
exact, at the cost of a few ray casts per light.

Two objectives: ``capped`` (ours: a region counts only up to what it still needs, so no light is spent
on a region that has enough) and the paper's plain count (every sample of a region still short counts).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

# A light must add at least this much (count unit) to be worth a photograph, or all that is still needed.
MIN_GAIN = 1.0
# Accept the best exactly-scored light when no estimate beats it by more than this fraction: estimates
# come from coarser samples than the exact counts, and chasing the last per cent costs many ray casts.
TOLERANCE = 0.05
MAX_EVALUATIONS = 32


@dataclass(frozen=True)
class Choice:
    """One light the greedy chose: its view, its candidate index, and the exact samples it gives."""

    view: int
    candidate: int
    counts: np.ndarray  # (R,) exact samples per region this light gives


@dataclass(frozen=True)
class Selection:
    """The greedy's choices in order, the views they use, and whether it stopped at the light limit."""

    choices: list[Choice]
    views_used: list[int]
    hit_light_limit: bool


def score(estimates: np.ndarray, need: np.ndarray, capped: bool) -> np.ndarray:
    """(Q,) score of candidates with per-region counts ``estimates`` (Q, R) given what regions need (R,)."""
    if capped:
        return np.minimum(estimates, np.maximum(need, 0.0)).sum(axis=1)
    return estimates[:, need > 0].sum(axis=1)


def select_lights(
    estimates_of: Callable[[int], np.ndarray],
    n_views: int,
    evaluate: Callable[[int, int, np.ndarray], np.ndarray],
    need: np.ndarray,
    *,
    capped: bool,
    max_lights: int,
    first_views: Sequence[int] = (0,),
) -> Selection:
    """Choose lights until every region's need is met, nothing more helps, or ``max_lights``.

    ``estimates_of(v)`` gives view v's (Q, R) estimated counts (computed on first use; copied here, since
    exact counts overwrite them); ``evaluate(v, q, need)`` the exact (R,) counts (it may refine the
    candidate for the current need). Views beyond ``first_views`` are opened only when the open ones
    cannot help any more (each new view is a turntable move).
    """
    need = need.astype(np.float64).copy()
    estimates: dict[int, np.ndarray] = {}
    exact: dict[int, np.ndarray] = {}
    used: list[int] = []

    def ensure(v: int) -> None:
        if v not in estimates:
            estimates[v] = np.array(estimates_of(v), dtype=np.float64, copy=True)
            exact[v] = np.zeros(len(estimates[v]), bool)

    for v in first_views:
        ensure(v)
        used.append(v)
    choices: list[Choice] = []
    while (need > 0).any() and len(choices) < max_lights:
        best = _best(estimates, exact, used, need, capped, evaluate)
        if best is None:
            unopened = [v for v in range(n_views) if v not in used]
            if not unopened:
                break
            for v in unopened:
                ensure(v)
            # open the view whose best estimate is highest (ties: the earlier view)
            gains = {v: score(estimates[v], need, capped).max(initial=0.0) for v in unopened}
            v_best = max(unopened, key=lambda v: (gains[v], -v))
            if gains[v_best] < _min_gain(need):
                break
            used.append(v_best)
            continue
        v, q = best
        counts = estimates[v][q].copy()
        choices.append(Choice(v, q, counts))
        need -= counts
        estimates[v][q] = 0.0  # the same light again would photograph the same pixels
    views_used = sorted({c.view for c in choices}, key=[c.view for c in choices].index)
    return Selection(
        choices, views_used, hit_light_limit=bool((need > 0).any() and len(choices) >= max_lights)
    )


def _min_gain(need: np.ndarray) -> float:
    """What a light must add to be chosen: MIN_GAIN, or less when a region is short by less than that."""
    short = need[need > 0]
    return min(MIN_GAIN, float(short.min())) if len(short) else MIN_GAIN


def _best(estimates, exact, used, need, capped, evaluate):
    """The (view, candidate) to accept among the open views, or None when nothing gains MIN_GAIN."""
    for _ in range(MAX_EVALUATIONS):
        best_exact, best_estimate = _top(estimates, exact, used, need, capped)
        if best_estimate is None or (
            best_exact is not None and best_exact[2] >= (1 - TOLERANCE) * best_estimate[2]
        ):
            return None if best_exact is None else best_exact[:2]
        v, q, _ = best_estimate
        estimates[v][q] = evaluate(v, q, need)
        exact[v][q] = True
    best_exact, _ = _top(estimates, exact, used, need, capped)
    return None if best_exact is None else best_exact[:2]


def _top(estimates, exact, used, need, capped):
    """Best (view, candidate, score) among exactly scored and among estimated candidates (None below the
    minimum gain)."""
    worth = _min_gain(need)
    best: dict[bool, tuple[int, int, float] | None] = {True: None, False: None}
    for v in used:
        s = score(estimates[v], need, capped)
        for is_exact in (True, False):
            masked = np.where(exact[v] == is_exact, s, -np.inf)
            q = int(np.argmax(masked)) if len(masked) else -1
            held = best[is_exact]
            if q >= 0 and masked[q] >= worth and (held is None or masked[q] > held[2]):
                best[is_exact] = (v, q, float(masked[q]))
    return best[True], best[False]
