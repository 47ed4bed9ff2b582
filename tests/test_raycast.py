import numpy as np
import pytest
import trimesh

from hlr_lab.geometry.camera import Camera
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import RayCaster, visible_vertices

K = np.array([[700.0, 0.0, 161.0], [0.0, 700.0, 118.5], [0.0, 0.0, 1.0]])


def sphere_mesh(radius=0.05, subdivisions=6) -> ColouredMesh:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return ColouredMesh(np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64))


def test_gbuffer_of_a_sphere_matches_the_analytic_intersection():
    radius = 0.05
    caster = RayCaster(sphere_mesh(radius))
    cam = Camera.look_at(
        [0.02, -0.4, 0.1], [0, 0, 0], matrix=K, width=320, height=240, distortion=[-0.1, 0.02]
    )
    g = caster.gbuffer(cam)
    origins, dirs = cam.pixel_rays(cam.pixel_grid())
    b = np.einsum("ij,ij->i", dirs, origins)
    disc = b * b - (np.einsum("ij,ij->i", origins, origins) - radius**2)
    analytic_hit = disc > 0
    t = -b - np.sqrt(np.where(analytic_hit, disc, 0))
    hit = g.hit.ravel()
    # rays grazing the silhouette may hit or miss the polygonal sphere; everywhere else they agree
    inner = disc > (0.03 * radius) ** 2 * 4
    assert np.array_equal(hit[inner], analytic_hit[inner])
    assert not hit[~analytic_hit].any()
    p_true = origins + dirs * t[:, None]
    sel = hit & inner
    p = g.point.reshape(-1, 3)[sel]
    # the icosphere (level 6, 40 k faces) lies within 0.02 % of the radius of the true sphere
    assert np.abs(np.linalg.norm(p, axis=1) - radius).max() < 2e-4 * radius
    assert np.linalg.norm(p - p_true[sel], axis=1).max() < 2e-3 * radius
    normals = g.normal.reshape(-1, 3)[sel]
    assert (
        np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normals, p_true[sel] / radius), -1, 1))).max()
        < 0.5
    )
    depth = cam.to_camera(p_true[sel])[:, 2]
    np.testing.assert_allclose(g.depth.ravel()[sel], depth, atol=2e-3 * radius)
    assert np.isinf(g.depth.ravel()[~hit]).all()
    assert (g.face.ravel()[~hit] == -1).all()
    np.testing.assert_allclose(g.barycentric.reshape(-1, 3)[sel].sum(axis=1), 1.0, atol=1e-9)


def test_visible_vertices_of_a_convex_body_face_the_camera():
    mesh = sphere_mesh(subdivisions=4)
    caster = RayCaster(mesh)
    cam = Camera.look_at([0.0, -0.5, 0.0], [0, 0, 0], matrix=K, width=320, height=240)
    vis = visible_vertices(caster, cam, max_view_angle_deg=80)
    to_cam = cam.centre - mesh.vertices
    cos_view = np.einsum("ij,ij->i", mesh.vertex_normals, to_cam) / np.linalg.norm(to_cam, axis=1)
    # on a convex body, visibility is exactly the front-facing test (away from the 80° grazing limit)
    clear = np.abs(cos_view - np.cos(np.radians(80))) > 0.01
    assert np.array_equal(vis[clear], (cos_view > np.cos(np.radians(80)))[clear])


def test_occluded_vertices_are_not_visible():
    front = trimesh.creation.box(extents=[0.02, 0.02, 0.02])
    back = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    back.apply_translation([0, 0.1, 0])
    both = trimesh.util.concatenate([front, back])
    mesh = ColouredMesh(np.asarray(both.vertices), np.asarray(both.faces, dtype=np.int64))
    cam = Camera.look_at([0.0, -0.5, 0.0], [0, 0, 0], matrix=K, width=320, height=240)
    vis = visible_vertices(RayCaster(mesh), cam, max_view_angle_deg=89)
    sphere_idx = np.arange(len(front.vertices), len(mesh.vertices))
    ray_dir = mesh.vertices[sphere_idx] - cam.centre
    # a sphere vertex hides behind the box when its ray passes through the box's |x|,|z| ≤ 0.01 shadow at y = −0.01
    s = (-0.01 - cam.centre[1]) / ray_dir[:, 1]
    at_box = cam.centre + ray_dir * s[:, None]
    behind_box = (np.abs(at_box[:, 0]) < 0.0099) & (np.abs(at_box[:, 2]) < 0.0099)
    assert behind_box.any()
    assert not vis[sphere_idx][behind_box].any()


@pytest.mark.parametrize("light", [[0.0, 0.0, 0.5], [0.3, 0.0, 0.3]])
def test_shadow_of_a_box_on_a_plane(light):
    plate = trimesh.creation.box(extents=[0.4, 0.4, 0.01])
    plate.apply_translation([0, 0, -0.005])
    block = trimesh.creation.box(extents=[0.05, 0.05, 0.05])
    block.apply_translation([0, 0, 0.1])  # floating 7.5 cm above the plate
    both = trimesh.util.concatenate([plate, block])
    caster = RayCaster(ColouredMesh(np.asarray(both.vertices), np.asarray(both.faces, dtype=np.int64)))
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-0.15, 0.15, (4000, 2)), np.zeros(4000)])
    normals = np.tile([0.0, 0.0, 1.0], (4000, 1))
    light = np.asarray(light)
    shadowed = caster.shadowed(pts, normals, light)
    # analytic: the segment to the light crosses the block's horizontal slab between z = 0.075 and 0.125
    d = light - pts
    expected = np.zeros(len(pts), bool)
    for z in np.linspace(0.075, 0.125, 51):
        q = pts + d * ((z - pts[:, 2]) / d[:, 2])[:, None]
        expected |= (np.abs(q[:, 0]) <= 0.025) & (np.abs(q[:, 1]) <= 0.025)
    near_edge = np.zeros(len(pts), bool)
    for z in np.linspace(0.075, 0.125, 51):
        q = pts + d * ((z - pts[:, 2]) / d[:, 2])[:, None]
        near_edge |= np.abs(np.maximum(np.abs(q[:, 0]), np.abs(q[:, 1])) - 0.025) < 1e-3
    assert expected.sum() > 50
    assert np.array_equal(shadowed[~near_edge], expected[~near_edge])


def test_an_occlusion_query_agrees_with_the_first_hit_and_stops_at_its_reach():
    """``blocked`` (Embree's occlusion query) against ``first_hit``'s distance, on 20 000 seeded rays
    through an off-centre sphere: blocked exactly when the first hit lies within the reach, for reaches
    not within 1e-5 (relative) of that hit (float32 rays); a reach of 0 blocks nothing, and rays that miss
    are never blocked."""
    caster = RayCaster(sphere_mesh(0.05))
    rng = np.random.default_rng(7)
    origins = rng.normal(size=(20_000, 3)) * 0.2 + [0.01, -0.02, 0.03]
    dirs = (rng.normal(size=(20_000, 3)) * 0.02 - origins) + rng.normal(size=(20_000, 3)) * 0.05
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    _, hit = caster.first_hit(origins, dirs)
    reach = rng.uniform(0.0, 0.5, len(origins))
    clear = np.abs(reach - hit) > 1e-5 * np.maximum(reach, 1e-3)
    blocked = caster.blocked(origins, dirs, reach)
    assert np.array_equal(blocked[clear], (hit < reach)[clear])
    assert 0.1 < blocked.mean() < 0.9  # both outcomes are exercised (17 % blocked)
    assert not caster.blocked(origins, dirs, np.zeros(len(origins))).any()
    assert not blocked[np.isinf(hit)].any()
    # 20 000 rays are split over the cores; a query of 1 000 runs on one thread: the same answers
    assert np.array_equal(caster.blocked(origins[-1000:], dirs[-1000:], reach[-1000:]), blocked[-1000:])


def test_lengths_of_rows_are_numpys_norms():
    """``lengths`` (one einsum) against ``np.linalg.norm`` on seeded rows of every scale, within 2 ulp;
    ``unit_rows`` gives rows of length 1 pointing the same way."""
    from hlr_lab.geometry.vectors import lengths, unit_rows

    v = np.random.default_rng(2).normal(size=(5_000, 3)) * np.logspace(-6, 6, 5_000)[:, None]
    np.testing.assert_allclose(lengths(v), np.linalg.norm(v, axis=1), rtol=4e-16)
    u = unit_rows(v.copy())
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(u * np.linalg.norm(v, axis=1)[:, None], v, rtol=1e-14)


def test_the_first_hit_is_trimeshs_without_every_faces_corners():
    """``first_hit`` against trimesh's ``intersects_id`` (its float64 plane crossing) on 20 000 seeded rays
    through a 330 k-face sphere: the same faces, distances within 1e-12 m. And it allocates for the rays,
    not the faces: under 4 MB for 1 000 rays, where trimesh's every-face corners and normals are 31 MB."""
    import tracemalloc

    caster = RayCaster(sphere_mesh(0.05, subdivisions=7))
    rng = np.random.default_rng(3)
    origins = rng.normal(size=(20_000, 3)) * 0.2
    dirs = rng.normal(size=(20_000, 3)) * 0.03 - origins
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    tracemalloc.start()
    try:
        caster.first_hit(origins[:1000], dirs[:1000])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * 2**20
    face, dist = caster.first_hit(origins, dirs)
    tri, ray, loc = caster._intersector.intersects_id(
        origins, dirs, multiple_hits=False, return_locations=True
    )
    expected = np.full(len(origins), -1)
    expected[ray] = tri
    assert np.array_equal(face, expected)
    assert 0.2 < (face >= 0).mean() < 0.9  # hits and misses both exercised
    np.testing.assert_allclose(dist[ray], np.linalg.norm(loc - origins[ray], axis=1), rtol=0, atol=1e-12)
    assert np.isinf(dist[face < 0]).all()
