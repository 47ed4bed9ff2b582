"""The mesh split by region, with each region's material, as every exporter needs it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.geometry.colour import delta_e, srgb8_to_lab, srgb8_to_linear
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.segment import Segmentation

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
    stand_in: bool = False  # no material was fitted: the region's own colour, diffuse only

    @property
    def name(self) -> str:
        """The part's (and its material's) name in every export; a stand-in says so in it."""
        return f"region_{self.id}" + ("_stand_in_not_measured" if self.stand_in else "")


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
        measured = m.specular == "measured"
        rs, n = np.zeros(3), 1.0
        if measured:
            assert m.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert m.n is not None
            rs, n = np.array(m.rs), float(m.n)
        parts.append(_part(mesh, seg, m.id, np.array(m.rd), rs, n, measured))
    # every face is exported: a region the fit gave no material (too few pixels, never seen) gets its
    # colour as a diffuse-only stand-in, named as such (RegionPart.name) — never a hole in the object
    fitted = {m.id for m in materials.regions}
    for region in seg.regions:
        if region.id not in fitted and np.any(seg.face_labels == region.id):
            colour = srgb8_to_linear(np.array(region.colour, float))
            parts.append(_part(mesh, seg, region.id, colour, np.zeros(3), 1.0, False, stand_in=True))
    return parts


def stand_ins(parts: list[RegionPart]) -> list[int]:
    """The ids of the regions exported with a stand-in material."""
    return [p.id for p in parts if p.stand_in]


def _part(mesh: ColouredMesh, seg: Segmentation, rid: int, rd, rs, n: float, measured: bool, *,
          stand_in: bool = False) -> RegionPart:  # fmt: skip
    faces = mesh.faces[seg.face_labels == rid]
    used, local = np.unique(faces, return_inverse=True)
    return RegionPart(rid, mesh.vertices[used], mesh.vertex_normals[used], local.reshape(-1, 3), rd, rs, n,
                      measured, stand_in)  # fmt: skip
