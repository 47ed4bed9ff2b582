"""The files a mesh file names, which a reader loads with it: an OBJ's ``mtllib`` libraries and the
images those name, a glTF's external buffers and images (PLY and GLB carry everything in one file)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from hlr_lab.errors import InputError
from hlr_lab.files import SPECIAL_REFUSED


def named_files(mesh: Path) -> list[str]:
    """The names ``mesh`` gives its companions, as written (relative to its folder, unless absolute),
    first occurrence first; [] for a format without companions or a file that cannot be read."""
    suffix = mesh.suffix.lower()
    if suffix == ".obj":
        libraries = _names(mesh, r"^[ \t]*mtllib[ \t]+(.+?)[ \t]*$")
        images = [
            i
            for lib in libraries
            for i in _names(mesh.parent / lib, r"^[ \t]*(?:map_\w+|bump|disp|norm)[ \t].*?(\S+)[ \t]*$")
        ]
        return list(dict.fromkeys(libraries + images))
    if suffix == ".gltf":
        try:
            doc = json.loads(_text(mesh))
        except (OSError, ValueError):
            return []
        if not isinstance(doc, dict):
            return []
        found = [
            str(item["uri"])
            for key in ("buffers", "images")
            for item in (doc.get(key) or [])
            if isinstance(item, dict)
            and isinstance(item.get("uri"), str)
            and not item["uri"].startswith("data:")
        ]
        return list(dict.fromkeys(found))
    return []


def refuse_special_companions(mesh: Path) -> None:
    """Refuse (:class:`InputError` naming both) a companion of ``mesh`` that exists but is not a regular
    file: a FIFO named by ``map_Kd`` would block the mesh reader forever."""
    for name in named_files(mesh):
        target = mesh.parent / name.replace("\\", "/")
        if target.exists() and not target.is_file():
            raise InputError(f"names {name}, which {SPECIAL_REFUSED.removeprefix('is ')}", path=mesh)


def _names(path: Path, pattern: str) -> list[str]:
    """Every first group of ``pattern`` over the lines of the text file ``path`` ([] when unreadable)."""
    try:
        text = _text(path)
    except OSError:
        return []
    return [m.group(1) for m in re.finditer(pattern, text, flags=re.MULTILINE)]


def _text(path: Path) -> str:
    if not path.is_file():  # a FIFO or a device is not read (it would block, or never end)
        raise FileNotFoundError(path)
    return path.read_text(encoding="utf-8", errors="replace")
