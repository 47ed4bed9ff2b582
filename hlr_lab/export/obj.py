"""OBJ + MTL: one ``usemtl`` group per region; Kd, Ks, Ns per region."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hlr_lab.export.regions import RegionPart
from hlr_lab.files import atomic_write_text

MTL_HEADER = """\
# hlr-lab materials, one per colour region.
# Kd, Ks: linear RGB reflectances of hlr-lab's model I = L (Kd cos(alpha) + Ks cos(beta)^Ns),
# beta the angle between the normal and the half vector: Ns is a Blinn-Phong exponent, unnormalised
# (a Phong R.V exponent is about Ns / 4). Regions whose highlight was not measured have Ks 0.
"""


def write_obj(path: str | Path, parts: list[RegionPart]) -> list[Path]:
    """Write ``path`` (.obj) and the .mtl beside it; returns both paths."""
    path = Path(path)
    mtl = path.with_suffix(".mtl")
    lines = [f"# hlr-lab export: {len(parts)} regions", f"mtllib {mtl.name}"]
    offset = 0
    groups = []
    for part in parts:
        lines.append(_rows("v", part.vertices))
        lines.append(_rows("vn", part.normals))
        f = part.faces + offset + 1
        groups.append(
            f"g {part.name}\nusemtl {part.name}\n"
            + "\n".join(f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in f.tolist())
        )
        offset += len(part.vertices)
    atomic_write_text(path, "\n".join(lines + groups) + "\n")
    atomic_write_text(mtl, MTL_HEADER + "\n".join(_material(p) for p in parts))
    return [path, mtl]


def _rows(tag: str, a: np.ndarray) -> str:
    return "\n".join(f"{tag} {x:.9g} {y:.9g} {z:.9g}" for x, y, z in a.tolist())


def _material(p: RegionPart) -> str:
    kd, ks = (" ".join(f"{x:.6f}" for x in c) for c in (p.rd, p.rs))
    note = (
        "# STAND-IN: no material was fitted for this region; its colour, diffuse only\n"
        if p.stand_in
        else ""
        if p.measured
        else "# specular not measured: diffuse only\n"
    )
    return f"\nnewmtl {p.name}\n{note}Kd {kd}\nKs {ks}\nNs {p.n:.4f}\nillum 2\n"
