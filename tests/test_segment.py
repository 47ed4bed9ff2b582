import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components

from hlr_lab.errors import InputError
from hlr_lab.geometry.colour import delta_e, srgb8_to_lab
from hlr_lab.object.grouping import connected_groups
from hlr_lab.object.mesh import ColouredMesh, load_mesh
from hlr_lab.object.procedural import PALETTE, paint_patches
from hlr_lab.object.segment import merge_fragments, segment, weighted_mode
from tests.conftest import same_partition


def test_pebble_materials_recovered_exactly(pebble_object):
    seg = segment(pebble_object.mesh)
    assert seg.n_regions == 4
    assert same_partition(seg.vertex_labels, pebble_object.material)
    # every region's mean colour is the colour it was painted with
    for r in seg.regions:
        painted = pebble_object.mesh.vertex_colours[seg.vertex_labels == r.id]
        assert (painted == r.colour).all()
    assert [r.area_m2 for r in seg.regions] == sorted((r.area_m2 for r in seg.regions), reverse=True)


def test_split_connected_separates_same_colour_patches(pebble_object):
    seg = segment(pebble_object.mesh, split_connected=True)
    assert seg.n_regions == 6
    assert same_partition(seg.vertex_labels, pebble_object.patch)
    assert len({r.material for r in seg.regions}) == 4


def test_face_labels_follow_the_vertex_majority(pebble_object):
    seg = segment(pebble_object.mesh)
    corner_labels = seg.vertex_labels[pebble_object.mesh.faces]
    unanimous = (corner_labels == corner_labels[:, :1]).all(axis=1)
    assert np.array_equal(seg.face_labels[unanimous], corner_labels[unanimous, 0])


def test_noisy_colours_still_form_the_painted_regions(pebble_object):
    rng = np.random.default_rng(7)
    m = pebble_object.mesh
    noisy = np.clip(m.vertex_colours + rng.normal(0, 3, m.vertex_colours.shape), 0, 255).astype(np.uint8)
    seg = segment(ColouredMesh(m.vertices, m.faces, noisy))
    assert same_partition(seg.vertex_labels, pebble_object.material)


def test_speckles_merge_into_their_surroundings(pebble_object):
    m = pebble_object.mesh
    rng = np.random.default_rng(11)
    speckled = m.vertex_colours.copy()
    isolated = rng.choice(len(m.vertices), 12, replace=False)
    speckled[isolated] = [255, 0, 255]  # magenta dots: a distinct colour but one vertex each
    seg = segment(ColouredMesh(m.vertices, m.faces, speckled))
    assert seg.n_regions == 4
    clean = np.ones(len(m.vertices), bool)
    clean[isolated] = False
    assert same_partition(seg.vertex_labels[clean], pebble_object.material[clean])


def test_fixed_region_count(pebble_object):
    seg = segment(pebble_object.mesh, n_materials=2)
    assert seg.n_regions == 2
    with pytest.raises(InputError, match="more regions than"):
        segment(pebble_object.mesh, n_materials=50)


def test_mesh_without_colour_is_refused(pebble_object):
    m = pebble_object.mesh
    with pytest.raises(InputError, match="no colour"):
        segment(ColouredMesh(m.vertices, m.faces))


def test_weighted_mode_and_fragment_merge_primitives():
    labels = np.array([[0, 1, 1], [2, 2, 0]])
    weights = np.array([[5.0, 1.0, 1.0], [1.0, 1.0, 3.0]])
    assert weighted_mode(labels, weights).tolist() == [0, 0]
    # a path graph 0-1-2-3-4: label 1 at node 2 is a light fragment between two 0s
    edges = (np.array([0, 1, 2, 3]), np.array([1, 2, 3, 4]))
    out = merge_fragments(np.array([0, 0, 1, 0, 0]), edges, np.ones(5), min_weight=2)
    assert out.tolist() == [0, 0, 0, 0, 0]


def test_a_meshs_edges_are_each_edge_once_in_one_direction():
    """``vertex_edges``: every edge of every face, once, lower vertex first, as int32 (a scan's adjacency
    in a fraction of the memory); ``face_edges``: every pair of faces sharing an edge, once."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    mesh = ColouredMesh(np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64))
    low, high = mesh.vertex_edges()
    assert low.dtype == np.int32
    assert np.all(low < high)
    every = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert np.array_equal(np.unique(np.column_stack([low, high]), axis=0), np.unique(every, axis=0))
    assert len(low) == len(np.unique(every, axis=0))
    first, second = mesh.face_edges()
    assert len(first) == len(low)  # a closed mesh: one pair of faces per edge
    assert len(np.unique(np.sort(np.column_stack([first, second]), axis=1), axis=0)) == len(first)


def test_bunny_with_eight_painted_regions(bunny_path):
    bunny = load_mesh(bunny_path)
    painted = paint_patches(bunny, 8)
    seg = segment(painted.mesh)
    assert seg.n_regions == 8
    assert same_partition(seg.vertex_labels, painted.patch)


def test_spot_texture_regions(spot_paths):
    obj, png = spot_paths
    seg = segment(load_mesh(obj, png))
    lab = srgb8_to_lab(np.array([r.colour for r in seg.regions]))
    # cream body, peach muzzle/udder, dark patches, grey horns, brown hooves … at least five materials,
    # and no two regions of the same colour
    assert 5 <= seg.n_regions <= 9
    d = delta_e(lab[:, None], lab[None])
    assert (d[~np.eye(len(lab), dtype=bool)] > 5).all()
    cream = srgb8_to_lab(np.array([255, 238, 230]))
    assert delta_e(lab[0], cream) < 5  # the largest region is the body colour
    assert sum(r.faces for r in seg.regions) == len(seg.face_labels)


def test_palette_colours_are_far_apart():
    lab = srgb8_to_lab(PALETTE)
    d = delta_e(lab[:, None], lab[None])
    assert d[~np.eye(len(lab), dtype=bool)].min() > 30


@pytest.mark.parametrize("k", [3, 7])
def test_the_weighted_mode_of_few_columns_is_the_heaviest_label_of_their_votes(k):
    """``weighted_mode`` (k² passes over the rows, for a face's corners or samples) against the general
    ``heaviest_label`` (every vote sorted): the same label for every row of 20 000 seeded rows with many
    ties (labels 0–3, weights 0, 0.1, 0.2, 1, 2), ties to the smaller label."""
    from hlr_lab.object.segment import heaviest_label

    rng = np.random.default_rng(k)
    n = 20_000
    labels = rng.integers(0, 4, (n, k))
    weights = rng.integers(0, 3, (n, k)) * rng.choice([1.0, 0.1], size=(n, k))
    expected = heaviest_label(np.repeat(np.arange(n), k), labels.ravel(), weights.ravel(), n)
    assert np.array_equal(weighted_mode(labels, weights), expected)


@pytest.mark.parametrize(
    ("n", "e", "seed"),
    [
        (0, 0, 0),
        (1, 3, 1),
        (5, 0, 2),
        (50, 20, 3),
        (2_000, 1_500, 4),
        (2_000, 6_000, 5),
        (200_000, 150_000, 6),
    ],
)
def test_connected_groups_are_scipys_components(n, e, seed):
    """The union-find's components, numbered by their lowest node, are scipy's (which builds a float64
    graph of the edges): random graphs from isolated nodes to one giant component, self-loops, repeated
    edges, and only the edges a mask keeps."""
    rng = np.random.default_rng(seed)
    u, v = rng.integers(0, max(n, 1), (2, e)).astype(np.int32)
    keep = rng.random(e) < 0.7
    for where in (None, keep):
        chosen = np.ones(e, bool) if where is None else where
        graph = sp.coo_matrix((np.ones(int(chosen.sum())), (u[chosen], v[chosen])), shape=(n, n))
        expected = connected_components(graph, directed=False)[1]
        got = connected_groups(n, u, v, where=where)
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.int32


def test_connected_groups_join_a_path_in_any_order():
    """A path whose nodes are numbered at random (many rounds of hooking) is one component."""
    order = np.random.default_rng(7).permutation(100_000)
    got = connected_groups(len(order), order[:-1], order[1:])
    assert (got == 0).all()
