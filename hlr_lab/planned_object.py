"""The object a plan was made for: its mesh, found from the plan's reference and checked by sha256, and
placed on the turntable as the plan placed it. Acquisition, the simulated world and fitting all start
from here, so a mesh that changed after planning is refused in one place."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile
from hlr_lab.mesh import ColouredMesh, load_mesh
from hlr_lab.procedural import BUILTIN_PREFIX, builtin_object


def load_planned_mesh(plan: PlanFile, plan_path: Path) -> ColouredMesh:
    """The plan's mesh in its own frame; paths in the plan are relative to the plan file."""
    ref = plan.object.mesh
    if ref.startswith(BUILTIN_PREFIX):
        mesh = builtin_object(ref).mesh
    else:
        texture = None if plan.object.texture is None else plan_path.parent / plan.object.texture
        mesh = load_mesh(plan_path.parent / ref, texture)
    if mesh.sha256 != plan.object.sha256:
        raise InputError(
            f"the mesh {ref} has changed since the plan was made (sha256 differs); plan again",
            path=plan_path,
            field="object.sha256",
        )
    return mesh


def mesh_to_turntable(plan: PlanFile) -> np.ndarray:
    """4×4: the plan's placement of the mesh on the turntable (identity for old plans without one)."""
    return np.array(plan.object.mesh_to_turntable or np.eye(4), dtype=np.float64)
