"""The plan a session was started with, and the files of its object, kept inside the session: a session
copied, moved, renamed or archived read-only is still fitted and reported from itself alone
(docs/sessions.md, "A session stands on its own").

``object/plan.json`` is the plan as acquired, its ``object.mesh`` and ``object.texture`` naming copies
beside it; a mesh's own companions (an OBJ's material library and the images it names, a glTF's
buffers and images) are copied next to the mesh under the names the mesh uses. ``session.json``
records the copy's sha256; the mesh is checked against the plan's sha256 when it is loaded, as always.
Built-in objects have no files to keep.
"""

from __future__ import annotations

import logging
from pathlib import Path, PurePosixPath

from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_bytes
from hlr_lab.formats.plan import PlanFile, read_plan, write_plan
from hlr_lab.object.companions import named_files
from hlr_lab.object.mesh import file_sha256
from hlr_lab.object.procedural import BUILTIN_PREFIX

log = logging.getLogger(__name__)
OBJECT = "object"  # the folder in the session
PLAN_COPY = f"{OBJECT}/plan.json"


def keep_object(session: Path, plan_path: Path) -> dict:
    """Copy the plan at ``plan_path`` and its object's files into ``session``/object; returns the session
    record's ``copy`` entry (``file``: the copied plan, relative to the session; ``sha256``: its)."""
    plan = read_plan(plan_path)
    folder = session / OBJECT
    folder.mkdir(parents=True, exist_ok=True)
    renamed: dict[str, str] = {}
    taken: set[str] = {"plan.json"}
    for field in ("mesh", "texture"):
        ref = getattr(plan.object, field)
        if ref is None or ref.startswith(BUILTIN_PREFIX):
            continue
        source = plan_path.parent / ref
        name = source.name if source.name not in taken else f"{field}-{source.name}"
        taken.add(name)
        _copy(source, folder / name, plan_path, f"object.{field}")
        renamed[field] = name
        if field == "mesh":
            for companion in companions(source):
                _copy(source.parent / companion, folder / companion, source, "a file the mesh names")
                taken.add(PurePosixPath(companion).parts[0])
    copy = plan.model_copy(update={"object": plan.object.model_copy(update=renamed)})
    write_plan(session / PLAN_COPY, copy)
    return {"file": PLAN_COPY, "sha256": file_sha256(session / PLAN_COPY)}


def kept_plan(session: Path, copy: object) -> tuple[PlanFile, Path]:
    """The session's own copy of its plan (``copy``: the record's entry, as :func:`keep_object` returned
    it) and its path, checked against the sha256 recorded when the session started."""
    if not isinstance(copy, dict) or copy.get("file") != PLAN_COPY or not isinstance(copy.get("sha256"), str):
        raise InputError(
            f"the record of the plan's copy is damaged (plan.copy: {copy!r}); restore session.json from a "
            "backup of the session",
            path=session / "session.json",
        )
    path = checked_file(session, PLAN_COPY, copy["sha256"], "copy of its plan", "the session started")
    return read_plan(path), path


def checked_file(session: Path, name: str, sha256: str, what: str, since: str) -> Path:
    """``session``/``name``, refused (:class:`InputError` saying ``what`` it is) when it is missing or its
    sha256 is no longer the one recorded when ``since``."""
    path = session / name
    if not path.is_file():
        raise InputError(
            f"the session's {what} ({name}) is missing; restore the session folder whole", path=session
        )
    if file_sha256(path) != sha256:
        raise InputError(
            f"the session's {what} ({name}) has changed since {since}; restore it from a backup of the session",
            path=session,
        )
    return path


def companions(mesh: Path) -> list[str]:
    """The files ``mesh`` names that a reader loads with it (:func:`hlr_lab.object.companions.named_files`),
    as relative POSIX paths under its folder. Names that leave the mesh's folder (absolute, or through
    ``..``) are not followed: such a mesh cannot be kept whole, and is logged as such."""
    kept = []
    for name in named_files(mesh):
        p = PurePosixPath(name.replace("\\", "/"))
        if p.is_absolute() or ".." in p.parts or not (mesh.parent / p).is_file():
            log.warning(
                "%s names %s, which is not kept with the session (outside its folder, or missing)", mesh, name
            )
            continue
        kept.append(str(p))
    return kept


def _copy(source: Path, target: Path, named_in: Path, field: str) -> None:
    try:
        data = source.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {source} to keep it with the session ({exc.strerror}); put it where "
                         "the plan says, or plan again", path=named_in, field=field) from exc  # fmt: skip
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(target, data)
