"""The fewest lights: the set multicover's bound and integer programme against brute force, the pruning of
redundant lights, and plans that keep the fewest of the greedy's and the programme's."""

import math
from dataclasses import replace
from itertools import combinations

import numpy as np
import pytest

from benchmarks.numerical import (
    PAPER_SETTINGS,
    optimum_figures,
    optimum_objects,
    optimum_report,
    paper_41_object,
)
from hlr_lab.errors import InputError
from hlr_lab.object.mesh import load_mesh
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.greedy import Choice, Selection, prune
from hlr_lab.planning.optimum import minimum_cover
from hlr_lab.planning.planner import PlanSettings, plan_lights


def fewest_by_brute_force(counts: np.ndarray, target: np.ndarray) -> int:
    capped = np.minimum(counts, target)
    for k in range(1, len(counts) + 1):
        for subset in combinations(range(len(counts)), k):
            if np.all(capped[list(subset)].sum(axis=0) >= target - 1e-9):
                return k
    raise AssertionError("no cover")


def multicover(seed: int, n: int = 13, r: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Sparse random counts (most candidates light few regions, as highlights do) and a reachable target;
    with more regions (r > 4), sparser and more skewed."""
    rng = np.random.default_rng(seed)
    shape, scale, lit = (0.6, 20.0, 0.5) if r <= 4 else (0.5, 15.0, 0.3)
    counts = rng.gamma(shape, scale, size=(n, r)) * (rng.random((n, r)) < lit)
    target = np.minimum(50.0, np.minimum(counts, 50.0).sum(axis=0))
    return counts, target


@pytest.mark.parametrize("seed", range(12))
def test_the_bound_never_exceeds_the_fewest_and_the_programme_finds_it(seed):
    counts, target = multicover(seed)
    fewest = fewest_by_brute_force(counts, target)
    incumbent = len(counts)  # every candidate: a cover, and the worst one
    found = minimum_cover(counts, target, incumbent, budget_s=10.0)
    assert found.lp_value <= fewest + 1e-6
    assert found.lower_bound <= fewest
    got = incumbent if found.cover is None else len(found.cover)
    assert got == fewest
    assert found.proven
    assert found.lower_bound == fewest
    if found.cover is not None:  # a real cover of the true counts
        assert np.all(np.minimum(counts[found.cover], target).sum(axis=0) >= target - 1e-6)
        assert len(set(found.cover.tolist())) == len(found.cover)


@pytest.mark.parametrize("seed", range(6))
def test_the_programme_is_asked_for_no_more_lights_than_it_may_use(seed):
    """Each integer programme carries the row Σ x ≤ most (a cover must beat the incumbent: HiGHS prunes on
    it, 42 → 8 ms on the paper's bunny): with most the fewest it finds the fewest, with one less it proves
    that there is no cover at all (status 2), whatever the counts."""
    import time

    from hlr_lab.planning.optimum import _solve

    counts, target = multicover(seed)
    fewest = fewest_by_brute_force(counts, target)
    capped = np.minimum(counts, target)
    far = time.perf_counter() + 60.0
    found = _solve(capped, np.ones(len(capped)), target, far, most=fewest)
    assert (found.status, round(found.fun)) == (0, fewest)
    assert _solve(capped, np.ones(len(capped)), target, far, most=fewest - 1).status == 2


@pytest.mark.parametrize("n", [5, 64, 65, 3000])
def test_the_relaxation_seeds_with_the_largest_columns_as_a_whole_sort_orders_them(n):
    """The LP's seeding takes each region's largest columns without sorting them all: the order is a stable
    sort's (largest first, ties by index), every column tied with the last one kept, on counts with many
    ties (vertex counts are small integers)."""
    from hlr_lab.planning.optimum import _largest_first

    values = np.random.default_rng(n).integers(0, 7, n).astype(float)
    got = _largest_first(values, 64)
    whole = np.argsort(-values, kind="stable")
    np.testing.assert_array_equal(got, whole[: len(got)])
    assert len(got) >= min(n, 64)
    assert np.all(values[whole[len(got) :]] < values[got[-1]])


def hard_multicover() -> tuple[np.ndarray, np.ndarray, int]:
    """250 candidates, 14 regions: counts, target and the greedy's lights (12) — a cover HiGHS does not
    settle within a few nodes."""
    counts, target = multicover(5, n=250, r=14)
    need, lights = target.copy(), 0
    while (need > 1e-9).any():
        j = int(np.argmax(np.minimum(counts, need).sum(axis=1)))
        need, lights = np.maximum(need - counts[j], 0.0), lights + 1
    return counts, target, lights


def test_the_search_ends_on_its_work_limit_not_on_the_clock(monkeypatch):
    """A plan must not depend on the machine's speed: the integer programme stops at its node limit (here
    5, to end quickly) with the same outcome whatever the time budget beyond what it needs; only when the
    clock ends it first does the status say so."""
    import hlr_lab.planning.optimum as optimum

    monkeypatch.setattr(optimum, "MILP_NODE_LIMIT", 5)
    counts, target, greedy = hard_multicover()
    a = minimum_cover(counts, target, greedy, budget_s=60.0)
    b = minimum_cover(counts, target, greedy, budget_s=600.0)
    assert not a.proven
    assert "node limit" in a.status
    assert (a.lower_bound, a.status, a.proven) == (b.lower_bound, b.status, b.proven)
    assert (a.cover is None) == (b.cover is None)
    if a.cover is not None and b.cover is not None:
        assert sorted(a.cover.tolist()) == sorted(b.cover.tolist())
    guarded = minimum_cover(counts, target, greedy, budget_s=1e-3)
    assert guarded.status == optimum.TIME_GUARD
    assert not guarded.proven


def test_no_programme_is_solved_twice(monkeypatch):
    """The hard cover's 249 columns are few enough that the proof rounds them by nothing: that proof is the
    true counts' programme, and the search does not solve it again (3.5 s each with 2 000 nodes)."""
    import hlr_lab.planning.optimum as optimum

    monkeypatch.setattr(optimum, "MILP_NODE_LIMIT", 5)
    solved: list[np.ndarray] = []
    real_solve = optimum._solve

    def counting_solve(kinds, *args, **kwargs):
        solved.append(kinds)
        return real_solve(kinds, *args, **kwargs)

    monkeypatch.setattr(optimum, "_solve", counting_solve)
    counts, target, greedy = hard_multicover()
    found = minimum_cover(counts, target, greedy, budget_s=60.0)
    assert not found.proven
    assert len(solved) >= 2  # the deepening's, and the proof
    for i, a in enumerate(solved):
        assert not any(a.shape == b.shape and np.array_equal(a, b) for b in solved[i + 1 :])


def test_an_incumbent_at_the_bound_is_proven_without_the_programme():
    counts = np.array([[50.0, 0.0], [0.0, 50.0], [30.0, 30.0]])
    found = minimum_cover(counts, np.array([50.0, 50.0]), incumbent=2, budget_s=0.0)
    assert found.lp_value == pytest.approx(1.8)  # the third light whole and 0.4 of each of the others
    assert found.proven
    assert found.cover is None
    assert found.lower_bound == 2


def test_a_bound_of_two_met_by_a_pair_is_proven_without_an_integer_programme(monkeypatch):
    """With an LP bound of 2 (bench plan's paper set-up, pebble and Spot) a pair that covers is the fewest
    outright: it is found by the pair search (milliseconds), never by HiGHS's branch and bound (~90 ms a
    programme on the paper's bunny). Where no pair covers, the proof's programme still runs."""
    import hlr_lab.planning.optimum as optimum

    solved = []
    real_solve = optimum._solve

    def counting_solve(*args, **kwargs):
        solved.append(args)
        return real_solve(*args, **kwargs)

    monkeypatch.setattr(optimum, "_solve", counting_solve)
    # four regions; lights 2 and 3 each fill two of them, 0 and 1 give three of them 30: the bound is 2
    counts = np.array([[30.0, 30.0, 30.0, 0], [0, 30.0, 30.0, 30.0], [50.0, 50.0, 0, 0], [0, 0, 50.0, 50.0]])
    found = minimum_cover(counts, np.full(4, 50.0), incumbent=4, budget_s=5.0)
    assert (found.lower_bound, found.proven, found.status) == (2, True, "optimal")
    assert found.cover is not None
    assert sorted(found.cover.tolist()) == [2, 3]
    assert solved == []
    # a later round of the planner's exact checks: no pair among the lights counted exactly (0 and 1)
    # covers, so the pair is sought among all of them — still no programme
    exact = np.array([True, True, False, False])
    found = minimum_cover(counts, np.full(4, 50.0), incumbent=4, budget_s=5.0, pairs_among=exact)
    assert found.cover is not None
    assert sorted(found.cover.tolist()) == [2, 3]
    assert solved == []
    # three regions, each light filling one and giving the next half: the bound is 2, no pair covers
    counts = np.array([[50.0, 25.0, 0], [0, 50.0, 25.0], [25.0, 0, 50.0]])
    found = minimum_cover(counts, np.full(3, 50.0), incumbent=3, budget_s=5.0)
    assert found.cover is None
    assert (found.lower_bound, found.proven) == (3, True)
    assert fewest_by_brute_force(counts, np.full(3, 50.0)) == 3
    assert solved  # the rounded programme ran for the proof


def vertex_like_counts(n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """Counts of a few samples each (vertex counts: 0–12 per region, half the regions lit) and M = 50."""
    rng = np.random.default_rng(3)
    counts = (rng.integers(0, 13, size=(n, 8)) * (rng.random((n, 8)) < 0.5)).astype(float)
    return counts, np.full(8, 50.0)


def test_a_cover_at_the_bound_among_the_cheapest_columns_is_proven_without_a_large_programme(monkeypatch):
    """A cover of ⌈L⌉ lights is the fewest whatever columns it was found among: the search tries the 64 of
    least reduced cost first (milliseconds), where a programme over every column that could be in such a
    cover (899 kinds here) took 0.55 s, and over the 2 000 cheapest 0.4–0.55 s on the paper's bunny."""
    import hlr_lab.planning.optimum as optimum

    solved = []
    real_solve = optimum._solve

    def counting_solve(kinds, *args, **kwargs):
        solved.append(kinds)
        return real_solve(kinds, *args, **kwargs)

    monkeypatch.setattr(optimum, "_solve", counting_solve)
    counts, target = vertex_like_counts()
    found = minimum_cover(counts, target, incumbent=9, budget_s=30.0)  # 9: the greedy's lights
    assert found.cover is not None
    assert np.all(np.minimum(counts[found.cover], target).sum(axis=0) >= target - 1e-6)
    assert (found.lower_bound, len(found.cover), found.proven, found.status) == (7, 7, True, "optimal")
    assert found.lower_bound == math.ceil(found.lp_value)
    assert [len(k) for k in solved] == [64]
    assert np.isin(solved[0], np.arange(13)).all()  # the true counts, not rounded ones


@pytest.mark.parametrize("seed", [0, 1, 9])
def test_the_bound_is_raised_past_the_relaxation_one_light_at_a_time_on_the_columns_each_cover_can_use(
    seed, monkeypatch
):
    """Where no cover meets ⌈L⌉ (these seeds: the fewest is one or two above it), each k from ⌈L⌉ up is
    settled by a programme over the columns of reduced cost ≤ k − L alone — a cover of k lights uses no
    other — so the proof holds for every candidate."""
    import hlr_lab.planning.optimum as optimum

    solved = []
    real_solve = optimum._solve

    def counting_solve(kinds, *args, **kwargs):
        solved.append(len(kinds))
        return real_solve(kinds, *args, **kwargs)

    monkeypatch.setattr(optimum, "_solve", counting_solve)
    counts, target = multicover(seed)
    fewest = fewest_by_brute_force(counts, target)
    found = minimum_cover(counts, target, len(counts), budget_s=10.0)
    assert math.ceil(found.lp_value - 1e-6) < fewest
    assert (found.lower_bound, found.proven) == (fewest, True)
    assert found.cover is not None
    assert len(found.cover) == fewest
    # the first programme: over the columns a cover of ⌈L⌉ lights can use; its minimum above ⌈L⌉ raised
    # the bound, and its cover (or a later k's) met the bound so raised
    capped = np.minimum(counts, target)
    lp, reduced = optimum._lp_relaxation(capped, target)
    usable = reduced <= math.ceil(lp - 1e-6) - lp + 1e-6
    assert solved[0] == len(optimum._unique_rows(capped[usable])[0])
    assert solved == sorted(solved)  # each k's columns hold the last k's


def test_a_proof_the_rounding_has_made_too_weak_to_say_anything_is_not_run():
    """Vertex counts rounded up to 10 % of M merge into a few kinds whose LP relaxation is lights below the
    true one: the rounded programme could prove nothing new, and ``_may_raise`` says so (docs/planning.md)."""
    import hlr_lab.planning.optimum as optimum

    counts, target = vertex_like_counts()
    found = minimum_cover(counts, target, incumbent=9, budget_s=0.0)  # the LP bound only
    rounded = optimum._rounded_kinds(np.minimum(counts, target), target.max())
    assert rounded is not None
    kinds, _, multiplicity = rounded
    assert len(np.unique(kinds)) <= 4
    assert not optimum._may_raise(kinds, multiplicity, target, found.lower_bound)
    assert optimum._may_raise(kinds, multiplicity, target, 1)  # any relaxation above 0 lights


def test_identical_candidates_may_each_be_taken():
    """Three copies of one light, each giving a third of what the region needs: a cover takes all three
    (merged into one variable bounded by 3, the programme must not take the kind once)."""
    counts = np.array([[20.0], [20.0], [20.0], [5.0]])
    found = minimum_cover(counts, np.array([50.0]), incumbent=4, budget_s=5.0)
    assert found.cover is not None
    assert sorted(found.cover.tolist()) == [0, 1, 2]
    assert found.proven
    assert found.lower_bound == 3


def test_an_unreachable_target_is_refused():
    with pytest.raises(ValueError, match="reachable"):
        minimum_cover(np.array([[10.0, 0.0]]), np.array([50.0, 0.0]), incumbent=1, budget_s=1.0)


def test_prune_drops_a_light_the_others_make_redundant_but_not_one_a_short_region_needs():
    choices = [
        Choice(0, 0, np.array([30.0, 0.0, 0.0])),  # region 0's first 30: redundant once the next two come
        Choice(0, 1, np.array([50.0, 20.0, 0.0])),
        Choice(0, 2, np.array([0.0, 40.0, 10.0])),  # region 2 stays short: its 10 samples are kept
    ]
    pruned = prune(Selection(choices, [0], False), 50.0)
    assert [c.candidate for c in pruned.choices] == [1, 2]


def test_a_negative_or_endless_budget_is_refused():
    with pytest.raises(InputError, match="--optimum-budget"):
        PlanSettings(optimum_budget_s=-1.0)
    with pytest.raises(InputError, match="--optimum-budget"):
        PlanSettings(optimum_budget_s=float("nan"))


def test_spot_plan_uses_no_more_lights_than_either_greedy(spot_paths, rig):
    """Spot on the simulated rig: the capped greedy alone once used 6 lights where the plain count used 4
    (its estimates of the small regions were 3× too high on Spot's coarse vertices). The plan keeps the
    fewest, never more than either greedy, and its bound is below it."""
    obj, png = spot_paths
    mesh = load_mesh(obj, png)
    seg = segment(mesh)
    placed = mesh.transformed(placement(mesh, up="y", scale=0.08))
    capped = plan_lights(placed, seg, rig, PlanSettings(compare_criteria=False, optimum_budget_s=0))
    result = plan_lights(placed, seg, rig, PlanSettings())
    assert len(result.lights) <= min(result.lights_by_criterion.values())
    assert result.optimum.lower_bound <= len(result.lights)
    assert (result.satisfied >= capped.satisfied).all()  # the same regions covered, or more
    # measured: 2 lights, proven (bound 2); the greedy alone 3 (capped) and 4 (plain)
    assert len(result.lights) <= 3


def test_paper_41_bunny_needs_the_papers_two_lights(bunny_path, rig):
    """The paper's 4.1 reports 2 lights for its 8 regions; the greedy alone needs 3 (pixel count), the
    integer programme finds 2 and the LP bound (2.0) proves them the fewest."""
    painted = paper_41_object(load_mesh(bunny_path), rig, up="y")
    seg = segment(painted)
    result = plan_lights(painted, seg, rig, replace(PAPER_SETTINGS, optimum_budget_s=10.0))
    assert result.satisfied.all()
    assert result.optimum.lower_bound == 2
    assert len(result.lights) == 2
    assert result.optimum.proven


def test_paper_41_bunny_counted_in_vertices_gets_the_lights_its_proof_counts(bunny_path, rig):
    """Counted in vertices, as the paper counts, the greedy takes 12 lights once pruned and the search proves
    11 the fewest. The plan's lights are the proven cover's as counted exactly: when the greedy chose again
    among the cover's candidates, refining each for what was still needed at its step, a cover the deepening
    found came out at 12."""
    painted = paper_41_object(load_mesh(bunny_path), rig, up="y")
    seg = segment(painted)
    settings = replace(PAPER_SETTINGS, count="vertices", optimum_budget_s=30.0)
    result = plan_lights(painted, seg, rig, settings)
    greedy = plan_lights(painted, seg, rig, replace(settings, optimum_budget_s=0.0))
    assert result.satisfied.all()
    assert (result.optimum.lower_bound, result.optimum.proven) == (11, True)
    assert result.optimum.chosen_by == "integer programme"
    assert len(result.lights) == 11 < len(greedy.lights)
    assert np.all(result.coverage >= settings.min_samples)


def test_where_every_cover_the_estimates_promise_falls_short_a_cover_of_lights_counted_exactly_is_kept(rig):
    """The built-in pebble with M 250: in each of the 8 rounds the programme's 4-light cover of the
    estimates falls short when counted exactly, and the last one, completed by the greedy, takes 5 lights.
    Among the few hundred candidates the rounds counted exactly there is a cover of 4 that holds as found,
    and the LP bound (3.2) proves it the fewest."""
    mesh = pebble().mesh
    result = plan_lights(mesh, segment(mesh), rig, PlanSettings(min_samples=250))
    assert result.satisfied.all()
    assert (len(result.lights), result.optimum.lower_bound, result.optimum.proven) == (4, 4, True)
    assert result.optimum.chosen_by == "integer programme"


def test_bench_plan_reports_the_fewest_lights_of_a_case():
    cases = {case[0]: case for case in optimum_objects(None, "z", 1.0, None)}
    name, placed, settings = cases["builtin:pebble, sim rig"]
    line = optimum_report(optimum_figures(name, placed, settings))
    assert "builtin:pebble" in line
    assert "lower bound" in line
    assert "greedy capped/plain" in line


def test_the_pair_search_finds_a_covering_pair_exactly_when_one_exists():
    """The search for a cover of two compares only pairs whose totals can reach the need (kinds sorted by
    total): against every pair compared, on 300 seeded sets (some with ties, rounded to 5, and kinds that
    stand for two columns), it finds a pair exactly when one exists, and that pair covers."""
    from hlr_lab.planning.optimum import _covering_pair

    rng = np.random.default_rng(0)
    for case in range(300):
        k, r = int(rng.integers(1, 60)), int(rng.integers(1, 6))
        need = rng.uniform(10, 50, r)
        kinds = rng.gamma(0.7, 20, (k, r)) * (rng.random((k, r)) < 0.6)
        kinds = np.minimum(np.round(kinds / 5) * 5 if case % 3 == 0 else kinds, need)
        multiplicity = rng.integers(1, 3, k)
        every = np.all(kinds[:, None, :] + kinds[None, :, :] >= need - 1e-6, axis=2)
        np.fill_diagonal(every, np.diag(every) & (multiplicity >= 2))
        pair = _covering_pair(kinds, multiplicity, need, deadline=float("inf"))
        assert (pair is not None) == bool(every.any()), case
        if pair is not None:
            assert every[pair[0], pair[1]], case
