from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from hlr_lab.errors import InputError
from hlr_lab.object.mesh import ColouredMesh, load_mesh, sample_texture
from hlr_lab.object.procedural import pebble


def write_coloured_ply(path: Path) -> None:
    m = pebble(subdivisions=2).mesh
    trimesh.Trimesh(m.vertices, m.faces, vertex_colors=m.vertex_colours, process=False).export(path)


def write_textured_quad(folder: Path) -> tuple[Path, Path]:
    """Two triangles with UVs (split at a seam: duplicated positions), and a two-colour texture."""
    obj = folder / "quad.obj"
    obj.write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 0 0\n"
        "vt 0 0\nvt 0.49 0\nvt 0.49 1\nvt 0 1\nvt 0.51 0\nvt 1 0\nvt 1 1\n"
        "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :4] = [200, 30, 30]
    tex[:, 4:] = [30, 30, 200]
    png = folder / "quad.png"
    Image.fromarray(tex).save(png)
    return obj, png


def test_vertex_coloured_ply(tmp_path):
    write_coloured_ply(tmp_path / "p.ply")
    mesh = load_mesh(tmp_path / "p.ply", need_colour=True)
    ref = pebble(subdivisions=2).mesh
    assert mesh.vertex_colours is not None
    assert len(mesh.faces) == len(ref.faces)
    assert len(mesh.sha256) == 64
    # PLY may reorder nothing, but compare as sets of (position, colour) to be independent of order
    got = {(tuple(np.round(v, 6)), tuple(c)) for v, c in zip(mesh.vertices, mesh.vertex_colours, strict=True)}
    want = {(tuple(np.round(v, 6)), tuple(c)) for v, c in zip(ref.vertices, ref.vertex_colours, strict=True)}
    assert got == want


def test_glb_keeps_vertex_colours(tmp_path):
    m = pebble(subdivisions=2).mesh
    trimesh.Trimesh(m.vertices, m.faces, vertex_colors=m.vertex_colours, process=False).export(
        tmp_path / "p.glb"
    )
    mesh = load_mesh(tmp_path / "p.glb", need_colour=True)
    assert len(mesh.faces) == len(m.faces)
    assert {tuple(c) for c in mesh.vertex_colours} == {tuple(c) for c in m.vertex_colours}


def test_textured_obj_with_separate_texture_is_welded(tmp_path):
    obj, png = write_textured_quad(tmp_path)
    with pytest.raises(InputError, match="no colour"):
        load_mesh(obj, need_colour=True)  # UVs but no image: trimesh's 2×2 placeholder is not a texture
    mesh = load_mesh(obj, png, need_colour=True)
    assert len(mesh.vertices) == 4  # the seam duplicate of (1, 0, 0) is welded
    assert mesh.corner_uv.shape == (2, 3, 2)
    assert mesh.texture.shape == (8, 8, 3)
    assert mesh.texture_source == png


def test_spot_loads_with_its_texture(spot_paths):
    obj, png = spot_paths
    mesh = load_mesh(obj, png, need_colour=True)
    assert len(mesh.vertices) < 3225  # seams welded
    assert mesh.vertex_normals.shape == mesh.vertices.shape
    assert np.isfinite(mesh.vertex_normals).all()


def test_texture_lookup_orientation():
    tex = np.zeros((2, 2, 3), np.uint8)
    tex[0, 0] = 1  # top-left texel is v = 1
    tex[1, 1] = 2  # bottom-right texel is u = 1, v = 0
    assert sample_texture(tex, np.array([0.25, 0.75]))[0] == 1
    assert sample_texture(tex, np.array([0.75, 0.25]))[0] == 2


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
        ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "no colour"),
    ],
)
def test_bad_meshes_get_one_clear_error(tmp_path, content, message):
    path = tmp_path / "bad.obj"
    path.write_text(content)
    with pytest.raises(InputError, match=message) as err:
        load_mesh(path, need_colour=True)
    assert str(path) in str(err.value)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="no such mesh file"):
        load_mesh(tmp_path / "nope.ply")
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01")
    with pytest.raises(InputError, match=r"garbage\.ply"):
        load_mesh(garbage)


def test_texture_without_uvs_is_refused(tmp_path):
    write_coloured_ply(tmp_path / "p.ply")
    _, png = write_textured_quad(tmp_path)
    with pytest.raises(InputError, match="no texture coordinates"):
        load_mesh(tmp_path / "p.ply", png)


def test_corner_normals_are_sharp_across_creases_and_smooth_elsewhere():
    """A welded cylinder (one vertex per rim point, as a scan would give): side corners keep the side's
    horizontal normal and cap corners point straight up or down, where one vertex normal per rim point
    would tilt both; on a smooth sphere the corner normals are the vertex normals."""
    cyl = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=64)
    cyl.merge_vertices()
    mesh = ColouredMesh(np.asarray(cyl.vertices), np.asarray(cyl.faces, np.int64))
    normals = mesh.corner_normals  # (F, 3, 3)
    cap = np.abs(mesh.face_normals[:, 2]) > 0.99
    np.testing.assert_allclose(np.abs(normals[cap][..., 2]), 1.0, atol=1e-9)
    assert np.abs(normals[~cap][..., 2]).max() < 1e-9  # horizontal on the side
    assert np.abs(mesh.vertex_normals[mesh.faces][~cap][..., 2]).max() > 0.2  # welding alone tilts them 12°

    sphere = trimesh.creation.icosphere(subdivisions=3)
    smooth = ColouredMesh(np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64))
    np.testing.assert_array_equal(smooth.corner_normals, smooth.vertex_normals[smooth.faces])


def test_a_few_faces_corner_normals_are_those_of_all_faces(monkeypatch):
    """``corner_normals_of`` (a G-buffer's hit faces on a scan) works out only the faces asked for (each
    once, however many pixels hit it), its crease vertices and their faces found a block of faces at a
    time: with blocks of 50 faces, the welded cylinder's creased and smooth corners are exactly those of
    :attr:`corner_normals`, and the mesh keeps nothing per face. Asked for as many as it has faces (a
    G-buffer of a coarse mesh), it works out all of them once and keeps them."""
    from hlr_lab.object import mesh as mesh_module

    cyl = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=64)
    cyl.merge_vertices()
    v, f = np.asarray(cyl.vertices), np.asarray(cyl.faces, np.int64)
    every = ColouredMesh(v, f).corner_normals
    monkeypatch.setattr(mesh_module, "_FACE_BLOCK", 50)
    rng = np.random.default_rng(4)
    few = rng.integers(0, len(f), 60)  # fewer than its 256 faces, some twice
    scan_like = ColouredMesh(v, f)
    np.testing.assert_array_equal(scan_like.corner_normals_of(few), every[few])
    assert "corner_normals" not in scan_like.__dict__
    many = rng.integers(0, len(f), 20 * len(f))  # pixels: many on each face
    coarse = ColouredMesh(v, f)
    np.testing.assert_array_equal(coarse.corner_normals_of(many), every[many])
    assert "corner_normals" in coarse.__dict__
    np.testing.assert_array_equal(coarse.corner_normals_of(few), every[few])
    # the same rule for the faces' own normals (a ray's hit face, in every first hit)
    units = ColouredMesh(v, f).face_normals
    scan_like, coarse = ColouredMesh(v, f), ColouredMesh(v, f)
    np.testing.assert_array_equal(scan_like.face_normals_of(few), units[few])
    np.testing.assert_array_equal(coarse.face_normals_of(many), units[many])
    assert "face_normals" not in scan_like.__dict__
    assert "face_normals" in coarse.__dict__


def _open_box() -> ColouredMesh:
    """A unit cube without its top (two rims' worth of open edges), plus a fin: an edge of three faces."""
    box = trimesh.creation.box()
    up = box.face_normals[:, 2] > 0.5
    faces = np.asarray(box.faces)[~up]
    fin_tip = len(box.vertices)  # a face on an existing bottom edge, sticking out: that edge has three
    bottom = faces[np.asarray(box.face_normals)[~up][:, 2] < -0.5][0]
    vertices = np.vstack([box.vertices, [[0.0, 0.0, -2.0]]])
    faces = np.vstack([faces, [[bottom[0], bottom[1], fin_tip]]])
    return ColouredMesh(np.asarray(vertices), faces.astype(np.int64))


def test_the_faces_beside_each_edge_are_trimeshs_and_the_rims_each_edge_of_one_face():
    """``edge_faces``: the pairs of faces sharing an edge and that edge's vertices are trimesh's
    ``face_adjacency`` and ``face_adjacency_edges`` (as sets, an edge of three faces in neither); the rims
    are the edges used once, each with its face."""
    for mesh in (_open_box(), pebble(subdivisions=2).mesh):
        shared, faces, rims, rim_faces = mesh.edge_faces()
        tm = mesh.trimesh
        ours = {(tuple(e), tuple(sorted(f))) for e, f in zip(shared.tolist(), faces.tolist(), strict=True)}
        theirs = {
            (tuple(sorted(e)), tuple(sorted(f)))
            for e, f in zip(tm.face_adjacency_edges.tolist(), tm.face_adjacency.tolist(), strict=True)
        }
        assert ours == theirs
        edges, first, uses = np.unique(tm.edges_sorted, axis=0, return_index=True, return_counts=True)
        once = uses == 1
        expected = {
            (tuple(e), f)
            for e, f in zip(edges[once].tolist(), tm.edges_face[first[once]].tolist(), strict=True)
        }
        assert {(tuple(e), f) for e, f in zip(rims.tolist(), rim_faces.tolist(), strict=True)} == expected
        assert shared.dtype == faces.dtype == rims.dtype == rim_faces.dtype == np.int32
    shared, _, rims, _ = _open_box().edge_faces()
    assert len(rims) == 4 + 2  # the open top's four edges and the fin's two free ones
    # the cube's 18 edges (a diagonal a side), less the top's diagonal, its rim and the fin's base
    assert len(shared) == 18 - 1 - 4 - 1


def test_surface_samples_are_trimeshs_seeded_draws():
    """The same points as trimesh's ``sample_surface`` with the same seed (the registration's search
    stands on them), without its per-face copies."""
    mesh = pebble(subdivisions=2).mesh
    ours = mesh.surface_samples(2000, seed=3)
    theirs = np.asarray(trimesh.sample.sample_surface(mesh.trimesh, 2000, seed=3)[0])
    np.testing.assert_allclose(ours, theirs, atol=1e-12)


def test_the_faces_beside_each_edge_are_the_same_read_in_blocks(monkeypatch):
    """``edge_faces`` reads a scan's sorted edges in blocks (bounded memory): blocks of 7 face edges, which
    split edges' pairs at block ends, give what one block does."""
    import hlr_lab.object.mesh as mesh_module

    for mesh in (_open_box(), pebble(subdivisions=1).mesh):
        whole = mesh.edge_faces()
        monkeypatch.setattr(mesh_module, "_FACE_BLOCK", 7)
        blocks = mesh.edge_faces()
        monkeypatch.undo()
        for a, b in zip(whole, blocks, strict=True):
            assert np.array_equal(a, b)
