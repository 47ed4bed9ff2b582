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
# ... and give some short region a share of what it needs (or all it lacks): the smaller of NEED_SHARE of
# what it needs in all (the lights photographed before the plan included) and BEST_SHARE of the most one
# light gives it. A light adding 3 pixels to a region that needs 450 more, whose best light gave 90, is
# chasing the rest of a highlight along the region's border, where the fit takes none (docs/planning.md,
# "How lights are chosen", step 3). Where a region needs few samples, or no light gives it many (vertex
# counts), the floor stays at MIN_GAIN: below M = 50 (NEED_SHARE × 50 = 1) always, so plans for the
# default M are what they were without it.
NEED_SHARE = 0.02
BEST_SHARE = 0.10
# Accept the best exactly-scored light when no estimate beats it by more than this fraction: estimates
# come from coarser samples than the exact counts, and chasing the last per cent costs many ray casts.
TOLERANCE = 0.05
MAX_EVALUATIONS = 32
# Capped scores tie wherever estimates exceed what a region still needs; among those the light giving
# short regions more samples in all is the better bet (an estimate may be high, the total rarely all
# wrong). Small enough never to outweigh a whole sample of capped gain on a 1000-sample plain count.
TIE_BREAK = 1e-4


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
    plain = estimates[:, need > 0].sum(axis=1)
    if capped:
        return np.minimum(estimates, np.maximum(need, 0.0)).sum(axis=1) + TIE_BREAK * plain
    return plain


def select_lights(
    estimates_of: Callable[[int], np.ndarray],
    n_views: int,
    evaluate: Callable[[int, int, np.ndarray], np.ndarray],
    need: np.ndarray,
    *,
    capped: bool,
    max_lights: int,
    first_views: Sequence[int] = (0,),
    taken: Sequence[Choice] = (),
    photographed: np.ndarray | None = None,
) -> Selection:
    """Choose lights until every region's need is met, nothing more helps, or ``max_lights``.

    ``estimates_of(v)`` gives view v's (Q, R) estimated counts (computed on first use; copied here, since
    exact counts overwrite them); ``evaluate(v, q, need)`` the exact (R,) counts (it may refine the
    candidate for the current need). Views beyond ``first_views`` are opened only when the open ones
    cannot help any more (each new view is a turntable move). ``taken``: lights already chosen (their
    views open), which the selection goes on from. ``photographed`` (K, R): the exact counts of the lights
    photographed before this plan, which ``need`` already leaves out; with ``need`` they set the floor a
    light must clear (what each region needs in all, and the most one light gives it).
    """
    need = need.astype(np.float64).copy()
    before = np.zeros((0, len(need))) if photographed is None else np.asarray(photographed, dtype=np.float64)
    share_of_need = NEED_SHARE * (np.maximum(need, 0.0) + before.sum(axis=0))  # (R,)
    # (R,) the most one light gives each region: photographed, chosen, or estimated in the views opened
    most = before.max(axis=0, initial=0.0)
    estimates: dict[int, np.ndarray] = {}
    exact: dict[int, np.ndarray] = {}
    used: list[int] = []

    def ensure(v: int) -> None:
        if v not in estimates:
            estimates[v] = np.array(estimates_of(v), dtype=np.float64, copy=True)
            exact[v] = np.zeros(len(estimates[v]), bool)
            np.maximum(most, estimates[v].max(axis=0, initial=0.0), out=most)

    for v in dict.fromkeys([*first_views, *(c.view for c in taken)]):
        ensure(v)
        used.append(v)
    choices: list[Choice] = list(taken)
    for c in taken:
        need -= c.counts
        np.maximum(most, c.counts, out=most)
        estimates[c.view][c.candidate] = 0.0
    while (need > 0).any() and len(choices) < max_lights:
        floor = _gain_floor(share_of_need, most)
        best = _best(estimates, exact, used, need, floor, capped, evaluate)
        if best is None:
            unopened = [v for v in range(n_views) if v not in used]
            if not unopened:
                break
            for v in unopened:
                ensure(v)
            # open the view whose best estimate is highest (ties: the earlier view)
            floor = _gain_floor(share_of_need, most)
            gains = {v: _worth(estimates[v], need, floor, capped).max(initial=0.0) for v in unopened}
            v_best = max(unopened, key=lambda v: (gains[v], -v))
            if gains[v_best] < _min_gain(need):
                break
            used.append(v_best)
            continue
        v, q = best
        counts = estimates[v][q].copy()
        choices.append(Choice(v, q, counts))
        need -= counts
        np.maximum(most, counts, out=most)
        estimates[v][q] = 0.0  # the same light again would photograph the same pixels
    views_used = sorted({c.view for c in choices}, key=[c.view for c in choices].index)
    return Selection(
        choices, views_used, hit_light_limit=bool((need > 0).any() and len(choices) >= max_lights)
    )


def prune(selection: Selection, min_samples: float | np.ndarray) -> Selection:
    """``selection`` without the lights it can do without: a light goes when every region it served that has
    its ``min_samples`` (a float, or (R,) each region's) keeps them without it and it gives no short region
    anything (reverse delete, the light with the least capped gain first). A greedy's early lights often
    become redundant later.
    """
    if not selection.choices:
        return selection
    counts = np.array([c.counts for c in selection.choices])
    total = counts.sum(axis=0)
    need = np.broadcast_to(np.asarray(min_samples, dtype=np.float64), total.shape)
    satisfied = total >= need - 1e-9
    keep = np.ones(len(counts), bool)
    for i in np.argsort(np.minimum(counts, need).sum(axis=1), kind="stable"):
        rest = total - counts[i]
        if np.all(rest[satisfied] >= need[satisfied] - 1e-9) and np.all(counts[i][~satisfied] <= 0):
            keep[i], total = False, rest
    choices = [c for c, k in zip(selection.choices, keep, strict=True) if k]
    views_used = sorted({c.view for c in choices}, key=[c.view for c in choices].index)
    return Selection(choices, views_used, selection.hit_light_limit)


def _gain_floor(share_of_need: np.ndarray, most: np.ndarray) -> np.ndarray:
    """(R,) what a light must give a region to count for it: the smaller of ``share_of_need`` (R,) and
    BEST_SHARE of ``most`` (R,), at least MIN_GAIN (or all it lacks, :func:`_gives_a_share`)."""
    return np.maximum(MIN_GAIN, np.minimum(share_of_need, BEST_SHARE * most))


def _min_gain(need: np.ndarray) -> float:
    """What a light must add to be chosen: MIN_GAIN, or less when a region is short by less than that."""
    short = need[need > 0]
    return min(MIN_GAIN, float(short.min())) if len(short) else MIN_GAIN


def _gives_a_share(counts: np.ndarray, need: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """(Q,) bool: the lights with per-region ``counts`` (Q, R) that give some region still short (``need``
    (R,) > 0) its ``floor`` (R,, :func:`_gain_floor`) or all it lacks."""
    short = need > 0
    given = np.minimum(counts[:, short], need[short])  # (Q, S) what each light gives the short regions
    return np.any(given >= np.minimum(floor[short], need[short]) - 1e-9, axis=1)


def _worth(estimates: np.ndarray, need: np.ndarray, floor: np.ndarray, capped: bool) -> np.ndarray:
    """(Q,) each candidate's score, 0 where it gives no short region its share (:func:`_gives_a_share`)."""
    return np.where(_gives_a_share(estimates, need, floor), score(estimates, need, capped), 0.0)


def _best(estimates, exact, used, need, floor, capped, evaluate):
    """The (view, candidate) to accept among the open views, or None when no light is worth taking."""
    # each open view's scores (Q,), made once: an evaluation changes one candidate's row, and its score is
    # made again alone (a row's sum is the same alone as among all: numpy reduces each row in turn)
    worth = {v: _worth(estimates[v], need, floor, capped) for v in used}
    for _ in range(MAX_EVALUATIONS):
        best_exact, best_estimate = _top(worth, exact, used, need)
        if best_estimate is None or (
            best_exact is not None and best_exact[2] >= (1 - TOLERANCE) * best_estimate[2]
        ):
            return None if best_exact is None else best_exact[:2]
        v, q, _ = best_estimate
        estimates[v][q] = evaluate(v, q, need)
        exact[v][q] = True
        worth[v][q] = _worth(estimates[v][q : q + 1], need, floor, capped)[0]
    best_exact, _ = _top(worth, exact, used, need)
    return None if best_exact is None else best_exact[:2]


def _top(worth, exact, used, need):
    """Best (view, candidate, score) among exactly scored and among estimated candidates, from each open
    view's scores ``worth[v]`` (Q,) (None below the minimum gain)."""
    least = _min_gain(need)
    best: dict[bool, tuple[int, int, float] | None] = {True: None, False: None}
    for v in used:
        s = worth[v]
        for is_exact in (True, False):
            masked = np.where(exact[v] == is_exact, s, -np.inf)
            q = int(np.argmax(masked)) if len(masked) else -1
            held = best[is_exact]
            if q >= 0 and masked[q] >= least and (held is None or masked[q] > held[2]):
                best[is_exact] = (v, q, float(masked[q]))
    return best[True], best[False]
