"""Where a command may write (docs/sessions.md, "Outputs never destroy inputs"): never over one of its own
inputs, never over a session's own files, never twice in one command, never under a name that cannot be
written.

A mistyped ``-o`` must not cost a night's measurement: ``fit S -o S/journal.jsonl`` would replace the
journal with materials, ``segment --mesh m.ply -o m.ply`` the mesh with its regions, ``export -o spot.obj``
the input mesh and its .mtl. Every command that writes hands its outputs (with their companions: the
diagnostics beside materials.json, an OBJ's .mtl) and its inputs to :func:`check_outputs` before it does
its work, so a refused output costs nothing and leaves nothing half-written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from hlr_lab.errors import InputError
from hlr_lab.files import LINK_REFUSED
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.session.folder import FOLDERS, OWN_FILES, SESSION
from hlr_lab.session.journal import JOURNAL
from hlr_lab.session.kept_object import companions

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")  # a line break in a name breaks every file that names it


def has_control_character(name: str) -> bool:
    """Whether ``name`` holds a control character (a line break, a tab, a NUL): no output may."""
    return _CONTROL.search(name) is not None


def check_outputs(
    outputs: Sequence[Path],
    inputs: Iterable[str | Path | None] = (),
    *,
    field: str | None = "--output",
    writes: Sequence[str | None] | None = None,
) -> None:
    """Refuse (:class:`InputError` naming the output and ``field``) to write any of ``outputs`` — the files
    one command is about to write — when it is one of ``inputs`` (the same file by any name, hard links
    included), a symbolic link, a file of a session (its journal, session.json, lock, log, reserve, anything in its
    ``frames/`` or ``object/``), another of ``outputs`` (two files of the command under one name), an
    existing folder, or a name with a control character (a line break, a NUL). ``inputs`` may hold
    ``None`` and ``builtin:`` names (skipped).

    ``writes``: what each output is, its hlr-lab format (``"hlr-lab.materials"``) or None for any other
    file (a report, a mesh); an existing file that declares another hlr-lab format is then refused too
    (``report S -o plan.json`` would replace the plan a resumed run needs). Without it, not checked."""
    taken: dict[str, Path] = {}
    for output in outputs:
        if has_control_character(str(output)):
            raise InputError(
                "has a control character (a line break, a tab, …) in its name, which the files naming it cannot "
                "carry: give a plain name",
                path=repr(str(output))[1:-1],
                field=field,
            )
        if output.is_symlink():  # writing through it would redirect the write; replacing it, break the link
            raise InputError(LINK_REFUSED, path=output, field=field)
        if output.is_dir():
            raise InputError("is a folder: name a file to write (or move the folder away)", path=output,
                             field=field)  # fmt: skip
        real = os.path.realpath(output)
        if real in taken:
            raise InputError(f"is written twice by this command (also as {taken[real]}): give another name",
                             path=output, field=field)  # fmt: skip
        taken[real] = output
        _refuse_session_file(output, real, field)
    for source in inputs:
        if source is None or str(source).startswith("builtin:"):
            continue
        for output in outputs:
            if _same_file(output, Path(source)):
                raise InputError(
                    f"is also this command's input ({source}): writing it would destroy it; give another output",
                    path=output,
                    field=field,
                )
    if writes is None:  # what each output is was not said: not checked
        return
    for output, kind in zip(outputs, writes, strict=True):  # last: an input or a session file says more
        found = declared_format(output)
        if found is not None and found != kind:
            what = f"an {kind} file" if kind else "a file of another kind"
            raise InputError(
                f"is an {found} file, and this command would write {what} over it: give another output (or move "
                "the file away first)",
                path=output,
                field=field,
            )


# the hlr-lab file an existing file is: a JSON file's first key, a rig file's [rig] format (after its comments)
_DECLARED = re.compile(
    rb'\A\s*\{\s*"format"\s*:\s*"(hlr-lab\.[a-z-]+)"|^format\s*=\s*"(hlr-lab\.[a-z-]+)"', re.M
)
_HEAD = 16384  # bytes read: a rig file's comments come before its format line


def declared_format(path: Path) -> str | None:
    """The hlr-lab format (``"hlr-lab.plan"``, …) an existing regular file declares at its head, or None
    (also for anything but a regular file: reading a FIFO would block)."""
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(_HEAD)
    except OSError:  # not there, or not readable: nothing to protect that hlr-lab could tell
        return None
    found = _DECLARED.search(head)
    return None if found is None else (found.group(1) or found.group(2)).decode()


def mesh_files(mesh: ColouredMesh) -> list[Path]:
    """The files ``mesh`` was read from: the mesh file, its texture, and what the mesh names (an OBJ's
    .mtl and its images, a glTF's buffers and images). [] for a built-in object."""
    if mesh.source is None:
        return []
    named = [mesh.source.parent / name for name in companions(mesh.source)]
    return [mesh.source, *([mesh.texture_source] if mesh.texture_source else []), *named]


def _refuse_session_file(output: Path, real: str, field: str | None) -> None:
    path = Path(real)
    for folder in path.parents:
        if not ((folder / SESSION).is_file() or (folder / JOURNAL).is_file()):
            continue
        parts = path.relative_to(folder).parts
        if parts[0] in FOLDERS or (len(parts) == 1 and parts[0] in OWN_FILES):
            raise InputError(
                f"is one of the session {folder}'s own files (docs/sessions.md), which a command never writes "
                "over: give another output",
                path=output,
                field=field,
            )


def _same_file(a: Path, b: Path) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)  # another name of the same file: a hard link
    except OSError:
        return False  # one of them does not exist (yet)
