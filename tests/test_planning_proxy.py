"""A scan planned on its ray proxy: the vertices clustered on a pixel grid, the mesh they span, and a plan
whose claims hold when its lights are counted on the scan itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from hlr_lab.object import mesh as mesh_module
from hlr_lab.object.clusters import cluster_vertices, clustered_mesh
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.procedural import paint_patches, pebble
from hlr_lab.object.raycast import RayCaster
from hlr_lab.object.segment import Segmentation, segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, TakenLight, plan_lights
from hlr_lab.planning.proxy import ray_proxy
from hlr_lab.rig.file import sim_rig
from tests.test_planning_samples import thin_plate


def test_the_clustered_mesh_keeps_the_surface_its_sides_and_no_degenerate_or_repeated_face():
    """The 1 mm plate clustered in 5 mm cells: far fewer vertices, every face spans three different ones
    and none repeats; the area (top, bottom and rim) within 3 % of the plate's; a ray straight down meets
    the top within the plate's thickness, and one straight up the bottom (the sides were never merged)."""
    mesh = thin_plate()
    seg = segment(mesh)
    clusters = cluster_vertices(
        mesh.vertices, mesh.vertex_normals, mesh.vertex_areas, seg.vertex_labels, 0.005
    )
    proxy, kept = clustered_mesh(mesh, clusters)
    assert len(proxy.vertices) < len(mesh.vertices) / 10
    f = proxy.faces
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert len(np.unique(np.sort(f, axis=1), axis=0)) == len(f)
    assert np.array_equal(clusters.group[mesh.faces[kept]], f)
    assert proxy.face_areas.sum() == pytest.approx(mesh.face_areas.sum(), rel=0.03)
    # the mean normals the proxy carries, not the ones its faces would give
    np.testing.assert_array_equal(proxy.vertex_normals, clusters.normal)
    caster = RayCaster(proxy)
    xy = np.random.default_rng(1).uniform(-0.04, 0.04, size=(200, 2))
    down = caster.first_hit(np.column_stack([xy, np.full(200, 0.1)]), np.tile([0.0, 0.0, -1.0], (200, 1)))[1]
    up = caster.first_hit(np.column_stack([xy, np.full(200, -0.1)]), np.tile([0.0, 0.0, 1.0], (200, 1)))[1]
    np.testing.assert_allclose(0.1 - down, 0.0005, atol=0.0005)  # the top, at z = +0.5 mm
    np.testing.assert_allclose(up - 0.1, -0.0005, atol=0.0005)  # the bottom, at z = −0.5 mm


def test_given_normals_are_the_vertex_normals_and_turn_with_the_mesh():
    """A mesh given its normals keeps them, and a rotation, a scale and a mirror turn them as they turn
    the faces' own normals (outward stays outward)."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    v, f = np.asarray(sphere.vertices, np.float64), np.asarray(sphere.faces, np.int64)
    outward = v / np.linalg.norm(v, axis=1, keepdims=True)
    given = ColouredMesh(v, f, normals=outward)
    assert given.vertex_normals is outward
    mirror = np.diag([2.0, -2.0, 2.0, 1.0])  # scaled and mirrored
    turn = trimesh.transformations.rotation_matrix(0.7, [1.0, 2.0, 3.0]) @ mirror
    moved = given.transformed(turn)
    computed = ColouredMesh(v, f).transformed(turn).vertex_normals
    assert np.einsum("ij,ij->i", moved.vertex_normals, computed).min() > 0.99


def test_vertex_normals_and_areas_by_blocks_of_faces_are_those_of_all_faces_at_once(monkeypatch):
    """A scan's per-face work runs a block of faces at a time: with blocks of 100 faces, the vertex normals
    and face areas are those of one cross product over all faces (to rounding)."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    v = np.asarray(sphere.vertices, np.float64) * np.random.default_rng(2).uniform(
        0.8, 1.2, (len(sphere.vertices), 1)
    )
    f = np.asarray(sphere.faces, np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    acc = np.zeros_like(v)
    np.add.at(acc, f.ravel(), np.repeat(cross, 3, axis=0))
    monkeypatch.setattr(mesh_module, "_FACE_BLOCK", 100)
    mesh = ColouredMesh(v, f)
    np.testing.assert_allclose(
        mesh.vertex_normals, acc / np.linalg.norm(acc, axis=1, keepdims=True), atol=1e-12
    )
    np.testing.assert_allclose(mesh.face_areas, np.linalg.norm(cross, axis=1) / 2, rtol=1e-12)
    np.testing.assert_allclose(
        mesh.face_normals, cross / np.linalg.norm(cross, axis=1, keepdims=True), atol=1e-12
    )


def _scanned_pebble() -> tuple[ColouredMesh, Segmentation]:
    """builtin:pebble at 0.3× in 4 patches, split twice at its edges' midpoints: 164 k vertices of ~0.25 px
    each on the simulated rig's camera (the pebble's own are 45 px), the same surface."""
    stone = pebble().mesh
    v, f = stone.vertices, stone.faces
    for _ in range(2):
        v, f = trimesh.remesh.subdivide(v, f)[:2]
    fine = ColouredMesh(np.asarray(v, np.float64), np.asarray(f, np.int64))
    placed = fine.transformed(placement(fine, scale=0.3))
    painted = paint_patches(placed, 4).mesh
    return painted, segment(painted)


def test_a_scan_is_planned_on_its_proxy_and_its_claims_hold_on_the_scan_itself():
    """A mesh far finer than the image is planned on a ray proxy of 1 px cells, several times fewer
    vertices; the plan's lights counted exactly on the scan itself give every region what the plan
    claims within 25 % (measured: 3–13 % over; its samples and its rays are the proxy's, so what moves a
    count is only the proxy's 1 px of geometry at a cone's edge), in total within 12 % (measured 6 %).
    A mesh whose vertices are pixels or more is planned as it is."""
    rig = sim_rig()
    scan, seg = _scanned_pebble()
    settings = PlanSettings(views_deg=[0.0], min_diffuse=0, compare_criteria=False, optimum_budget_s=0)
    result = plan_lights(scan, seg, rig, settings)
    assert result.proxy is not None
    assert len(result.proxy.mesh.vertices) < len(scan.vertices) / 2
    assert result.satisfied.sum() >= 3  # one of the four patches faces away from the one view
    taken = [TakenLight(light.turntable_deg, light.light_world) for light in result.lights]
    counted = plan_lights(scan, seg, rig, settings, caster=RayCaster(scan), taken=taken)
    on_scan = np.sum([light.expected for light in counted.lights[: len(taken)]], axis=0)
    claims = result.coverage
    np.testing.assert_allclose(claims, on_scan, rtol=0.25)
    assert claims.sum() == pytest.approx(on_scan.sum(), rel=0.12)
    from hlr_lab.display.plan import plan_summary

    said = "\n".join(plan_summary(result, Path("plan.json")))
    assert f"of its {len(scan.vertices):,} vertices" in said  # plan says what it planned on
    stone = pebble().mesh
    assert ray_proxy(stone.transformed(placement(stone)), segment(stone), rig.camera) is None


def test_bench_plan_prints_the_proxy_and_the_claims_checked_on_the_mesh():
    """``bench plan``'s lines for a scan: the proxy's size, and claim / count per region on the mesh itself
    and on the copy it was split from, with the worst as a signed per cent; the registration with it."""
    from benchmarks.numerical import PlanFigures, ScanRegistration, plan_report

    figures = PlanFigures(
        "bunny subdivided", 10_000_000, 3, 2, 4, 2, 0, 12.4, {"proxy": 8.2}, 1219.0, 1802.0, 20.9, 2739.0,
        proxy_vertices=1_078_893,
        gbuffer_s=9.5,
        rss_peak_gbuffer_mb=3100.0,
        claims_on_mesh=np.array([1.05, 0.96, 1.09]),
        claims_on_copy=np.array([14.47, 0.72, np.inf]),
        register=ScanRegistration(412.3, 3456.0, 0.0123, 0.0081, 14.1),
    )  # fmt: skip
    text = "\n".join(plan_report(figures))
    assert "ray proxy of 1,078,893 vertices" in text
    assert "on the mesh itself: per region 1.05, 0.96, 1.09; worst +9% where counted" in text
    assert "per region 14.47, 0.72, none counted; worst +1347% where counted" in text
    assert "segmenting it (not in the plan time): 20.90 s, peak RSS 2739 MB" in text
    assert "412.3 s, peak RSS 3456 MB; vertices 0.012 mm RMS off, rotation 0.008°" in text
    assert "(the mesh it was subdivided from: 14.1 s)" in text
    assert (
        "the fit's geometry on it (its own ray engine, one G-buffer of the simulated rig's camera): 9.50 s"
        in text
    )


def test_bench_plan_prints_the_paper_set_ups_plan_made_again_in_its_process():
    """The paper's set-up's compute is its plan made again where everything is loaded (the ≤ 0.3 s target's
    figure): its median and least over the runs, and counted in vertices as the paper counts, with and
    without the search for the fewest; a scan's case has neither."""
    from benchmarks.numerical import PlanFigures, VertexCountFigures, plan_report

    figures = PlanFigures(
        "bunny", 34_834, 8, 2, 5, 2, 0, 0.6, {"cones": 0.14}, 161.0, 268.0, 0.02, 161.0,
        warm_s=(0.52, 0.47, 0.49, 0.61, 0.48),
        vertex_count=VertexCountFigures(11, 11, True, 12, 1.42, 1.30, 0.17),
    )  # fmt: skip
    text = "\n".join(plan_report(figures))
    assert "planned again in the same process: median 0.49 s, least 0.47 s of 5" in text
    assert (
        "counted in vertices, as the paper counts: lights 11 (lower bound 11, proven; the greedy's 12); "
        "planned again: median 1.42 s, of which the search for the fewest 1.30 s; greedy and bound alone "
        "(--optimum-budget 0) 0.17 s"
    ) in text
    scan = PlanFigures("scan", 10_000_000, 8, 2, 4, 2, 0, 8.8, {}, 1303.0, 1875.0, 11.6, 2028.0)
    assert "planned again" not in "\n".join(plan_report(scan))
    assert "counted in vertices" not in "\n".join(plan_report(scan))


def test_bench_plans_scan_is_the_same_surface_watertight_with_the_vertices_asked():
    """``bench plan --large N``'s scan: exactly N vertices (whole midpoint rounds, then single edges split),
    the same area, no rim where the mesh had none (a T-junction's edges would be rims: outlines to the
    registration) and its faces wound as the mesh's."""
    from benchmarks.numerical import subdivided

    stone = pebble().mesh
    for count in (stone.vertices.shape[0] + 1, 50_000, 200_000):
        scan = subdivided(stone, count)
        assert len(scan.vertices) == count
        assert scan.face_areas.sum() == pytest.approx(stone.face_areas.sum(), rel=1e-12)
        assert len(scan.edge_faces()[2]) == 0
        assert scan.trimesh.is_winding_consistent
