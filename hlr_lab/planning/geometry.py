"""Geometry of planning: where the object sits, the light sphere S, what the gantry can reach, and
where each vertex's highlight lands on S."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from hlr_lab.errors import InputError, PlanningError
from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.vectors import unit_rows
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.rig.file import Gantry

_UP_AXES = {"x": 0, "y": 1, "z": 2}
MAX_SPHERE_SCALE = 100.0  # a lamp 100 object radii away is already a directional light


def placement(mesh: ColouredMesh, *, up: str = "z", scale: float = 1.0) -> np.ndarray:
    """4×4 mesh → turntable transform: scaled, ``up`` turned to +z, bounding box centred on the turntable
    axis and resting on the plate (z = 0)."""
    if up.lstrip("+-") not in _UP_AXES or len(up) > 2:
        raise InputError(f"unknown up axis {up!r}; use x, y, z, -x, -y or -z", field="--up")
    if not scale > 0:
        raise InputError(f"the scale must be positive, got {scale}", field="--scale")
    axis = np.zeros(3)
    axis[_UP_AXES[up.lstrip("+-")]] = -1.0 if up.startswith("-") else 1.0
    rot = _rotation_taking(axis, np.array([0.0, 0.0, 1.0]))
    v = (mesh.vertices @ rot.T) * scale
    lo, hi = v.min(axis=0), v.max(axis=0)
    m = np.eye(4)
    m[:3, :3] = rot * scale
    m[:3, 3] = [-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]]
    return m


def _rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Proper rotation taking unit vector a onto unit vector b (a half-turn about x when opposite)."""
    # Not trimesh.geometry.align_vectors: that aligns a with b but adds a turn about b (y-up → z-up comes
    # out turned 90° about z), which would move every planned object on the plate. This is the least one.
    v, c = np.cross(a, b), float(a @ b)
    if c < -0.999999:
        return np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


SphereSource = Literal["rig", "scale"]  # the gantry's sphere, or the paper's K × the object's


@dataclass(frozen=True, eq=False)
class LightSphere:
    """The sphere S lights are placed on, in world coordinates, and the gantry limits that apply.

    ``source`` is "rig" (the gantry arm radius) or "scale" (K × the object's bounding sphere, as the paper).
    """

    centre: np.ndarray
    radius: float
    source: SphereSource
    gantry: Gantry

    def reachable(self, positions: np.ndarray, camera: Camera) -> np.ndarray:
        """(N,) bool for world positions (N, 3) on S: joint limits, camera keep-out cone, above the table."""
        g = self.gantry
        # the height first: it is one comparison and rules out ~40 % of a whole sphere, whose joint angles
        # (two inverse trigonometric functions a point) are then found for the rest only
        out = positions[:, 2] >= g.min_light_height
        above = np.flatnonzero(out)
        d = (positions[above] - self.centre) / self.radius
        az, el = g.kinematics.direction_angles(d)
        to_cam = camera.centre - self.centre
        to_cam /= np.linalg.norm(to_cam)
        out[above] = (
            (az >= g.azimuth_limits[0])
            & (az <= g.azimuth_limits[1])
            & (el >= g.elevation_limits[0])
            & (el <= g.elevation_limits[1])
            & (d @ to_cam <= np.cos(g.camera_keepout))
        )
        return out


def light_sphere(gantry: Gantry, placed_vertices: np.ndarray, sphere_scale: float | None) -> LightSphere:
    """S from the rig (arm radius about the gantry centre) or ``sphere_scale`` × the bounding sphere.

    Raises PlanningError when the object pokes out of S (a light there would sit inside the object).
    """
    if sphere_scale is None:
        centre, radius = np.asarray(gantry.centre, float), float(gantry.arm_radius)
        source: SphereSource = "rig"
    else:
        if not 1 < sphere_scale <= MAX_SPHERE_SCALE:
            raise InputError(
                f"--sphere-scale must exceed 1 and be at most {MAX_SPHERE_SCALE:g} (the paper uses 2), got "
                f"{sphere_scale:g}",
                field="--sphere-scale",
            )
        lo, hi = placed_vertices.min(axis=0), placed_vertices.max(axis=0)
        centre = (lo + hi) / 2
        radius = sphere_scale * float(np.linalg.norm(placed_vertices - centre, axis=1).max())
        source = "scale"
    # the turntable sweeps the object around z: its farthest point from S's centre over all angles
    r_xy = np.linalg.norm(placed_vertices[:, :2], axis=1) + np.linalg.norm(centre[:2])
    reach = float(np.sqrt(r_xy**2 + (placed_vertices[:, 2] - centre[2]) ** 2).max())
    if reach >= radius:
        raise PlanningError(
            f"the object reaches {reach:.3f} m from the light sphere's centre but the sphere's "
            f"radius is {radius:.3f} m; use a larger arm, --sphere-scale, or --scale"
        )
    return LightSphere(centre, radius, source, gantry)


@dataclass(frozen=True, eq=False)
class Highlights:
    """Where the highlights of N surface points land on S (all in one frame).

    point (N, 3), normal (N, 3), mirror (N, 3) unit mirror direction of the view direction about the
    normal, distance (N,) from the point to S along ``mirror``, footprint (N, 3) unit direction from S's
    centre to where the mirror ray meets S, and cos_incidence (N,) of the mirror ray with S's normal there.
    """

    point: np.ndarray
    normal: np.ndarray
    mirror: np.ndarray
    distance: np.ndarray
    footprint: np.ndarray
    cos_incidence: np.ndarray


def mirror_highlights(
    points: np.ndarray, normals: np.ndarray, eye: np.ndarray, centre: np.ndarray, radius: float
) -> Highlights:
    """Paper §3.2 step 2: the light position that puts a highlight on each point is where the mirror
    reflection of the view direction about the normal meets S (points must lie inside S)."""
    view = unit_rows(eye - points)
    mirror = unit_rows(2.0 * np.einsum("ij,ij->i", normals, view)[:, None] * normals - view)
    rel = points - centre
    b = np.einsum("ij,ij->i", mirror, rel)
    c = np.einsum("ij,ij->i", rel, rel) - radius * radius  # < 0 inside S
    t = -b + np.sqrt(b * b - c)
    hit = rel + t[:, None] * mirror
    footprint = hit / radius
    return Highlights(points, normals, mirror, t, footprint, np.einsum("ij,ij->i", mirror, footprint))
