"""A scan planned on a coarser copy of itself, its ray proxy.

A scanner's mesh has millions of vertices, each far under a pixel. Planning needs the surface only at the
image's resolution, but the ray engine's scene, its memory and every per-vertex array grow with the
vertices (8.9 M vertices: 32 s and 4 GB, docs/planning.md). So a mesh finer than the pixel count needs is
planned on its vertices clustered on a ``PROXY_CELL_PX`` grid (:mod:`hlr_lab.object.clusters`): each
cluster a vertex at one of its members, with the members' mean normal, and the faces that span three
clusters. The planner's samples then lie on the very surface its rays are cast against, as on any mesh.
(Samples merged from the full mesh but rays cast against a proxy disagree by the proxy's error, which at
these scales moves counts by 4–21 %: the samples must stand on the proxy's surface, docs/planning.md.)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from hlr_lab.geometry.camera import Camera
from hlr_lab.object.clusters import cluster_vertices, clustered_mesh
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.segment import Segmentation
from hlr_lab.planning.samples import MERGE_BELOW, TARGET_PX, pixels_per_m2

# The proxy's grid cell, in pixels on a side at the object's distance. On the 2.2 M-vertex bunny (paper
# set-up) the same two lights counted on a 1 px proxy came out within −9…+11 % per region (+1.4 % in
# total) of the full mesh's counts, and on a 2 px proxy −16…+22 %; the bunny's own 35 k vertices, the mesh
# the scan was subdivided from, −46…+32 %: a 1 px proxy is well inside what any coarser copy moves.
PROXY_CELL_PX = 1.0
# A mesh is planned on a proxy when its median vertex stands for less than this many pixels: where the
# planner would otherwise merge its vertices into samples (samples.MERGE_BELOW).
PROXY_BELOW_PX = MERGE_BELOW * TARGET_PX


@dataclass(frozen=True, eq=False)
class RayProxy:
    """The mesh planning casts its rays against and takes its samples from, in the given mesh's frame, with
    the segmentation carried over; ``cell_m`` the grid cell (m); ``source_vertices`` the given mesh's count."""

    mesh: ColouredMesh
    segmentation: Segmentation
    cell_m: float
    source_vertices: int


def ray_proxy(
    mesh: ColouredMesh, segmentation: Segmentation, camera: Camera, *, cell_px: float = PROXY_CELL_PX
) -> RayProxy | None:
    """``mesh``'s ray proxy (``camera`` in the mesh's frame sets the pixel scale), or None when its median
    vertex already stands for ``PROXY_BELOW_PX`` pixels or more (the mesh is then planned as it is)."""
    px_per_m2 = pixels_per_m2(mesh.vertices, camera)  # (V,)
    if float(np.median(mesh.vertex_areas * px_per_m2)) >= PROXY_BELOW_PX:
        return None
    cell_m = float(np.sqrt(cell_px / np.median(px_per_m2)))
    del px_per_m2
    # the normals computed for the clustering alone, not kept on the mesh (a scan's: 240 MB at 10 M)
    normals = mesh.normals if mesh.normals is not None else mesh.area_weighted_normals()
    clusters = cluster_vertices(mesh.vertices, normals, mesh.vertex_areas, segmentation.vertex_labels, cell_m)
    del normals
    proxy, kept = clustered_mesh(mesh, clusters)
    labels = dataclasses.replace(
        segmentation, vertex_labels=clusters.label, face_labels=segmentation.face_labels[kept]
    )
    return RayProxy(proxy, labels, cell_m, len(mesh.vertices))
