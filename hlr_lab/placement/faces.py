"""An object resting on another face than the plan's (a bunny on its side): which of the mesh's stable
resting poses it is in.

When the outlines do not find the object standing as planned (:func:`hlr_lab.placement.solve.register`
refuses), the likeliest stable poses of the mesh (trimesh's ``poses.compute_stable_poses``: the faces of its
convex hull it can rest on, with how likely a drop lands on each) are tried in turn, each as the nominal
placement the search starts from — centred on the axis and resting on the plate as the plan's is — and the
one whose outlines fit best is taken. None fitting, the refusal names what was tried.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import trimesh

from hlr_lab.errors import PlacementError
from hlr_lab.geometry.camera import Camera
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.placement.photographs import ObservedView
from hlr_lab.placement.pose import PlacementFrame
from hlr_lab.placement.solve import YAW_STEP_DEG, Outlines, Registration, register

RESTS_TRIED = 4  # the likeliest other stable poses tried (the bunny has 17; the first four hold 65 %)
SAME_FACE_DEG = 10.0  # a stable pose whose up direction is this close to the plan's is the plan's face


@dataclass(frozen=True, eq=False)
class Rest:
    """Where the object was found resting: the registration, its outlines, and — when not on the plan's
    face — which stable pose (its rank by likelihood, 0 the likeliest) and its probability."""

    found: Registration
    outlines: Outlines
    pose_rank: int | None = None
    probability: float | None = None

    def describe(self) -> str | None:
        """A sentence for the record when it rests on another face; None on the plan's."""
        if self.pose_rank is None:
            return None
        return (
            f"resting on another face than the plan's: the mesh's stable pose {self.pose_rank} (a drop lands so "
            f"with probability {self.probability:.2f})"
        )


def register_on_faces(
    mesh: ColouredMesh,
    camera: Camera,
    nominal: np.ndarray,
    views: list[ObservedView],
    scale: float,
    *,
    yaw_step_deg: float = YAW_STEP_DEG,
) -> Rest:
    """Register ``views`` standing as ``nominal`` (4, 4) mesh → turntable says; failing that, resting on
    another of the mesh's stable faces (``scale``: mesh units → metres). :class:`PlacementError` when no face
    fits, naming the plan's refusal and the faces tried. ``yaw_step_deg``: the search's (:func:`register`)."""
    planned = Outlines(mesh, camera, PlacementFrame.about(mesh.vertices, nominal), views)
    try:
        return Rest(register(planned, yaw_step_deg=yaw_step_deg), planned)
    except PlacementError as as_planned:
        refusal = as_planned
    fits: list[Rest] = []
    tried = []
    for rank, placed, probability in itertools.islice(other_rests(mesh, nominal, scale), RESTS_TRIED):
        tried.append(f"{rank} (p = {probability:.2f})")
        outlines = Outlines(mesh, camera, PlacementFrame.about(mesh.vertices, placed), views)
        try:
            fits.append(
                Rest(register(outlines, yaw_step_deg=yaw_step_deg), outlines, rank, float(probability))
            )
        except PlacementError:
            continue
    if not fits:
        raise PlacementError(
            f"{refusal} — nor does it rest on another of the mesh's faces (tried its stable poses "
            f"{', '.join(tried) or 'none: it has no other'})"
        )
    return min(fits, key=lambda r: r.found.residual_px)


def other_rests(
    mesh: ColouredMesh, nominal: np.ndarray, scale: float
) -> Iterator[tuple[int, np.ndarray, float]]:
    """The mesh's stable resting poses other than the one ``nominal`` (4, 4) stands it in, likeliest first:
    each one's rank among all of them, its mesh → turntable (4, 4: centred on the axis, resting on the
    plate, ``scale`` mesh units → metres) and the probability that a drop lands on it."""
    transforms, probabilities = trimesh.poses.compute_stable_poses(mesh.trimesh)
    up = _mesh_up(nominal)
    for rank, (rest, probability) in enumerate(zip(transforms, probabilities, strict=True)):
        placed = _resting(mesh, rest, scale)
        if np.degrees(np.arccos(np.clip(_mesh_up(placed) @ up, -1, 1))) >= SAME_FACE_DEG:
            yield rank, placed, float(probability)


def _mesh_up(placement: np.ndarray) -> np.ndarray:
    """(3,) the mesh-frame direction ``placement`` (4, 4) turns to the turntable's +z."""
    up = placement[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    return up / np.linalg.norm(up)


def _resting(mesh: ColouredMesh, rest: np.ndarray, scale: float) -> np.ndarray:
    """(4, 4) mesh → turntable: the stable pose ``rest`` (mesh units, resting on z = 0) scaled to metres,
    its bounding box centred on the axis and resting on the plate (as the plan places its object)."""
    m = np.diag([scale, scale, scale, 1.0]) @ rest
    v = mesh.vertices @ m[:3, :3].T + m[:3, 3]
    lo, hi = v.min(axis=0), v.max(axis=0)
    m[:3, 3] -= [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
    return m
