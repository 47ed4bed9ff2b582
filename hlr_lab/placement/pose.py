"""A placement as six numbers: a turn (rotation vector, degrees) about the planned object's centre, then a
shift (millimetres) along the turntable frame's axes, applied after the plan's mesh → turntable transform.

Centred on the object so that a turn does not move it across the plate (the numbers are then nearly
independent, which the refinement and the standard errors need); rotations through scipy's ``Rotation``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True, eq=False)
class PlacementFrame:
    """What a placement is relative to: the plan's mesh → turntable transform ``nominal`` (4, 4) and the
    planned object's centre ``centre`` (3,) in the turntable frame (metres)."""

    nominal: np.ndarray
    centre: np.ndarray

    @classmethod
    def about(cls, vertices: np.ndarray, nominal: np.ndarray) -> PlacementFrame:
        """The frame about the centre (the vertices' mean) of ``vertices`` (N, 3, mesh frame) placed as
        ``nominal`` (4, 4) mesh → turntable says."""
        return cls(nominal, (vertices @ nominal[:3, :3].T + nominal[:3, 3]).mean(axis=0))

    def matrix(self, params: np.ndarray) -> np.ndarray:
        """(4, 4) mesh → turntable for ``params`` (6,): rotation vector (degrees) about ``centre``, then the
        shift (mm)."""
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_rotvec(np.radians(params[:3])).as_matrix()
        turn[:3, 3] = self.centre + params[3:] / 1000 - turn[:3, :3] @ self.centre
        return turn @ self.nominal

    def params(self, mesh_to_turntable: np.ndarray) -> np.ndarray:
        """(6,) the inverse of :meth:`matrix` for a rigid ``mesh_to_turntable`` (4, 4) of the same scale."""
        turn = mesh_to_turntable @ np.linalg.inv(self.nominal)
        rotvec = np.degrees(Rotation.from_matrix(turn[:3, :3]).as_rotvec())
        shift = turn[:3, 3] - self.centre + turn[:3, :3] @ self.centre
        return np.concatenate([rotvec, 1000 * shift])


def nudged(params: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(6,) the placement ``params`` (6,) turned further by ``delta[:3]`` (a rotation vector in degrees about the
    turntable's axes, through the object's centre) and shifted by ``delta[3:]`` (mm): the local coordinates
    in which a registration states its standard errors. (A rotation vector's own components are turns about
    the axes only near zero, and a placement turned 345° is one turned −15°.)"""
    turn = Rotation.from_rotvec(np.radians(delta[:3])) * Rotation.from_rotvec(np.radians(params[:3]))
    return np.concatenate([np.degrees(turn.as_rotvec()), params[3:] + delta[3:]])


def local_difference(params: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(6,) the ``delta`` that :func:`nudged` takes ``reference`` (6,) to ``params`` (6,) with: how far one
    placement lies from another, turn (degrees, about the turntable's axes) and shift (mm)."""
    turn = (
        Rotation.from_rotvec(np.radians(params[:3])) * Rotation.from_rotvec(np.radians(reference[:3])).inv()
    )
    return np.concatenate([np.degrees(turn.as_rotvec()), params[3:] - reference[3:]])


def yaw_params(yaw_deg: float, shift_mm: np.ndarray) -> np.ndarray:
    """(6,) a turn of ``yaw_deg`` about the vertical through the centre, then ``shift_mm`` (3,)."""
    return np.concatenate([[0.0, 0.0, yaw_deg], shift_mm])


def vertex_errors_mm(vertices: np.ndarray, estimated: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(V,) how far each mesh vertex (V, 3) lies from where it really is (mm): ``estimated`` and ``true``
    are (4, 4) mesh → turntable."""
    a = vertices @ estimated[:3, :3].T + estimated[:3, 3]
    b = vertices @ true[:3, :3].T + true[:3, 3]
    return 1000 * np.linalg.norm(a - b, axis=1)


def rotation_error_deg(estimated: np.ndarray, true: np.ndarray) -> float:
    """The angle (degrees) of the rotation between two (4, 4) placements (their 3×3 parts, scale removed)."""
    a = estimated[:3, :3] / np.cbrt(np.linalg.det(estimated[:3, :3]))
    b = true[:3, :3] / np.cbrt(np.linalg.det(true[:3, :3]))
    return float(np.degrees(Rotation.from_matrix(a @ b.T).magnitude()))
