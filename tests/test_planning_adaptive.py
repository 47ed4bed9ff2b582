"""What an adaptive run plans with (no rig, no renderer): a θc per region, lights already taken counted,
and the pilot — the fewest of the plan's poses that show every region's highlight."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hlr_lab.adaptive.pilot import PILOT_SAMPLES, cut_to, pilot_poses
from hlr_lab.adaptive.precision import DARK_RD, MAX_FACTOR, RegionNeed, region_needs
from hlr_lab.adaptive.run import rest_of_plan
from hlr_lab.adaptive.theta_c import CONFIRMS_PLAN, confirmed, core_deg, region_cones, replan_cones
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import MaterialEntry, PixelCounts, materials_file
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import plan_object, plan_settings
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, TakenLight, plan_lights
from hlr_lab.rig.file import sim_rig

# vertices as the count unit, a coarse pebble and a coarse grid: each plan here takes about a second
FAST = PlanSettings(count="vertices", min_samples=8, min_diffuse=0, spacing_deg=1.0, views_deg=(0.0, 90.0))


@pytest.fixture(scope="module")
def placed():
    mesh = pebble(subdivisions=3).mesh
    return mesh.transformed(placement(mesh)), segment(mesh)


def test_each_region_counts_its_own_cone(placed):
    """A plan made with a θc per region counts each region's samples in that region's cone: each of its
    lights, counted again as a taken light under one θc for every region, gives the regions of that θc
    exactly what the plan said (the per-region counts are the uniform ones, region by region)."""
    mesh, seg = placed
    rig = sim_rig()
    thetas = (12.0, 3.0, 12.0, 3.0)
    result = plan_lights(mesh, seg, rig, replace(FAST, region_theta_c_deg=thetas))
    assert result.lights
    for theta in set(thetas):
        regions = [r for r, t in enumerate(thetas) if t == theta]
        for light in result.lights:
            again = plan_lights(mesh, seg, rig, replace(FAST, theta_c_deg=theta, max_lights=1),
                                taken=[TakenLight(light.turntable_deg, light.light_world)])  # fmt: skip
            recount = again.lights[0]
            assert recount.purpose == "taken"
            np.testing.assert_allclose(recount.expected[regions], light.expected[regions])
    wide = plan_lights(mesh, seg, rig, replace(FAST, theta_c_deg=12.0))
    narrow = plan_lights(mesh, seg, rig, replace(FAST, theta_c_deg=3.0))
    assert len(wide.lights) < len(result.lights) < len(narrow.lights)  # narrow cones need more lights


def test_lights_already_taken_are_counted_and_only_the_rest_is_planned(placed):
    """Given a plan's first light as taken, the plan starts with it (its counts exact, as before) and adds
    only what the regions still need, within --max-lights counting the taken one; given all of them, it
    adds nothing and says so."""
    mesh, seg = placed
    rig = sim_rig()
    first = plan_lights(mesh, seg, rig, FAST)
    assert len(first.lights) >= 2
    taken = [TakenLight(lt.turntable_deg, lt.light_world) for lt in first.lights]
    again = plan_lights(mesh, seg, rig, FAST, taken=taken[:1])
    assert again.lights[0].purpose == "taken"
    np.testing.assert_allclose(again.lights[0].expected, first.lights[0].expected)
    assert all(lt.purpose != "taken" for lt in again.lights[1:])
    assert again.satisfied.all()
    still = np.maximum(FAST.min_samples - first.lights[0].expected, 0)
    added = np.sum([lt.expected for lt in again.lights[1:]], axis=0)
    assert np.all(added[still > 0] > 0)  # every region still short was served
    limited = plan_lights(mesh, seg, rig, replace(FAST, max_lights=1), taken=taken[:1])
    assert [lt.purpose for lt in limited.lights] == ["taken"]  # --max-lights counts the taken ones too
    assert limited.uncovered
    assert all("--max-lights 1" in why for why in limited.uncovered.values())
    done = plan_lights(mesh, seg, rig, FAST, taken=taken)
    assert [lt.purpose for lt in done.lights] == ["taken"] * len(taken)
    assert done.optimum.status == "nothing to add"
    assert done.satisfied.all()


def test_a_theta_c_per_region_is_refused_unless_one_per_region_and_within_0_to_90(placed):
    mesh, seg = placed
    with pytest.raises(InputError, match="θc must lie in"):
        PlanSettings(region_theta_c_deg=(5.0, 95.0))
    with pytest.raises(InputError, match="2 regions' θc given for 4 regions"):
        plan_lights(mesh, seg, sim_rig(), replace(FAST, region_theta_c_deg=(5.0, 6.0)))


def test_the_plan_file_keeps_each_regions_theta_c_and_the_taken_poses(tmp_path):
    mesh = pebble(subdivisions=3).mesh
    settings = replace(FAST, region_theta_c_deg=(4.0, 9.0, 4.0, 9.0))
    plan, result = plan_object(mesh, segment(mesh), sim_rig(), settings, mesh_spec="builtin:pebble",
                               plan_folder=tmp_path)  # fmt: skip
    write_plan(tmp_path / "plan.json", plan)
    back = read_plan(tmp_path / "plan.json")
    assert back.parameters.region_theta_c_deg == {"0": 4.0, "1": 9.0, "2": 4.0, "3": 9.0}
    assert plan_settings(back).region_theta_c_deg == (4.0, 9.0, 4.0, 9.0)
    assert plan_settings(back).min_diffuse == 0  # the plan's own, not the default
    taken = [TakenLight(lt.turntable_deg, lt.light_world) for lt in result.lights[:1]]
    again, _ = plan_object(mesh, segment(mesh), sim_rig(), settings, mesh_spec="builtin:pebble",
                           plan_folder=tmp_path, taken=taken)  # fmt: skip
    assert again.poses[0].purpose == "taken"


def test_the_pilot_is_the_fewest_poses_showing_every_regions_highlight(tmp_path):
    """Poses crafted on a real plan: a pose shows a region at min(50, M) samples, or at the most any pose
    gives a region no pose gives that many; ties go to the plan's order; the pilot keeps the plan's order
    and its coverage is what its poses give."""
    mesh = pebble(subdivisions=3).mesh
    plan, _ = plan_object(mesh, segment(mesh), sim_rig(), replace(FAST, max_lights=4, min_samples=400),
                          mesh_spec="builtin:pebble", plan_folder=tmp_path)  # fmt: skip
    assert len(plan.poses) == 4
    assert PILOT_SAMPLES == 50
    crafted = [{"0": 60.0, "1": 10.0}, {"1": 55.0}, {"0": 70.0, "1": 20.0, "2": 3.0}, {"2": 1.0, "3": 80.0}]
    poses = [p.model_copy(update={"expected": e}) for p, e in zip(plan.poses, crafted, strict=True)]
    plan = plan.model_copy(update={"poses": poses})
    # region 2's best is pose 2's 3 samples; 0 and 2 from pose 2, 1 from pose 1, 3 from pose 3
    assert pilot_poses(plan) == [poses[1].id, poses[2].id, poses[3].id]
    cut = cut_to(plan, pilot_poses(plan))
    assert [p.id for p in cut.poses] == [poses[1].id, poses[2].id, poses[3].id]
    assert cut.coverage["1"].samples == 75.0
    small_m = plan.model_copy(update={"parameters": plan.parameters.model_copy(update={"min_samples": 15.0})})
    assert pilot_poses(small_m) == [poses[2].id, poses[3].id]  # M 15: pose 2's 20 samples show region 1 too
    assert pilot_poses(plan.model_copy(update={"poses": []})) == []


def test_a_plan_without_a_highlight_has_no_pilot_and_is_refused_before_anything_opens(tmp_path):
    from hlr_lab.adaptive.run import acquire_adaptive

    mesh = pebble(subdivisions=3).mesh
    plan, _ = plan_object(
        mesh, segment(mesh), sim_rig(), FAST, mesh_spec="builtin:pebble", plan_folder=tmp_path
    )
    dark = plan.model_copy(update={"poses": [p.model_copy(update={"expected": {}}) for p in plan.poses]})
    write_plan(tmp_path / "plan.json", dark)
    with pytest.raises(InputError, match="no pose of the plan puts a highlight on any region"):
        acquire_adaptive(tmp_path / "plan.json", sim_rig(), tmp_path / "session")
    assert not (tmp_path / "session").exists()


def test_a_re_plan_counts_each_lobes_core_unless_the_plan_s_cone_holds_it_and_a_plan_all_hold_is_kept(
    tmp_path,
):
    """A lobe's core is 2·arccos(2^(−1/n)) (n 400: 6.74°, n 1500: 3.48°, n 8 held at 30°, n 10⁶ at 1°).
    Against the plan's cones (5°, region 3's own 8°): a core no narrower than the plan's and within √2 of
    it (5–7.07°, 8–11.3°) keeps the plan's cone, any other is re-planned in its core, a region without a
    lobe measured in the plan's; every measured core so confirming the plan (at least one) makes the
    re-plan the rest of the plan as made, the pilot's poses first as "taken" under their own ids."""
    mesh = pebble(subdivisions=3).mesh
    settings = replace(FAST, max_lights=4, min_samples=400, region_theta_c_deg=(5.0, 5.0, 5.0, 8.0))
    plan, _ = plan_object(mesh, segment(mesh), sim_rig(), settings, mesh_spec="builtin:pebble",
                          plan_folder=tmp_path)  # fmt: skip
    regions = plan.object.regions
    ids = [r.id for r in regions]
    assert len(plan.poses) == 4
    assert core_deg(400) == pytest.approx(6.74, abs=0.005)
    assert core_deg(1500) == pytest.approx(3.48, abs=0.005)
    assert core_deg(8) == 30.0
    assert core_deg(1e6) == 1.0
    assert pytest.approx(2**0.5) == CONFIRMS_PLAN

    def cones(*n: float | None):
        lobe = dict(
            specular="measured", reason=None, rs=[0.25] * 3, rs_se=[0.001] * 3, n_se=1.0, theta_c_deg=6.0
        )
        entries = [_entry(r, **lobe, n=k) if k else _entry(r) for r, k in zip(regions, n, strict=True)]
        return region_cones(plan, materials_file(entries))

    # n 200's core: 9.54°, 1.19× region 3's 8°
    why = confirmed(plan, cones(400, 400, None, 200))
    assert why is not None
    assert "its core 1.19–1.35× the plan's θc" in why
    assert replan_cones(plan, cones(400, 400, None, 200)) == dict(zip(ids, (5.0, 5.0, 5.0, 8.0), strict=True))
    for other in (cones(1500, 400, 400, 200), cones(40, 400, 400, 200), cones(400, 400, 400, 100)):
        assert confirmed(plan, other) is None
    assert confirmed(plan, cones(None, None, None, None)) is None
    assert replan_cones(plan, cones(400, 1500, None, 200)) == dict(
        zip(ids, (5.0, pytest.approx(3.48, abs=0.005), 5.0, 8.0), strict=True)
    )
    assert replan_cones(plan, cones(40, 8, None, 1500)) == dict(
        zip(ids, (pytest.approx(21.27, abs=0.005), 30.0, 5.0, pytest.approx(3.48, abs=0.005)), strict=True)
    )
    pilot = cut_to(plan, [plan.poses[1].id, plan.poses[3].id])
    rest = rest_of_plan(plan, pilot)
    assert [p.id for p in rest.poses] == [plan.poses[i].id for i in (1, 3, 0, 2)]
    assert [p.purpose for p in rest.poses[:2]] == ["taken", "taken"]
    assert rest.poses[2:] == [plan.poses[0], plan.poses[2]]
    assert rest.coverage == plan.coverage
    assert rest.parameters == plan.parameters


def test_sample_factors_raise_each_regions_needs_to_that_many_times_what_the_taken_lights_give(
    placed, tmp_path
):
    """A precision asked (an adaptive run): region r needs max(M, fᵣ × its taken samples) highlight samples
    and likewise diffuse-only ones; the plan is made for those needs, records them per region (parameters and
    coverage), and its settings read back are the resolved needs, not the factors."""
    mesh, seg = placed
    rig = sim_rig()
    settings = replace(FAST, min_diffuse=10.0)
    first = plan_lights(mesh, seg, rig, settings)
    taken = [TakenLight(lt.turntable_deg, lt.light_world) for lt in first.lights[:1]]
    lit = int(np.argmax(first.lights[0].expected))  # the region the first light serves most
    spread = int(np.argmax(first.lights[0].diffuse))
    factors = tuple(
        3 * settings.min_samples / first.lights[0].expected[lit] if r == lit else 0.5 for r in range(4)
    )
    diffuse_factors = tuple(4.0 if r == spread else 0.0 for r in range(4))
    asked = replace(settings, highlight_factor=factors, diffuse_factor=diffuse_factors)
    result = plan_lights(mesh, seg, rig, asked, taken=taken)
    had, had_diffuse = result.lights[0].expected, result.lights[0].diffuse
    np.testing.assert_allclose(result.lights[0].expected, first.lights[0].expected)
    want = np.maximum(settings.min_samples, np.array(factors) * had)
    want_diffuse = np.maximum(settings.min_diffuse, np.array(diffuse_factors) * had_diffuse)
    assert result.settings.highlight_factor is None
    assert result.settings.diffuse_factor is None
    np.testing.assert_allclose(result.settings.needed(4), want)
    np.testing.assert_allclose(result.settings.diffuse_needed(4), want_diffuse)
    assert want[lit] == pytest.approx(3 * settings.min_samples)  # the factors asked more than M
    assert want_diffuse[spread] > settings.min_diffuse
    met = (result.coverage >= want - 1e-9) & (result.diffuse >= want_diffuse - 1e-9)
    np.testing.assert_array_equal(result.satisfied, met)
    assert np.all(result.satisfied | np.isin(np.arange(4), list(result.uncovered)))
    plan, _ = plan_object(
        mesh, seg, rig, asked, mesh_spec="builtin:pebble", plan_folder=tmp_path, taken=taken
    )
    write_plan(tmp_path / "plan.json", plan)
    back = read_plan(tmp_path / "plan.json")
    assert back.coverage[str(lit)].needed == pytest.approx(want[lit], rel=1e-6)
    assert back.coverage[str(spread)].diffuse_needed == pytest.approx(want_diffuse[spread], rel=1e-6)
    np.testing.assert_allclose(plan_settings(back).needed(4), want, rtol=1e-6)
    np.testing.assert_allclose(plan_settings(back).diffuse_needed(4), want_diffuse, rtol=1e-6)


def test_factors_of_at_most_one_against_every_light_taken_add_no_light(placed):
    """A later round whose fit finds every region at its precision (each factor ≤ 1) against all the lights
    taken so far, which met the plan's M: nothing is added, and that ends an adaptive run."""
    mesh, seg = placed
    rig = sim_rig()
    first = plan_lights(mesh, seg, rig, FAST)
    assert first.satisfied.all()
    taken = [TakenLight(lt.turntable_deg, lt.light_world) for lt in first.lights]
    met = replace(FAST, highlight_factor=(1.0, 0.9, 0.5, 0.0), diffuse_factor=(0.2, 1.0, 0.0, 0.7))
    again = plan_lights(mesh, seg, rig, met, taken=taken)
    assert len(again.lights) == len(taken)
    assert again.satisfied.all()


def test_per_region_needs_and_factors_are_refused_unless_one_per_region_and_not_negative(placed):
    mesh, seg = placed
    with pytest.raises(InputError, match="a region's M must be above 0"):
        PlanSettings(region_min_samples=(5.0, 0.0))
    with pytest.raises(InputError, match="must be 0 or more"):
        PlanSettings(highlight_factor=(1.0, -1.0))
    with pytest.raises(InputError, match="2 regions' M given for 4 regions"):
        plan_lights(mesh, seg, sim_rig(), replace(FAST, region_min_samples=(5.0, 6.0)))


def _entry(region, **kw) -> MaterialEntry:
    """A fitted region's entry: Rd only by default, ``kw`` replacing any field."""
    base = dict(id=region.id, color=region.color, vertices=10, rd=[0.5, 0.4, 0.01],
                rd_se=[0.0005, 0.0002, 0.0001], specular="unmeasured", reason="no highlight", theta_c_deg=35.0,
                pixels=PixelCounts(diffuse=1000, highlight=0), residual_rms=0.01, estimator="robust")  # fmt: skip
    return MaterialEntry(**(base | kw))


def test_each_regions_factor_is_its_pilots_largest_relative_error_over_the_precision_squared(tmp_path):
    """Rs's worst channel or n, whichever is less certain, sets the highlight factor; Rd's worst channel the
    diffuse one, a channel darker than DARK_RD held to p % of DARK_RD; a region whose highlight the pilot did
    not measure keeps the plan's highlight samples (factor 0, said why), one the pilot did not fit both; a
    factor over MAX_FACTOR is held there, and said."""
    mesh = pebble(subdivisions=3).mesh
    plan, _ = plan_object(
        mesh, segment(mesh), sim_rig(), FAST, mesh_spec="builtin:pebble", plan_folder=tmp_path
    )
    regions = plan.object.regions

    def entry(i: int, **kw) -> MaterialEntry:
        return _entry(regions[i], **kw)

    lobe = dict(specular="measured", reason=None, rs=[0.2, 0.25, 0.2], rs_se=[0.002, 0.001, 0.001], n=100.0)
    dim = lobe | dict(rs=[0.05, 0.05, 0.05], rs_se=[0.005, 0.001, 0.001])  # ±10 %: 400× asked, held at 16×
    pilot = materials_file(
        [entry(0, **lobe, n_se=0.5), entry(1, **lobe, n_se=2.0), entry(2), entry(3, **dim, n_se=1)]
    )
    needs = region_needs(plan, pilot, precision_pct=0.5)
    assert [n.region for n in needs] == [r.id for r in regions]
    # Rd: 0.0005/0.5 = 0.1 %, 0.0002/0.4 = 0.05 %, the dark channel 0.0001 of DARK_RD 0.02 = 0.5 %
    assert DARK_RD == 0.02
    assert all(n.diffuse_se_pct == pytest.approx(0.5) for n in needs[:3])
    assert needs[0].diffuse_factor == pytest.approx(1.0)
    assert needs[0].highlight_se_pct == pytest.approx(1.0)  # Rs's red channel 0.002/0.2 beats n's 0.5 %
    assert needs[0].highlight_factor == pytest.approx(4.0)
    assert needs[1].highlight_se_pct == pytest.approx(2.0)  # n's 2/100 beats Rs's 1 %
    assert needs[1].highlight_factor == pytest.approx(16.0)
    assert needs[2].highlight_factor == 0
    assert "highlight was not measured" in (needs[2].reason or "")
    assert needs[3].highlight_factor == MAX_FACTOR == 16
    assert needs[3].highlight_se_pct == pytest.approx(10.0)
    assert "at most 16× its samples asked, for about ±2.5 %" in (needs[3].reason or "")
    assert needs[0].reason is None
    held = lobe | dict(rs=[0.0, 0.25, 0.2], rs_se=[0.0002, 0.001, 0.001])  # a channel held at 0: of DARK_RD
    assert region_needs(plan, materials_file([entry(0, **held, n_se=0.5)]), 0.5)[
        0
    ].highlight_se_pct == pytest.approx(1.0)
    alone = region_needs(plan, materials_file([entry(0, **lobe, n_se=0.5)]), precision_pct=0.5)
    assert alone[3].highlight_factor == alone[3].diffuse_factor == 0
    assert "not fitted" in (alone[3].reason or "")


def test_a_later_round_asks_nothing_more_of_a_region_whose_error_stopped_following_its_pixels(tmp_path):
    """Round 2 against round 1's needs: a region whose highlight pixels grew 6× while its Rs standard error
    stayed ±1.2 % (a small region, counted by its few surface patches) is asked for no more samples,
    and says why; one whose error fell as the square-root law says (4× the pixels, half the error) is asked
    (s/p)² as in round 1; so is one whose pixels grew too little to tell (1.2×); Rd is judged alike, from
    the diffuse-only pixels."""
    mesh = pebble(subdivisions=3).mesh
    plan, _ = plan_object(
        mesh, segment(mesh), sim_rig(), FAST, mesh_spec="builtin:pebble", plan_folder=tmp_path
    )
    r = plan.object.regions
    lobe = dict(specular="measured", reason=None, rs=[0.2, 0.2, 0.2], n=100.0, n_se=0.1)
    at_1_2 = lobe | dict(rs_se=[0.0024] * 3)  # Rs ±1.2 %
    at_0_6 = lobe | dict(rs_se=[0.0012] * 3)  # ±0.6 %
    fitted = materials_file([
        _entry(r[0], **at_1_2, pixels=PixelCounts(diffuse=1000, highlight=600)),
        _entry(r[1], **at_0_6, pixels=PixelCounts(diffuse=1000, highlight=400)),
        _entry(r[2], **at_1_2, pixels=PixelCounts(diffuse=1000, highlight=120)),
        _entry(r[3], rd_se=[0.005, 0.002, 0.0001], pixels=PixelCounts(diffuse=6000, highlight=0)),
    ])  # fmt: skip
    previous = {
        r[0].id: RegionNeed(r[0].id, 16.0, 1.0, 1.22, 0.1, highlight_pixels=100, diffuse_pixels=1000),
        r[1].id: RegionNeed(r[1].id, 16.0, 1.0, 1.2, 0.1, highlight_pixels=100, diffuse_pixels=1000),
        r[2].id: RegionNeed(r[2].id, 16.0, 1.0, 1.25, 0.1, highlight_pixels=100, diffuse_pixels=1000),
        r[3].id: RegionNeed(r[3].id, 0.0, 16.0, None, 1.0, diffuse_pixels=1000),  # Rd ±1 % then, ±1 % now
    }
    needs = region_needs(plan, fitted, 0.5, previous)
    assert needs[0].highlight_factor == 0
    assert "went ±1.2 → ±1.2 % while its pixels grew 6.0×" in (needs[0].reason or "")
    assert "no more samples asked" in (needs[0].reason or "")
    assert needs[0].highlight_pixels == 600
    assert needs[1].highlight_factor == pytest.approx((0.6 / 0.5) ** 2)
    assert needs[1].reason is None
    assert needs[2].highlight_factor == pytest.approx((1.2 / 0.5) ** 2)
    assert needs[3].diffuse_factor == 0
    assert "its Rd standard error went ±1 → ±1 % while its pixels grew 6.0×" in (needs[3].reason or "")
    assert needs[3].highlight_factor == 0
    alone = region_needs(plan, fitted, 0.5)  # round 1: nothing to compare with
    assert alone[0].highlight_factor == pytest.approx((1.2 / 0.5) ** 2)
    assert alone[3].diffuse_factor == pytest.approx(4.0)


def test_the_adaptive_benchs_line_puts_each_runs_worst_error_in_standard_errors_beside_its_per_cent():
    """``bench adaptive`` prints, per case, the poses and worst errors of both runs, each run's worst
    |error| in its stated standard errors (whether a difference between the two is the noise), and each
    run's largest stated standard errors (the accuracy its photographs give)."""
    from benchmarks.adaptive import CaseFigures, RunFigures, case_line

    planned = RunFigures(5, {"rd": 0.02, "rs": 2.97, "n": 2.25}, [], {0: 5.0}, worst_z=1.96,
                         worst_se_pct={"rd": 0.011, "rs": 1.5, "n": 1.04})  # fmt: skip
    adaptive = RunFigures(12, {"rd": 0.01, "rs": 6.3, "n": 2.54}, [], {0: 2.6, 1: 4.7}, worst_z=2.71,
                          worst_se_pct={"rd": 0.02, "rs": 2.4, "n": 0.9})  # fmt: skip
    line = case_line(CaseFigures("narrow", "pebble", planned, adaptive, 3, 9, {}))
    assert line.split()[:9] == ["narrow", "pebble", "5", "0.02", "2.97", "2.25", "12", "(3+9)", "0.01"]
    assert "fitted θc 2.6–4.7°; worst |error|/σ 2.0 and 2.7" in line
    assert "largest stated σ Rd/Rs/n % 0.01/1.50/1.04 and 0.02/2.40/0.90" in line
