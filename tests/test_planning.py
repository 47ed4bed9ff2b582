"""Planning: invariants checked with independent brute-force geometry, and the paper's 4.1 set-up."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import KDTree

from benchmarks.numerical import MIXED_THETA_C_DEG, PAPER_SETTINGS, paper_41_object
from hlr_lab.errors import InputError, PlanningError
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import azimuth_elevation, directions_with_spacing, rotation_z
from hlr_lab.object.mesh import load_mesh
from hlr_lab.object.raycast import RayCaster
from hlr_lab.object.segment import segment
from hlr_lab.planning.diffuse import COARSE_COUNT_FROM_PX, diffuse_counts
from hlr_lab.planning.geometry import light_sphere, mirror_highlights, placement
from hlr_lab.planning.greedy import BEST_SHARE, MIN_GAIN, NEED_SHARE, select_lights
from hlr_lab.planning.planner import (
    PlanResult,
    PlanSettings,
    _Candidates,
    _Clock,
    _Planner,
    auto_views,
    plan_lights,
)
from hlr_lab.planning.samples import sub_triangle_centroids


@pytest.fixture(scope="module")
def pebble_plan(placed_pebble, pebble_object, rig) -> tuple[PlanResult, RayCaster]:
    seg = segment(pebble_object.mesh)
    caster = RayCaster(placed_pebble)
    return plan_lights(placed_pebble, seg, rig, PlanSettings(), caster=caster), caster


def brute_force_counted(
    result: PlanResult, caster: RayCaster, light_index: int, rig, *, diffuse: bool = False
) -> np.ndarray:
    """Which samples a light really highlights (``diffuse``: lights outside their cones), from first
    principles and without the planner's shortcuts: rays cast the other way round, angles by arccos, no
    KD-tree, no pooling."""
    s, light, settings = result.samples, result.lights[light_index], result.settings
    cam = rig.camera.centre @ rotation_z(np.radians(light.turntable_deg))[:3, :3]  # into the turntable frame
    n, x = s.normal, s.point
    to_cam, to_light = cam - x, light.light_turntable - x
    view_angle = np.arccos(np.clip(np.einsum("ij,ij->i", n, to_cam) / np.linalg.norm(to_cam, axis=1), -1, 1))
    light_angle = np.arccos(
        np.clip(np.einsum("ij,ij->i", n, to_light) / np.linalg.norm(to_light, axis=1), -1, 1)
    )
    v = to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)
    mirror = 2 * np.einsum("ij,ij->i", n, v)[:, None] * n - v
    cone_angle = np.arccos(
        np.clip(np.einsum("ij,ij->i", mirror, to_light) / np.linalg.norm(to_light, axis=1), -1, 1)
    )
    limit = np.radians(settings.max_view_angle_deg)
    in_cone = cone_angle <= np.radians(settings.theta_c_deg)
    candidate = (view_angle <= limit) & (light_angle <= limit) & (~in_cone if diffuse else in_cone)
    idx = np.flatnonzero(candidate)

    def unobstructed(eye: np.ndarray, pts: np.ndarray) -> np.ndarray:  # cast from the eye toward the surface
        d = pts - eye
        dist = np.linalg.norm(d, axis=1)
        _, hit = caster.first_hit(np.broadcast_to(eye, pts.shape), d / dist[:, None])
        return hit >= dist - 1e-4 * caster.scale

    seen = unobstructed(cam, x[idx])
    lit = unobstructed(light.light_turntable, x[idx])
    return idx[seen & lit]


def test_every_counted_highlight_is_in_its_cone_visible_lit_and_reachable(pebble_plan, rig):
    result, caster = pebble_plan
    assert result.lights
    assert result.satisfied.all()
    assert not result.uncovered
    g = rig.gantry
    for i, light in enumerate(result.lights):
        truth = brute_force_counted(result, caster, i, rig)
        assert np.isin(light.counted, truth).all(), f"light {i} counts samples that are not highlights"
        w = light.expected.sum()
        missed = np.setdiff1d(truth, light.counted)
        cam = rig.camera.in_frame(rotation_z(np.radians(light.turntable_deg)))
        weights = cam.projected_area_px(result.samples.point, result.samples.normal, result.samples.area)
        assert weights[missed].sum() <= 0.01 * w  # complete but for samples on a ray-test knife edge
        assert weights[light.counted].sum() == pytest.approx(w)
        regions = np.bincount(
            result.samples.region[light.counted],
            weights=weights[light.counted],
            minlength=len(light.expected),
        )
        np.testing.assert_allclose(regions, light.expected)
        # reachable: joint limits, camera keep-out, above the table
        d = (light.light_world - result.sphere.centre) / result.sphere.radius
        az, el = azimuth_elevation(d)
        assert g.azimuth_limits[0] <= az <= g.azimuth_limits[1]
        assert g.elevation_limits[0] <= el <= g.elevation_limits[1]
        to_cam = rig.camera.centre - result.sphere.centre
        assert np.degrees(np.arccos(d @ to_cam / np.linalg.norm(to_cam))) >= np.degrees(g.camera_keepout)
        assert light.light_world[2] >= g.min_light_height
        assert np.linalg.norm(light.light_world - result.sphere.centre) == pytest.approx(result.sphere.radius)
        assert light.azimuth_deg == pytest.approx(np.degrees(az))


def test_light_positions_agree_between_frames(pebble_plan):
    result, _ = pebble_plan
    for light in result.lights:
        world = rotation_z(np.radians(light.turntable_deg))[:3, :3] @ light.light_turntable
        np.testing.assert_allclose(world, light.light_world, atol=1e-12)


def test_a_region_hidden_from_the_first_view_gets_another_view(
    pebble_plan, placed_pebble, pebble_object, rig
):
    result, _ = pebble_plan
    assert (
        len({light.turntable_deg for light in result.lights}) >= 2
    )  # green faces away from the camera at 0°
    seg = segment(pebble_object.mesh)
    one_view = plan_lights(placed_pebble, seg, rig, PlanSettings(views_deg=[0.0]))
    hidden = [r for r, why in one_view.uncovered.items() if why.startswith("not visible")]
    assert hidden
    assert all(not one_view.satisfied[r] for r in hidden)
    assert {light.turntable_deg for light in one_view.lights} == {0.0}


def test_unreachable_highlights_are_reported_and_really_unreachable(placed_pebble, pebble_object, rig):
    # a gantry that can only light from high above: the sides' highlights are out of reach
    high = replace(rig, gantry=replace(rig.gantry, elevation_limits=(np.radians(70), np.radians(80))))
    seg = segment(pebble_object.mesh)
    settings = PlanSettings(count="vertices", views_deg=[0.0], spacing_deg=1.0, compare_criteria=False)
    result = plan_lights(placed_pebble, seg, high, settings)
    unreachable = [r for r, why in result.uncovered.items() if why.startswith("highlight unreachable")]
    assert unreachable
    # brute force over every reachable candidate: no light puts a counted highlight on those regions
    sphere = light_sphere(high.gantry, placed_pebble.vertices, None)
    from hlr_lab.geometry.sphere import directions_with_spacing

    d = directions_with_spacing(1.0)
    pos = sphere.centre + sphere.radius * d
    pos = pos[sphere.reachable(pos, high.camera)]
    v = placed_pebble.vertices
    members = np.isin(seg.vertex_labels, unreachable)
    h = mirror_highlights(
        v[members], placed_pebble.vertex_normals[members], high.camera.centre, sphere.centre, sphere.radius
    )
    to = pos[None, :, :] - h.point[:, None, :]
    cos = np.einsum("kqd,kd->kq", to, h.mirror) / np.linalg.norm(to, axis=2)
    assert (cos < np.cos(np.radians(settings.theta_c_deg))).all()


def test_diffuse_only_samples_are_the_lit_seen_samples_outside_the_cone(pebble_plan, rig):
    """Each light's diffuse-only samples per region against first principles; highlight and diffuse-only
    samples of a light never overlap."""
    result, caster = pebble_plan
    for i, light in enumerate(result.lights):
        truth = brute_force_counted(result, caster, i, rig, diffuse=True)
        assert not np.isin(light.counted, truth).any()
        cam = rig.camera.in_frame(rotation_z(np.radians(light.turntable_deg)))
        weights = cam.projected_area_px(result.samples.point, result.samples.normal, result.samples.area)
        expected = np.bincount(
            result.samples.region[truth], weights=weights[truth], minlength=len(light.diffuse)
        )
        # the same but for samples on a ray test's knife edge (shadow and view rays cast the other way);
        # a region given COARSE_COUNT_FROM_PX or more is counted on the estimates' samples, within 2 %
        fine = light.diffuse < COARSE_COUNT_FROM_PX
        np.testing.assert_allclose(light.diffuse[fine], expected[fine], rtol=0.01, atol=2.0)
        np.testing.assert_allclose(light.diffuse[~fine], expected[~fine], rtol=0.02)


def test_diffuse_counts_are_exact_where_they_can_decide_a_light(placed_pebble, pebble_object, rig):
    """A light's diffuse-only count of a region is the fine samples' count where the estimates' samples give
    it fewer than max(COARSE_COUNT_FROM_PX, 2 --min-diffuse), the estimates' samples' count above that."""
    seg = segment(pebble_object.mesh)
    settings = PlanSettings(views_deg=[0.0], min_diffuse=300.0)
    planner = _Planner(placed_pebble, seg, rig, settings, None, _Clock())  # the plan's own two samplings
    fine, coarse = planner.view_samples(0), planner.coarse_view_samples(0)
    assert coarse is not fine
    kwargs = dict(theta_c=planner.theta_c, max_light_angle=planner.max_light_angle, shadows=True)
    below = above = 0
    for d in directions_with_spacing(30.0)[::3]:
        light = fine.light_position(d)
        got = planner.diffuse(0, light)
        on_fine = diffuse_counts(fine, planner.caster, light, **kwargs)
        on_coarse = diffuse_counts(coarse, planner.caster, light, **kwargs)
        exact = on_coarse < 600.0  # 2 × --min-diffuse
        np.testing.assert_array_equal(got[exact], on_fine[exact])
        np.testing.assert_array_equal(got[~exact], on_coarse[~exact])
        below, above = below + int(exact.sum()), above + int((~exact).sum())
    assert below  # both ways were exercised
    assert above


@pytest.mark.parametrize("gather", [None, 0.4])
def test_a_candidate_cell_is_the_dense_points_nearest_to_it(placed_pebble, rig, gather):
    """A coarse candidate's cell, found near it, is every reachable dense point whose nearest reachable
    coarse point it is; also when the cells reach past where they are looked for (the whole grid then)."""
    sphere = light_sphere(rig.gantry, placed_pebble.vertices, None)
    cands = _Candidates(sphere, rig, 0.5, 5.0 / 3)
    if gather is not None:  # look within 0.4 coarse spacings: most cells reach past 3/4 of that
        cands._gather = gather * np.radians(5.0 / 3)
    owner = KDTree(cands.coarse).query(cands.fine)[1]  # every dense point's nearest, the whole grid's
    for q in range(0, len(cands.coarse), 13):
        np.testing.assert_array_equal(cands.cell(q), np.flatnonzero(owner == q))
    assert (cands._cells is not None) == (gather is not None)


def test_regions_short_of_diffuse_samples_get_lights_of_their_own_and_say_so(
    placed_pebble, pebble_object, rig
):
    """Asked for more diffuse-only samples than the highlight lights give, the planner adds lights marked
    "diffuse", each adding some, up to --max-lights; a region still short says why (exit 3 in plan)."""
    seg = segment(pebble_object.mesh)
    base = PlanSettings(views_deg=[0.0, 180.0], spacing_deg=1.0, compare_criteria=False, optimum_budget_s=0)
    plain = plan_lights(placed_pebble, seg, rig, base)
    need = float(plain.diffuse.max() * 3)
    asked = plan_lights(
        placed_pebble, seg, rig, replace(base, min_diffuse=need, max_lights=len(plain.lights) + 3)
    )
    added = [light for light in asked.lights if light.purpose == "diffuse"]
    assert added
    assert len(asked.lights) <= len(plain.lights) + 3
    assert all(light.diffuse.sum() > 0 for light in added)
    assert (asked.diffuse >= plain.diffuse - 1e-9).all()
    short = np.flatnonzero(asked.diffuse < need)
    assert len(short)
    for r in short:
        assert "diffuse-only" in asked.uncovered[int(r)]
        assert not asked.satisfied[r]
    none = plan_lights(placed_pebble, seg, rig, replace(base, min_diffuse=0))
    assert all(light.purpose == "highlights" for light in none.lights)


def test_exact_counts_match_brute_force_at_wide_cones(placed_pebble, pebble_object, rig):
    """The KD-tree shortcut of exact_counts finds every sample whose cone holds the light (θc = 20°)."""
    seg = segment(pebble_object.mesh)
    settings = PlanSettings(
        theta_c_deg=20.0, views_deg=[0.0], compare_criteria=False, min_samples=5000, max_lights=3
    )
    result = plan_lights(placed_pebble, seg, rig, settings)
    caster = RayCaster(placed_pebble)
    assert result.lights
    for i, light in enumerate(result.lights):
        truth = brute_force_counted(result, caster, i, rig)
        assert np.isin(light.counted, truth).all()
        assert len(np.setdiff1d(truth, light.counted)) <= 0.01 * len(truth)


def test_capped_criterion_and_the_plain_count_are_both_reported(pebble_plan):
    result, _ = pebble_plan
    assert set(result.lights_by_criterion) == {"capped", "plain"}
    assert len(result.lights) <= min(result.lights_by_criterion.values())  # the fewest of them, or fewer
    assert result.optimum.lower_bound <= len(result.lights)


def test_greedy_caps_what_a_region_needs():
    # candidate 0 gives region 0 a lot; candidate 1 gives both regions what they need
    bounds = np.array([[500.0, 0.0], [60.0, 60.0], [0.0, 55.0]])
    evaluate = lambda v, q, need: bounds[q]  # noqa: E731 - exact = estimate here
    capped = select_lights(lambda v: bounds, 1, evaluate, np.array([50.0, 50.0]), capped=True, max_lights=5)
    plain = select_lights(lambda v: bounds, 1, evaluate, np.array([50.0, 50.0]), capped=False, max_lights=5)
    assert [c.candidate for c in capped.choices] == [1]
    assert [c.candidate for c in plain.choices] == [0, 1]


def test_greedy_never_accepts_an_overestimated_light():
    estimates = np.array([[100.0], [90.0]])
    exact = np.array([[10.0], [80.0]])  # candidate 0 looked best but is mostly shadowed
    sel = select_lights(
        lambda v: estimates, 1, lambda v, q, need: exact[q], np.array([50.0]), capped=False, max_lights=1
    )
    assert sel.choices[0].candidate == 1
    assert sel.choices[0].counts[0] == 80.0


def test_a_light_giving_a_region_a_few_of_the_hundreds_it_needs_is_not_taken():
    """The chase along a border: once the good lights (90 samples each) are used, lights adding 3 to a
    region that needs 450 (below both NEED_SHARE of its need and BEST_SHARE of its best light's) are left,
    and the region stays short; a light that finishes a region is taken however little it adds; where a
    region needs few samples, or no light gives it many (vertex counts), a sample is worth a light."""
    few = np.array([[90.0, 0.0], [80.0, 0.0]] + [[3.0, 0.0]] * 40)
    evaluate = lambda v, q, need: few[q]  # noqa: E731 - exact = estimate here
    sel = select_lights(lambda v: few, 1, evaluate, np.array([450.0, 0.0]), capped=True, max_lights=64)
    assert [c.candidate for c in sel.choices] == [0, 1]
    assert not sel.hit_light_limit
    assert min(NEED_SHARE * 450, BEST_SHARE * 90) > 3 >= MIN_GAIN
    finishing = select_lights(lambda v: few, 1, evaluate, np.array([173.0, 0.0]), capped=True, max_lights=64)
    assert [c.candidate for c in finishing.choices] == [0, 1, 2]
    # the lights photographed before the plan count: 3 is below a tenth of a pilot's 90, and 2 % of 540
    rest = few[2:]
    sel = select_lights(lambda v: rest, 1, lambda v, q, need: rest[q], np.array([450.0, 0.0]), capped=True,
                        max_lights=64, photographed=np.array([[90.0, 0.0]]))  # fmt: skip
    assert sel.choices == []
    for need, counts in (
        (50.0, [[20.0, 0.0]] + [[1.0, 0.0]] * 30),
        (400.0, [[5.0, 0.0]] * 8 + [[1.0, 0.0]] * 8),
    ):
        c = np.array(counts)
        sel = select_lights(lambda v, c=c: c, 1, lambda v, q, n, c=c: c[q], np.array([need, 0.0]), capped=True,
                            max_lights=64)  # fmt: skip
        assert len(sel.choices) == len(c)  # a sample is worth a light here


def test_auto_views_start_at_zero_and_respect_limits():
    assert auto_views((-180, 180), 90) == [0.0, 90.0, -90.0, -180.0]
    assert auto_views((0, 100), 45) == [0.0, 45.0, 90.0]


def test_sub_triangles_tile_the_face():
    for level in (1, 2, 5):
        b = sub_triangle_centroids(level)
        assert b.shape == (level * level, 3)
        np.testing.assert_allclose(b.sum(axis=1), 1.0)
        np.testing.assert_allclose(
            b.mean(axis=0), 1 / 3
        )  # equal-area pieces: their centroids average to the centroid
        assert len(np.unique(np.round(b, 9), axis=0)) == level * level


def test_sphere_smaller_than_the_object_is_refused(placed_pebble, rig):
    tiny = replace(rig.gantry, arm_radius=0.05)
    with pytest.raises(PlanningError, match="larger arm"):
        light_sphere(tiny, placed_pebble.vertices, None)
    with pytest.raises(InputError, match="--sphere-scale"):
        light_sphere(rig.gantry, placed_pebble.vertices, 0.8)


def test_placement_rests_the_object_on_the_table_axis(pebble_object):
    m = placement(pebble_object.mesh, up="-y", scale=2.0)
    v = pebble_object.mesh.transformed(m).vertices
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose((v.min(axis=0) + v.max(axis=0))[:2] / 2, 0.0, atol=1e-12)
    extent = np.ptp(pebble_object.mesh.vertices, axis=0)
    assert np.ptp(v[:, 2]) == pytest.approx(2.0 * extent[1])  # mesh −y now points up, scaled 2×
    with pytest.raises(InputError, match="up axis"):
        placement(pebble_object.mesh, up="w")


def test_paper_41_bunny_eight_regions(bunny_path, rig, record_property):
    """The paper's 4.1: bunny, 8 regions in view, sphere 2× the bounding sphere, θc = 5°, one view."""
    painted = paper_41_object(load_mesh(bunny_path), rig, up="y")
    seg = segment(painted)
    assert seg.n_regions == 8
    # The paper reports 2 lights, the first highlighting 7 of the 8 regions. Counting pixels we measured
    # 3 (first light: 7 regions); counting vertices 13, since a 5° cone holds only 30–80 bunny vertices
    # (measured) against M = 50 per region. The bounds leave room for small numerical changes only.
    for count, most_lights in (("pixels", 4), ("vertices", 15)):
        result = plan_lights(painted, seg, rig, replace(PAPER_SETTINGS, count=count))
        assert result.sphere.source == "scale"
        assert result.satisfied.all(), result.uncovered
        record_property(f"paper41_lights_{count}", result.lights_by_criterion)
        assert 1 <= len(result.lights) <= most_lights
        assert result.lights_by_criterion["capped"] <= result.lights_by_criterion["plain"]
        if count == "pixels":
            assert (result.lights[0].expected > 0).sum() >= 6  # the first light serves most regions at once


def test_spot_plan(spot_paths, rig):
    obj, png = spot_paths
    mesh = load_mesh(obj, png)
    seg = segment(mesh)
    placed = mesh.transformed(placement(mesh, up="y", scale=0.08))
    result = plan_lights(placed, seg, rig, PlanSettings(view_step_deg=90))
    assert result.lights
    for r in np.flatnonzero(~result.satisfied):
        assert int(r) in result.uncovered  # every short region says why
    assert result.satisfied.sum() >= 4


def test_camera_model_used_by_the_plan_is_the_rig_camera(rig):
    assert isinstance(rig.camera, Camera)
    assert rig.camera.width == 1280
    assert rig.camera.height == 960


def test_a_y_up_mesh_is_stood_up_by_the_least_rotation():
    """--up y turns the mesh about x only (y → z, z → −y): the object keeps its x on the plate. (trimesh's
    align_vectors would add a quarter turn about z, and move every y-up plan's object on the plate.)"""
    from hlr_lab.planning.geometry import _rotation_taking

    rot = _rotation_taking(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(rot, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_each_regions_estimates_pool_on_its_own_cone_as_near_the_exact_counts_as_a_plan_with_one_cone(
    placed_pebble, pebble_object, rig
):
    """An adaptive re-plan's cones (each region's measured θc: 30°, 12°, 2.6° and 4° on the pebble's
    regions) pool each region's samples on a grid of its own θc/2, as a plan with one θc pools all of
    them; the wide lobes pooled on the narrowest's grid took 38.5 s of ``hlr-lab bench plan``'s mixed
    case, 3.0 s now (a speed the bench prints). Each region's best candidates by estimate, counted exactly:
    the estimates stay within what one cone's give (measured 1.11–1.35 × the exact counts here, 1.09–1.27
    with one 5° cone; high at a peak, where a pool's disc holds each member's whole cone)."""
    seg = segment(pebble_object.mesh)
    settings = PlanSettings(region_theta_c_deg=MIXED_THETA_C_DEG, min_samples=250)
    planner = _Planner(placed_pebble, seg, rig, settings, None, _Clock())
    estimates = planner.estimates_of(0)  # (Q, R)
    for region in range(seg.n_regions):
        if estimates[:, region].max() == 0:  # region 2: its narrow lobe seen in no candidate of this view
            continue
        best = np.argsort(-estimates[:, region], kind="stable")[:8]
        only = np.eye(seg.n_regions)[region] * 1e9  # the exact count asked for this region alone
        exact = np.array([planner.evaluate(0, int(q), only, True)[region] for q in best])
        ratio = estimates[best, region] / exact
        assert np.all((ratio > 0.9) & (ratio < 1.5)), (region, ratio)
