"""Ray casting on a mesh with Embree (through trimesh): visibility, shadows and G-buffers.

Everything is in the mesh's own frame; express cameras and lights there first
(:meth:`hlr_lab.geometry.camera.Camera.in_frame`). These are the building blocks of planning and fitting.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import trimesh

from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.vectors import lengths
from hlr_lab.object.mesh import ColouredMesh

try:  # Embree is ~50× faster than trimesh's pure-numpy fallback; without it a 1 M-pixel G-buffer takes minutes
    from trimesh.ray.ray_pyembree import RayMeshIntersector
except ImportError as exc:  # pragma: no cover - embreex is a hard dependency
    raise ImportError("hlr-lab needs the Embree ray engine: pip install embreex") from exc

# Offsets that keep a ray leaving a surface from hitting that surface again, as a fraction of
# the object's bounding radius; Embree works in float32 (~1e-7 relative).
SURFACE_OFFSET = 1e-5
# How much nearer than expected a hit may be and still count as the expected surface (visibility).
HIT_TOLERANCE = 1e-4
# Rays per Embree call: bounds the temporaries trimesh makes (~200 bytes a ray) on million-ray queries.
_RAY_CHUNK = 1 << 18
# Occlusion queries of at least this many rays are split over the machine's cores: Embree releases the GIL,
# and 400 000 visibility rays take 78 ms on 2 threads against 138 ms on one; below this a thread's hand-off
# costs about what it saves.
_PARALLEL_RAYS = 1 << 14


def _cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@dataclass(frozen=True, eq=False)
class GBuffer:
    """Per-pixel geometry of one view; arrays are (H, W, …), pixels without a hit have face −1.

    face (H, W) int64; point (H, W, 3) mesh-frame hit point; normal (H, W, 3) interpolated corner
    normal (unit, sharp across creases); depth (H, W) camera-frame z (inf on a miss); barycentric (H, W, 3).
    """

    face: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    barycentric: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


class RayCaster:
    """First-hit and occlusion queries against one mesh (the Embree scene is built once)."""

    def __init__(self, mesh: ColouredMesh):
        self.mesh = mesh
        self._intersector = RayMeshIntersector(mesh.trimesh, scale_to_box=False)
        # trimesh's Embree scene wrapper (private, trimesh ≥ 4): it shifts (and scales) origins as the scene
        # was built, and passes queries through to embreex. Held here: trimesh's cache hashes the mesh's
        # arrays on every access (0.1 ms a query, a tenth of planning's ray time).
        self._scene = self._intersector._scene
        self.scale = mesh.bounding_sphere()[1]

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) origins and unit directions → hit face (N,) (−1 on a miss) and distance (N,) (inf).

        Embree finds the face; the distance is the ray's crossing of that face's plane in float64 (as
        trimesh's ``intersects_id`` does, without its every-face corner and normal arrays: 2 GB on a 10 M
        vertex scan). A ray within 1e-5 of parallel to the face it grazes is a miss, as in trimesh.
        """
        origins = np.ascontiguousarray(origins, dtype=np.float64)
        directions = np.ascontiguousarray(directions, dtype=np.float64)
        face = np.full(len(origins), -1, dtype=np.int64)
        dist = np.full(len(origins), np.inf)
        for start in range(0, len(origins), _RAY_CHUNK):
            o, d = origins[start : start + _RAY_CHUNK], directions[start : start + _RAY_CHUNK]
            primitive = np.asarray(self._scene.run(o, d))  # (n,) face index, −1 on a miss
            ray = np.flatnonzero(primitive != -1)
            hit_face = primitive[ray].astype(np.int64)
            normal = self.mesh.face_normals_of(hit_face)  # (h, 3)
            along = np.einsum("ij,ij->i", d[ray], normal)
            ok = np.abs(along) > 1e-5
            ray, hit_face, normal, along = ray[ok], hit_face[ok], normal[ok], along[ok]
            corner = self.mesh.vertices[self.mesh.faces[hit_face, 0]]
            t = np.einsum("ij,ij->i", corner - o[ray], normal) / along
            face[start + ray] = hit_face
            dist[start + ray] = np.abs(t)
        return face, dist

    def blocked(self, origins: np.ndarray, directions: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """(N,) bool: the mesh lies along the ray from each origin (N, 3) in its unit direction (N, 3) within
        ``reach`` (N,) of it. Embree's occlusion query: it stops at any hit and skips the hit point,
        ~5× faster than :meth:`first_hit` for shadow and visibility rays."""
        origins = np.ascontiguousarray(origins, dtype=np.float64)
        directions = np.ascontiguousarray(directions, dtype=np.float64)
        tfar = (np.asarray(reach, dtype=np.float64) * self._scene.scale).astype(np.float32)
        out = np.zeros(len(origins), dtype=bool)
        n = len(origins)
        parts = _cores() if n >= _PARALLEL_RAYS else 1
        step = max(min(_RAY_CHUNK, -(-n // parts)), 1)

        def run(start: int) -> None:
            end = start + step
            hit = self._scene.run(
                origins[start:end], directions[start:end], query="OCCLUDED", dists=tfar[start:end]
            )
            out[start:end] = np.asarray(hit) != -1

        starts = range(0, n, step)
        if parts > 1:  # threads for this query only (~0.1 ms to start): none outlives it or a fork
            with ThreadPoolExecutor(parts, thread_name_prefix="hlr-rays") as pool:
                list(pool.map(run, starts))
        else:
            for start in starts:
                run(start)
        return out

    def segment_blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(N,) bool: the open segment start→end crosses the mesh (starts just off the surface)."""
        d = ends - starts
        length = lengths(d)
        return self.blocked(starts, d / length[:, None], length * (1 - 1e-9))

    def shadowed(self, points: np.ndarray, normals: np.ndarray, light: np.ndarray) -> np.ndarray:
        """(N,) bool: the surface points (N, 3) with normals (N, 3) do not see the point light (3,)."""
        starts = points + normals * (SURFACE_OFFSET * self.scale)
        return self.segment_blocked(starts, np.broadcast_to(light, points.shape))

    def visible_from(self, centre: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(N,) bool: nothing lies between the eye ``centre`` (3,) and each surface point (N, 3)."""
        d = points - centre
        dist = lengths(d)
        return ~self.blocked(
            np.broadcast_to(centre, points.shape), d / dist[:, None], dist - HIT_TOLERANCE * self.scale
        )

    def gbuffer(self, camera: Camera) -> GBuffer:
        """Cast one ray per pixel centre of ``camera`` (expressed in the mesh frame)."""
        h, w = camera.height, camera.width
        s = self.surface_along(*camera.grid_rays())
        depth = np.full(h * w, np.inf)
        depth[s.hit] = camera.to_camera(s.point[s.hit])[:, 2]
        return GBuffer(
            s.face.reshape(h, w),
            s.point.reshape(h, w, 3),
            s.normal.reshape(h, w, 3),
            depth.reshape(h, w),
            s.barycentric.reshape(h, w, 3),
        )

    def surface(self, camera: Camera, pixels: np.ndarray) -> PixelSurface:
        """What the rays through ``pixels`` (N, 2) of ``camera`` (mesh frame) hit first."""
        return self.surface_along(*camera.pixel_rays(pixels))

    def surface_along(self, origins: np.ndarray, dirs: np.ndarray) -> PixelSurface:
        """What the rays from ``origins`` (N, 3) along unit ``dirs`` (N, 3) (mesh frame) hit first."""
        face, dist = self.first_hit(origins, dirs)
        hit = face >= 0
        n = len(face)
        point = np.full((n, 3), np.nan)
        point[hit] = origins[hit] + dirs[hit] * dist[hit, None]
        bary = np.full((n, 3), np.nan)
        normal = np.full((n, 3), np.nan)
        if hit.any():
            corners = self.mesh.faces[face[hit]]
            bary[hit] = trimesh.triangles.points_to_barycentric(self.mesh.vertices[corners], point[hit])
            nrm = np.einsum("ij,ijk->ik", bary[hit], self.mesh.corner_normals_of(face[hit]))
            normal[hit] = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
        return PixelSurface(face, point, normal, bary)


@dataclass(frozen=True, eq=False)
class PixelSurface:
    """First hits of N pixel rays: face (N,) (−1 on a miss), point, normal (unit), barycentric (N, 3)."""

    face: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    barycentric: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


def facing(
    camera: Camera, points: np.ndarray, normals: np.ndarray, *, max_view_angle_deg: float
) -> np.ndarray:
    """(N,) bool: surface point in the image and facing the camera within ``max_view_angle_deg`` (no ray test).

    ``camera``, ``points`` (N, 3) and ``normals`` (N, 3) are in the mesh frame.
    """
    to_cam = camera.centre - points
    cos_view = np.einsum("ij,ij->i", normals, to_cam) / lengths(to_cam)
    ok = cos_view >= np.cos(np.radians(max_view_angle_deg))
    facing_idx = np.flatnonzero(ok)  # projected only where facing: about half the surface
    pixels, z = camera.project(points[facing_idx])
    ok[facing_idx] = (z > 0) & camera.in_image(pixels)
    return ok


def visible_points(
    caster: RayCaster, camera: Camera, points: np.ndarray, normals: np.ndarray, *, max_view_angle_deg: float
) -> np.ndarray:
    """(N,) bool: :func:`facing` and nothing between the camera and the point."""
    candidate = facing(camera, points, normals, max_view_angle_deg=max_view_angle_deg)
    visible = np.zeros(len(points), dtype=bool)
    idx = np.flatnonzero(candidate)
    visible[idx] = caster.visible_from(camera.centre, points[idx])
    return visible


def visible_vertices(caster: RayCaster, camera: Camera, *, max_view_angle_deg: float) -> np.ndarray:
    """(V,) bool: :func:`visible_points` for the mesh's vertices."""
    mesh = caster.mesh
    return visible_points(
        caster, camera, mesh.vertices, mesh.vertex_normals, max_view_angle_deg=max_view_angle_deg
    )
