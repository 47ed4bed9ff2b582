"""OBJ + MTL: one ``usemtl`` group per region; Kd, Ks, Ns per region."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.export.regions import RegionPart
from hlr_lab.files import atomic_write_all

MTL_HEADER = """\
# hlr-lab materials, one per colour region.
# Kd, Ks: linear RGB reflectances of hlr-lab's model I = L (Kd cos(alpha) + Ks cos(beta)^Ns),
# beta the angle between the normal and the half vector: Ns is a Blinn-Phong exponent, unnormalised
# (a Phong R.V exponent is about Ns / 4). Regions whose highlight was not measured have Ks 0.
"""


def obj_files(path: Path, parts: list[RegionPart]) -> list[Path]:
    """The files :func:`write_obj` writes for ``path``: the OBJ and its .mtl. Refuses (:class:`InputError`) a
    name the OBJ cannot carry on its ``mtllib`` line (readers split it at spaces), and a .mtl already
    there that hlr-lab did not write (the user named the OBJ, not the library beside it)."""
    del parts  # one .mtl whatever the regions
    mtl = path.with_suffix(".mtl")
    if re.search(r"\s", mtl.name):
        raise InputError(
            f"the OBJ names its material library ({mtl.name}) on its mtllib line, which readers split at spaces: "
            "give a name without spaces",
            path=path,
            field="--output",
        )
    if mtl.is_file() and not _ours(mtl):
        raise InputError(
            f"the OBJ's material library would replace {mtl}, which hlr-lab did not write: move it, or give "
            "another name",
            path=path,
            field="--output",
        )
    return [path, mtl]


def write_obj(path: str | Path, parts: list[RegionPart]) -> list[Path]:
    """Write ``path`` (.obj) and the .mtl beside it, both or neither (the library goes in first: an OBJ
    is never left naming a missing one); returns both paths."""
    path, mtl = obj_files(Path(path), parts)
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
    library = MTL_HEADER + "\n".join(_material(p) for p in parts)
    atomic_write_all([(mtl, library.encode()), (path, ("\n".join(lines + groups) + "\n").encode())])
    return [path, mtl]


def _ours(mtl: Path) -> bool:
    try:
        with mtl.open("rb") as f:
            return f.readline().rstrip(b"\n") == MTL_HEADER.splitlines()[0].encode()
    except OSError:
        return False


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
