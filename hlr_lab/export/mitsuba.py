"""A Mitsuba 3 scene: a PLY per region, a ``roughplastic`` BSDF each (Beckmann, α = √(2/(n+2)),
diffuse_reflectance = Rd, and F0 = 8 Rs/(n+8) carried by ``int_ior`` — the IOR whose normal-incidence
Fresnel is the largest channel's F0 — with ``specular_reflectance`` = F0 / that maximum, since Mitsuba
takes reflectances in [0, 1] only), a point light and a camera framing the object, so that
``mitsuba scene.xml`` renders a preview straight away."""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
import trimesh
from trimesh.exchange.ply import export_ply

from hlr_lab.errors import InputError
from hlr_lab.export.conversion import MITSUBA_PLASTIC_IOR, beckmann_alpha, ior_for_f0, specular_f0
from hlr_lab.export.regions import RegionPart
from hlr_lab.files import atomic_write_all

_HEADER = "hlr-lab export"  # the comment that opens every scene.xml hlr-lab writes


def mitsuba_files(folder: Path, parts: list[RegionPart]) -> list[Path]:
    """The files :func:`write_mitsuba` writes into ``folder``: ``scene.xml``, then a PLY per region. Refuses
    (:class:`InputError`) a ``folder`` that is a file, and a ``scene.xml`` there that hlr-lab did not write."""
    if folder.exists() and not folder.is_dir():
        raise InputError("a mitsuba export is a folder (scene.xml, meshes/): give a folder", path=folder,
                         field="--output")  # fmt: skip
    scene = folder / "scene.xml"
    if scene.is_file() and not _ours(scene):
        raise InputError(f"the export would replace {scene}, which hlr-lab did not write: give another folder",
                         path=folder, field="--output")  # fmt: skip
    return [scene, *(folder / "meshes" / f"{p.name}.ply" for p in parts)]


def write_mitsuba(folder: str | Path, parts: list[RegionPart]) -> list[Path]:
    """Write ``folder/scene.xml`` and ``folder/meshes/region_<id>.ply``, all or none (the meshes go in
    first: a scene is never left naming a missing one); returns the paths, scene.xml first."""
    scene, *plys = mitsuba_files(Path(folder), parts)
    meshes = [
        export_ply(trimesh.Trimesh(p.vertices, p.faces, vertex_normals=p.normals, process=False),
                   encoding="binary", vertex_normal=True)
        for p in parts
    ]  # fmt: skip
    pts = np.concatenate([p.vertices for p in parts])
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    radius = float(np.linalg.norm(pts - centre, axis=1).max())
    eye, light = centre + radius * np.array([0.0, -4.0, 1.5]), centre + radius * np.array([2.0, -3.0, 3.0])
    body = [_bsdf(p) for p in parts] + [
        f'  <shape type="ply" id="shape_{p.name}">\n    <string name="filename" value="meshes/{p.name}.ply"/>\n'
        f'    <ref id="{p.name}"/>\n  </shape>'
        for p in parts
    ]
    xml = f"""<?xml version="1.0" encoding="utf-8"?>
<!-- {_HEADER}: {len(parts)} regions. Blinn-Phong fits converted to roughplastic (hlr_lab.export.conversion);
     the exact fitted values are in the comment above each BSDF. The camera and light are a preview. -->
<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="{np.degrees(2 * np.arctan(1.2 / 4.3)):.3f}"/>
    <transform name="to_world"><lookat origin="{_xyz(eye)}" target="{_xyz(centre)}" up="0, 0, 1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="64"/></sampler>
    <film type="hdrfilm"><integer name="width" value="640"/><integer name="height" value="480"/></film>
  </sensor>
  <emitter type="point">
    <point name="position" value="{_xyz(light)}"/>
    <rgb name="intensity" value="{(radius * 4.7) ** 2:.6g}"/>
  </emitter>
  <emitter type="constant"><rgb name="radiance" value="0.05"/></emitter>
{chr(10).join(body)}
</scene>
"""
    atomic_write_all([*zip(plys, meshes, strict=True), (scene, xml.encode())])
    return [scene, *plys]


def _bsdf(p: RegionPart) -> str:
    f0 = specular_f0(p.rs, p.n)
    peak = float(f0.max())
    ior = ior_for_f0(peak) if peak > 0 else MITSUBA_PLASTIC_IOR
    scale = f0 / peak if peak > 0 else np.zeros(3)
    fitted = escape(
        f"rd {np.round(p.rd, 6).tolist()} rs {np.round(p.rs, 6).tolist()} n {p.n:.4g}"
        + ("" if p.measured else " (specular not measured)")
        + (
            " STAND-IN: no material was fitted for this region; its colour, diffuse only"
            if p.stand_in
            else ""
        )
    )
    return f"""  <!-- {fitted} -->
  <bsdf type="roughplastic" id="{p.name}">
    <string name="distribution" value="beckmann"/>
    <float name="alpha" value="{beckmann_alpha(p.n):.6g}"/>
    <float name="int_ior" value="{ior:.6g}"/>
    <rgb name="diffuse_reflectance" value="{_xyz(np.clip(p.rd, 0, 1))}"/>
    <rgb name="specular_reflectance" value="{_xyz(scale)}"/>
  </bsdf>"""


def _ours(scene: Path) -> bool:
    try:
        with scene.open("rb") as f:
            return _HEADER.encode() in f.read(200)
    except OSError:
        return False


def _xyz(v) -> str:
    return ", ".join(f"{x:.6g}" for x in v)
