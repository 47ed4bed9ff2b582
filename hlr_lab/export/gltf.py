"""glTF 2.0 binary (.glb): one mesh with a primitive per region, PBR metallic-roughness materials.

Conversion (see ``conversion``): baseColorFactor = Rd, metallicFactor = 0, roughnessFactor =
(2/(n+2))^¼, and KHR_materials_specular with specularColorFactor = F0/0.04, F0 = 8 Rs/(n+8). The exact
fitted values are kept in each material's ``extras.hlr_lab``.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from hlr_lab.export.conversion import GLTF_DIELECTRIC_F0, gltf_roughness, specular_f0
from hlr_lab.export.regions import RegionPart
from hlr_lab.files import atomic_write_bytes

_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def write_gltf(path: str | Path, parts: list[RegionPart]) -> list[Path]:
    """Write one binary glTF 2.0 file (.glb): one primitive and one PBR material per region part;
    returns the files written (the .glb alone)."""
    path = Path(path)
    blob = bytearray()
    views, accessors, primitives, materials = [], [], [], []

    def add(data: np.ndarray, target: int, component: int, kind: str, minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": data.nbytes, "target": target})
        blob.extend(data.tobytes())
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": len(data), "type": kind}
        if minmax:
            acc["min"], acc["max"] = data.min(axis=0).tolist(), data.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    for i, p in enumerate(parts):
        pos = add(p.vertices.astype(np.float32), _ARRAY_BUFFER, _FLOAT, "VEC3", minmax=True)
        nrm = add(p.normals.astype(np.float32), _ARRAY_BUFFER, _FLOAT, "VEC3")
        idx = add(p.faces.astype(np.uint32).ravel(), _ELEMENT_ARRAY_BUFFER, _UINT, "SCALAR")
        primitives.append({"attributes": {"POSITION": pos, "NORMAL": nrm}, "indices": idx, "material": i})
        materials.append(_material(p))
    doc = {
        "asset": {"version": "2.0", "generator": "hlr-lab"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "object"}],
        "meshes": [{"primitives": primitives, "name": "object"}],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    atomic_write_bytes(path, _glb(json.dumps(doc).encode(), bytes(blob)))
    return [path]


def _material(p: RegionPart) -> dict:
    f0 = specular_f0(p.rs, p.n)
    return {
        "name": p.name,
        **(
            {"extras": {"hlr_lab": "stand-in: no material was fitted; its colour, diffuse only"}}
            if p.stand_in
            else {}
        ),
        "pbrMetallicRoughness": {
            "baseColorFactor": [*map(float, np.clip(p.rd, 0, 1)), 1.0],
            "metallicFactor": 0.0,
            "roughnessFactor": gltf_roughness(p.n),
        },
        "extensions": {
            "KHR_materials_specular": {
                "specularFactor": 1.0,
                "specularColorFactor": (f0 / GLTF_DIELECTRIC_F0).tolist(),
            }
        },
        "extras": {
            "hlr_lab": {
                "model": "blinn-phong",
                "rd": p.rd.tolist(),
                "rs": p.rs.tolist(),
                "n": p.n,
                "specular": "measured" if p.measured else "unmeasured",
            }
        },
    }


def _glb(json_chunk: bytes, bin_chunk: bytes) -> bytes:
    json_chunk += b" " * (-len(json_chunk) % 4)
    bin_chunk += b"\0" * (-len(bin_chunk) % 4)
    total = 12 + 8 + len(json_chunk) + 8 + len(bin_chunk)
    return (
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<I4s", len(json_chunk), b"JSON")
        + json_chunk
        + struct.pack("<I4s", len(bin_chunk), b"BIN\0")
        + bin_chunk
    )
