"""``regions.json``: the output of ``hlr-lab segment`` — per-vertex and per-face region labels of one mesh.

```json
{"format": "hlr-lab.regions", "version": 1,
 "mesh": "spot.obj", "sha256": "…", "texture": "spot.png", "texture_sha256": "…",
 "parameters": {"delta_e": 10.0, "min_fragment": 0.001, "split_connected": false, "regions_requested": null},
 "regions": [{"id": 0, "color": [252, 235, 227], "vertices": 1968, "faces": 3910, "area_m2": 3.75, "material": 0}],
 "vertex_labels": [0, 0, 3, …], "face_labels": [0, 2, …]}
```
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from hlr_lab.errors import InputError
from hlr_lab.files import OpenModel, StrictModel, as_triple, read_format, write_json
from hlr_lab.object.mesh import ColouredMesh, file_sha256
from hlr_lab.object.segment import Region, Segmentation

REGIONS_FORMAT = "hlr-lab.regions"
Label = Annotated[int, Field(ge=0, le=2**31 - 1)]  # a region id (the range check against the regions follows)
Colour8 = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)]


class RegionEntry(OpenModel):
    """One same-colour region: its id, sRGB colour (0–255), size (vertices, faces, m²) and material."""

    id: int = Field(ge=0)
    color: Colour8
    vertices: int = Field(ge=0)
    faces: int = Field(default=0, ge=0)
    area_m2: float = Field(default=0.0, ge=0)
    material: int = Field(default=0, ge=0)

    @classmethod
    def of(cls, r: Region) -> RegionEntry:
        return cls(
            id=r.id,
            color=list(r.colour),
            vertices=r.vertices,
            faces=r.faces,
            area_m2=round(r.area_m2, 9),
            material=r.material,
        )


class SegmentParameters(StrictModel):
    """What the segmentation was run with (ΔE, the smallest fragment kept, patches split or not)."""

    delta_e: float
    min_fragment: float
    split_connected: bool
    regions_requested: int | None = None


class RegionsFile(StrictModel):
    """``regions.json`` (docs/formats.md): the mesh it belongs to, the regions, each vertex's and face's
    region."""

    format: Literal["hlr-lab.regions"]
    version: Literal[1]
    mesh: str
    sha256: str
    texture: str | None = None
    texture_sha256: str | None = None
    parameters: SegmentParameters
    regions: Annotated[list[RegionEntry], Field(min_length=1)]
    vertex_labels: list[Label]
    face_labels: list[Label]


def mesh_reference(mesh_path: Path | str, relative_to: Path) -> str:
    """How a file names the mesh: relative to the file's folder when below it, else absolute."""
    p = Path(mesh_path)
    if str(mesh_path).startswith("builtin:"):
        return str(mesh_path)
    try:
        return str(p.resolve().relative_to(relative_to.resolve()))
    except ValueError:
        return str(p.resolve())


def write_regions(
    path: str | Path, mesh: ColouredMesh, seg: Segmentation, *, mesh_name: str, regions_requested: int | None
) -> None:
    """Write ``regions.json`` for ``seg`` of ``mesh`` (named ``mesh_name`` in the file), in one piece."""
    path = Path(path)
    write_json(
        path,
        RegionsFile(
            format=REGIONS_FORMAT,
            version=1,
            mesh=mesh_reference(mesh_name, path.parent),
            sha256=mesh.sha256 or "",
            texture=None if mesh.texture_source is None else mesh_reference(mesh.texture_source, path.parent),
            texture_sha256=None if mesh.texture_source is None else file_sha256(mesh.texture_source),
            parameters=SegmentParameters(
                delta_e=seg.delta_e,
                min_fragment=seg.min_fragment,
                split_connected=seg.split_connected,
                regions_requested=regions_requested,
            ),
            regions=[RegionEntry.of(r) for r in seg.regions],
            vertex_labels=seg.vertex_labels.tolist(),
            face_labels=seg.face_labels.tolist(),
        ),
    )


def read_regions(path: str | Path, mesh: ColouredMesh) -> Segmentation:
    """Read a regions file made for ``mesh``; refuses one made for another mesh (sha256, counts)."""
    path = Path(path)
    f = read_format(path, REGIONS_FORMAT, RegionsFile)
    if mesh.sha256 and f.sha256 != mesh.sha256:
        raise InputError(
            f"made for another mesh ({f.mesh}, sha256 {f.sha256[:12]}…) than the one given "
            f"(sha256 {mesh.sha256[:12]}…); run hlr-lab segment on this mesh",
            path=path,
            field="sha256",
        )
    if len(f.vertex_labels) != len(mesh.vertices) or len(f.face_labels) != len(mesh.faces):
        raise InputError(
            f"has {len(f.vertex_labels)} vertex / {len(f.face_labels)} face labels but the mesh has "
            f"{len(mesh.vertices)} / {len(mesh.faces)}",
            path=path,
            field="vertex_labels",
        )
    ids = [r.id for r in f.regions]
    if ids != list(range(len(ids))):
        raise InputError("region ids must be 0, 1, 2, … in order", path=path, field="regions")
    v, fl = np.asarray(f.vertex_labels, np.int64), np.asarray(f.face_labels, np.int64)
    for name, labels in (("vertex_labels", v), ("face_labels", fl)):
        if len(labels) and (labels.min() < 0 or labels.max() >= len(ids)):
            raise InputError(f"labels must lie in 0…{len(ids) - 1}", path=path, field=name)
    regions = [
        Region(r.id, r.material, as_triple(r.color), r.vertices, r.faces, r.area_m2) for r in f.regions
    ]
    p = f.parameters
    return Segmentation(v, fl, regions, p.delta_e, p.split_connected, p.min_fragment)
