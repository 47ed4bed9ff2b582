"""Vertices clustered on a grid: a scan's millions of vertices, each far under a pixel, as fewer points
that still lie on its surface, and the coarser mesh they span.

Vertex clustering (Rossignac–Borrel) in one grouping of integer keys, O(V log V) and vectorised: a vertex's
key is its grid cell, the octant-like bin of its normal (``NORMAL_BINS`` per axis, so that the two sides of
a thin part never merge) and its label (so that no cluster straddles two regions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.object.grouping import group_rows
from hlr_lab.object.mesh import ColouredMesh

NORMAL_BINS = 3  # per axis: vertices whose normals differ by more than ~40° are never merged


@dataclass(frozen=True, eq=False)
class VertexClusters:
    """V vertices in G clusters.

    group (V,) int: each vertex's cluster; member (G,) int: the cluster's vertex nearest its area-weighted
    mean (on the surface, where the mean of a curved patch is not); area (G,) m²: the members' summed
    vertex areas; normal (G, 3): their area-weighted mean unit normal; label (G,): their label.
    """

    group: np.ndarray
    member: np.ndarray
    area: np.ndarray
    normal: np.ndarray
    label: np.ndarray

    def __len__(self) -> int:
        return len(self.member)


def cluster_vertices(
    points: np.ndarray, normals: np.ndarray, areas: np.ndarray, labels: np.ndarray, cell_m: float
) -> VertexClusters:
    """Cluster V vertices — ``points`` (V, 3) m, unit ``normals`` (V, 3), ``areas`` (V,) m² each stands for,
    ``labels`` (V,) int — by (``cell_m`` grid cell, normal bin, label)."""
    v, n, a = points, normals, areas
    # the keys as narrow columns and every (V, 3) step an axis at a time: a 10 M-vertex scan's temporaries
    # stay ~40 bytes a vertex
    columns: list[np.ndarray] = []
    code = np.zeros(len(v), dtype=np.int8)  # the normal's bins, in their lexicographic order: 27 at most
    for k in range(3):
        columns.append(_cells(v[:, k], cell_m))
        code = code * NORMAL_BINS + np.clip(
            np.floor((n[:, k] + 1) * NORMAL_BINS / 2), 0, NORMAL_BINS - 1
        ).astype(np.int8)
    group, first = group_rows([*columns, code, labels])
    del columns, code
    count = len(first)
    area = np.bincount(group, weights=a, minlength=count)
    weight = np.maximum(area, 1e-300)
    mean = np.column_stack(
        [np.bincount(group, weights=v[:, k] * a, minlength=count) / weight for k in range(3)]
    )
    normal = np.column_stack([np.bincount(group, weights=n[:, k] * a, minlength=count) for k in range(3)])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    # the cluster stands at its member nearest the mean: the mean of a curved patch lies off the surface
    # (inside a convex one), by more than the ray caster's tolerances, and that surface would then hide
    # it from the camera or shadow it
    d2 = sum((v[:, k] - mean[group, k]) ** 2 for k in range(3))  # (V,)
    least = np.full(count, np.inf)
    np.minimum.at(least, group, d2)
    at_least = np.flatnonzero(d2 == least[group])  # ascending: of a cluster's ties, its first vertex is kept
    member = at_least[np.unique(group[at_least], return_index=True)[1]]  # (G,) in the clusters' order
    return VertexClusters(group, member, area, normal, labels[first])


def _cells(x: np.ndarray, cell_m: float) -> np.ndarray:
    """(V,) each coordinate's cell of the grid floor(x / cell_m), counted from the lowest, in the narrowest
    unsigned type that holds them (a few hundred cells across an object: 2 bytes a vertex, not 8)."""
    cell = np.floor(x / cell_m)
    cell -= cell.min()
    return cell.astype(np.min_scalar_type(int(cell.max())))


def clustered_mesh(mesh: ColouredMesh, clusters: VertexClusters) -> tuple[ColouredMesh, np.ndarray]:
    """The mesh the clusters span: a vertex per cluster (at its member, with its mean normal), each face
    whose corners fall in three different clusters once (a face repeated by another, in either winding,
    is dropped). Returns the mesh (no colour) and (F',) the index of each kept face in ``mesh.faces``."""
    proper = np.concatenate(  # a block of faces at a time: a scan's (F, 3) corner clusters are 480 MB
        [
            np.flatnonzero(_proper(clusters.group[mesh.faces[block]])) + block.start
            for block in mesh.face_blocks()
        ]
        or [np.zeros(0, np.int64)]
    )
    corners = clusters.group[mesh.faces[proper]]  # (F', 3): of a stand-in's cells, a few per cent of F
    _, once = group_rows(np.sort(corners, axis=1))
    once = np.sort(once)
    kept, faces = proper[once], corners[once].astype(np.int64)
    return ColouredMesh(mesh.vertices[clusters.member], faces, normals=clusters.normal), kept


def _proper(corners: np.ndarray) -> np.ndarray:
    """(F,) bool: the faces whose corners (F, 3) lie in three different clusters."""
    return (
        (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2]) & (corners[:, 0] != corners[:, 2])
    )
