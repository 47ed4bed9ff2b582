"""The surface samples of a scanned mesh: millions of vertices, each far under a pixel, merged into
samples of a few pixels (what planning counts them by), without mixing regions or the two sides of a
thin part."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.samples import faces_towards, merged_vertices, surface_samples


def thin_plate() -> ColouredMesh:
    """A 10 × 10 cm plate 1 mm thick, finely subdivided, its left half red and its right half blue."""
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.001))
    v, f = box.vertices, box.faces
    for _ in range(6):
        v, f = trimesh.remesh.subdivide(v, f)[:2]
    colours = np.where(v[:, :1] < 0, [[200, 40, 40]], [[40, 60, 200]]).astype(np.uint8)
    return ColouredMesh(np.asarray(v, np.float64), np.asarray(f, np.int64), colours)


def test_merged_vertices_keep_each_regions_area_and_never_mix_sides_or_regions():
    """Cells of 5 mm hold the plate's top and bottom (1 mm apart) and its two colours: the merged samples
    are far fewer, each region keeps its whole area, every sample's normal is one face's (±z or a side:
    an average of top and bottom would lie in between), and each sample lies on its region's half."""
    mesh = thin_plate()
    seg = segment(mesh)
    assert seg.n_regions == 2
    merged = merged_vertices(mesh, seg, 0.005)
    assert len(merged) < len(mesh.vertices) / 10
    np.testing.assert_allclose(
        np.bincount(merged.region, weights=merged.area),
        np.bincount(seg.vertex_labels, weights=mesh.vertex_areas),
    )
    np.testing.assert_allclose(np.linalg.norm(merged.normal, axis=1), 1.0)
    along = np.abs(merged.normal).max(axis=1)
    assert along.min() > 0.7  # a face's normal, or a corner's between two faces: never top and bottom
    top = merged.normal[:, 2] > 0.9
    bottom = merged.normal[:, 2] < -0.9
    assert np.all(merged.point[top, 2] > 0)
    assert np.all(merged.point[bottom, 2] < 0)
    left = seg.vertex_labels[np.argmin(mesh.vertices[:, 0])]
    face = top | bottom
    assert np.all((merged.point[face, 0] < 0) == (merged.region[face] == left))


@pytest.mark.parametrize("span", [10, 2**40])
def test_rows_are_grouped_as_numpy_groups_them_in_one_integer_or_as_bytes(span):
    """``group_rows``: rows packed into one int64 when their ranges allow (span 10), compared as bytes when
    not (span 2⁴⁰ in three columns overflows 63 bits): either way the groups of ``np.unique(axis=0)``
    (packed, in its order too), with negative keys; given as narrow columns, the same groups."""
    from hlr_lab.object.grouping import group_rows

    rng = np.random.default_rng(3)
    base = rng.integers(-span, span, size=(40, 3))
    keys = base[rng.integers(0, 40, 5_000)]  # (5 000, 3), 40 distinct rows at most
    group, first = group_rows(keys)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    if span == 10:  # the same from narrow columns
        narrow = group_rows(
            [keys[:, 0].astype(np.int8), keys[:, 1].astype(np.int16), keys[:, 2].astype(np.int32)]
        )
        assert np.array_equal(narrow[0], group)
        assert np.array_equal(narrow[1], first)
        assert np.array_equal(first, np.unique(keys, axis=0, return_index=True)[1])  # each group's first row
    if span == 10:  # integer packing keeps the lexicographic order; bytes order differently
        assert np.array_equal(group, inverse.ravel())
    assert np.array_equal(keys[first][group], keys)  # each row is its group's member
    assert len(first) == len(unique)


def test_merged_samples_lie_on_the_surface_so_that_it_neither_hides_nor_shadows_them():
    """On a 5 cm sphere (40 962 vertices) merged in 3 mm cells, a cell's mean point lies ~20 µm inside the
    surface — beyond the ray caster's tolerances (5 µm to be seen, 0.5 µm off the surface for shadows) —
    and the sphere itself would hide it from a camera in front and shadow it from a lamp beside that
    camera. The samples stand on a member vertex: every one facing the camera (within 60°) is seen and
    lit, and none lies more than 1 µm off the sphere. (At the means: 24 % seen, 81 % shadowed.)"""
    from hlr_lab.object.raycast import RayCaster

    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.05)
    v, f = np.asarray(sphere.vertices, np.float64), np.asarray(sphere.faces, np.int64)
    mesh = ColouredMesh(v, f, np.tile(np.array([[180, 120, 60]], np.uint8), (len(v), 1)))
    merged = merged_vertices(mesh, segment(mesh), 0.003)
    assert len(merged) < len(v) / 5
    radius = np.linalg.norm(merged.point, axis=1)
    assert np.abs(radius - 0.05).max() < 1e-6  # the icosphere's vertices lie on the sphere
    caster = RayCaster(mesh)
    eye = np.array([0.0, -0.5, 0.0])
    front = merged.normal @ (eye / np.linalg.norm(eye)) > np.cos(np.radians(60))
    assert front.sum() > 50
    assert caster.visible_from(eye, merged.point[front]).all()
    lamp = np.array([0.05, -0.5, 0.05])
    assert not caster.shadowed(merged.point[front], merged.normal[front], lamp).any()


def test_faces_no_view_can_see_the_front_of_give_no_samples_and_no_facing_sample_is_lost(rig):
    """A coarse pebble (faces split into samples) seen from the camera at turntable 0: the samples of the
    faces some eye may face are fewer than the whole surface's, and they hold every sample of the whole
    set whose (interpolated) normal points towards the eye — the same points, none lost."""
    obj = pebble(subdivisions=2)
    placed = obj.mesh.transformed(placement(obj.mesh))
    seg = segment(placed)
    eye = rig.camera.centre
    every = surface_samples(placed, seg, rig.camera, "pixels")
    kept = surface_samples(placed, seg, rig.camera, "pixels", towards=faces_towards(placed, eye[None]))
    assert len(every) > len(placed.faces)  # faces were split: the filter is what this tests
    assert len(kept) < 0.7 * len(every)

    def facing_points(s) -> np.ndarray:
        towards = np.einsum("nd,nd->n", s.normal, eye - s.point) > 0
        p = s.point[towards]
        return p[np.lexsort(p.T)]

    np.testing.assert_array_equal(facing_points(kept), facing_points(every))


def test_a_surface_no_eye_sees_the_front_of_gives_no_samples(rig):
    """An open plate facing down, the camera above it: no face may face the eye, so no sample (an empty
    set, not an error)."""
    plate = trimesh.creation.box(extents=(0.1, 0.1, 0.001))
    v, f = plate.vertices, plate.faces[plate.face_normals[:, 2] < -0.5]  # the underside only
    grey = np.full((len(v), 3), 128, np.uint8)
    mesh = ColouredMesh(np.asarray(v, np.float64), np.asarray(f, np.int64), grey)
    seg = segment(mesh)
    assert len(surface_samples(mesh, seg, rig.camera, "pixels", target_px=1e-3)) > 0
    away = faces_towards(mesh, np.array([[0, 0, 0.5]]))
    none = surface_samples(mesh, seg, rig.camera, "pixels", target_px=1e-3, towards=away)
    assert len(none) == 0
