"""``session.json``: what a session was started with (plan checksum and the session's own copy of it,
rig snapshot, software version), written once. A resumed run must use the same plan and rig, or say
explicitly that it does not."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from hlr_lab import __version__
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_create_bytes, check_header, dumps, non_finite, read_json
from hlr_lab.formats.plan import PlanFile, read_plan
from hlr_lab.object.mesh import file_sha256
from hlr_lab.rig.file import Rig
from hlr_lab.session.folder import SESSION, check_session_folder
from hlr_lab.session.kept_object import keep_object, kept_plan

SESSION_FORMAT = "hlr-lab.session"


def read_record(session: Path) -> dict:
    """``session.json``, checked: its header and the fields a resumed run and a fit rely on."""
    path = session / SESSION
    check_session_folder(session)  # nothing read below comes through a link or from a special file
    if not path.is_file():
        raise InputError(
            "not a session directory (no session.json); give the --out of hlr-lab acquire", path=session
        )
    record = read_json(path)
    check_header(record, path, SESSION_FORMAT, {1})
    assert isinstance(record, dict)  # check_header refuses anything but a table with the header
    if (where := non_finite(record)) is not None:
        raise InputError("is not a number (NaN or infinity): the session record is damaged; restore it from a "
                         "backup of the session", path=path, field=where)  # fmt: skip
    for section, key, kind in (("plan", "path", str), ("plan", "sha256", str), ("rig", "sha256", str),
                               ("rig", "snapshot", dict)):  # fmt: skip
        value = record.get(section, {}).get(key) if isinstance(record.get(section), dict) else None
        if not isinstance(value, kind):
            raise InputError(
                f"the session record is damaged ({section}.{key} is missing or not a {kind.__name__}); give a "
                "new --out to start a new session",
                path=path,
            )
    return record


def session_plan(session: Path, record: dict) -> tuple[PlanFile, Path]:
    """The plan ``session`` was acquired with, and the path its mesh is found from: the session's own copy
    (:mod:`hlr_lab.session.kept_object`); for a session from before copies were kept, the plan where it
    was then, checked against its sha256."""
    copy = record["plan"].get("copy")
    if copy is not None:
        return kept_plan(session, copy)
    plan_path = Path(record["plan"]["path"])
    if not plan_path.is_file():
        raise InputError(
            f"the session's plan {plan_path} is gone; restore it to fit this session", path=session
        )
    if file_sha256(plan_path) != record["plan"]["sha256"]:
        raise InputError(
            f"the plan {plan_path} has changed since this session was acquired; restore the plan it was "
            "acquired with",
            path=session,
        )
    return read_plan(plan_path), plan_path


def start_or_resume(session: Path, plan_path: Path, plan_sha256: str, rig: Rig, *, force: bool) -> bool:
    """Create ``session.json``, or check it against this plan and rig; True when resuming."""
    snapshot = rig.file.model_dump(mode="json")
    rig_sha256 = hashlib.sha256(json.dumps(snapshot, sort_keys=True).encode()).hexdigest()
    path = session / SESSION
    if not path.exists():  # the object's files first: a session.json names a complete copy
        copy = keep_object(session, plan_path)
        record = {
            "format": SESSION_FORMAT,
            "version": 1,
            "plan": {"path": str(plan_path.resolve()), "sha256": plan_sha256, "copy": copy},
            "rig": {"source": rig.source, "sha256": rig_sha256, "snapshot": snapshot},
            "software": {"hlr-lab": __version__},
            "started_at": time.time(),
        }
        atomic_create_bytes(path, (dumps(record) + "\n").encode())
        return False
    record = read_record(session)
    started_with = {"plan": record["plan"]["sha256"], "rig": record["rig"]["sha256"]}
    now = {"plan": plan_sha256, "rig": rig_sha256}
    changed = [what for what in ("plan", "rig") if started_with[what] != now[what]]
    if changed and not force:
        raise InputError(
            f"this session was started with another {' and '.join(changed)}; give a new --out to start a "
            "new session, or --force to continue this one anyway",
            path=path,
        )
    return True
