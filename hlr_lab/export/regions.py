"""The mesh split by region, with each region's material, as every exporter needs it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.colour import delta_e, srgb8_to_lab
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.mesh import ColouredMesh
from hlr_lab.segment import Segmentation

MATCH_DELTA_E = 10.0  # a materials region and a segmentation region of the same id must look alike


@dataclass(frozen=True, eq=False)
class RegionPart:
    """One region's own copy of the mesh: vertices (V, 3), normals (V, 3), faces (F, 3) into them; and its
    material: rd (3,), rs (3,) (zeros when unmeasured), n, and whether the specular was measured."""

    id: int
    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    rd: np.ndarray
    rs: np.ndarray
    n: float
    measured: bool

    @property
    def name(self) -> str:
        return f"region_{self.id}"


def region_parts(
    mesh: ColouredMesh, seg: Segmentation, materials: MaterialsFile, *, source: str
) -> list[RegionPart]:
    """Split ``mesh`` by ``seg``'s face labels and attach ``materials``; refuses a mismatch."""
    by_id = {r.id: r for r in seg.regions}
    parts = []
    for m in materials.regions:
        region = by_id.get(m.id)
        if region is None:
            raise InputError(
                f"region {m.id} is not in the mesh's segmentation ({len(by_id)} regions); pass the "
                "--regions file the session was made with",
                path=source,
                field=f"regions[{m.id}]",
            )
        d = float(delta_e(srgb8_to_lab(np.array(m.color)), srgb8_to_lab(np.array(region.colour))))
        if d > MATCH_DELTA_E:
            raise InputError(
                f"region {m.id} has colour {m.color} here but {list(region.colour)} on the mesh "
                f"(ΔE {d:.0f}); pass the --regions file the session was made with",
                path=source,
                field=f"regions[{m.id}].color",
            )
        faces = mesh.faces[seg.face_labels == m.id]
        used, local = np.unique(faces, return_inverse=True)
        measured = m.specular == "measured"
        parts.append(
            RegionPart(
                m.id,
                mesh.vertices[used],
                mesh.vertex_normals[used],
                local.reshape(-1, 3),
                np.array(m.rd),
                np.array(m.rs) if measured else np.zeros(3),
                float(m.n) if measured else 1.0,
                measured,
            )
        )
    return parts
