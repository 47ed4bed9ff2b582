"""A session folder that cannot be turned against its user (docs/sessions.md, "A session stands on its
own"): nothing in it redirects a write or a read.

A session is often shared, copied or unpacked from an archive. The folder itself may be reached through a
link (``--out`` names it as the user likes), but inside it hlr-lab writes and reads only what is really
there: before a run or a fit touches it, every entry of the folder and of its ``frames/`` and ``object/``
is checked to be a regular file or a real folder, never a symbolic link, a FIFO (a read would block), a
device (``/dev/zero`` never ends) or a socket. The files hlr-lab then opens itself (the journal, its
reserve, the lock, the log) are opened with ``O_NOFOLLOW`` (:func:`hlr_lab.files.open_regular`), and an
atomic write never replaces a link (:func:`hlr_lab.files.atomic_write_bytes`), so a link made while a
run goes on is refused too.
"""

from __future__ import annotations

import os
from pathlib import Path

from hlr_lab.errors import InputError
from hlr_lab.files import LINK_REFUSED
from hlr_lab.session.frames import FRAMES
from hlr_lab.session.journal import DAMAGED, JOURNAL, RESERVE
from hlr_lab.session.kept_object import OBJECT

SESSION = "session.json"  # what the session was started with (hlr_lab.session.metadata)
LOCK = "acquire.lock"  # the lock of the run writing the session (hlr_lab.instrument.locks)
LOG = "acquire.log"  # what the drivers and hlr-lab logged during the runs
FOLDERS = (FRAMES, OBJECT)  # the session's own folders: checked entry by entry as its top level is
OWN_FILES = (SESSION, JOURNAL, DAMAGED, RESERVE, LOCK, LOG)  # what a run writes at the top (docs/sessions.md)
_SPECIAL = (
    "is not a regular file or folder (a FIFO, a socket or a device): a session holds only its own files; "
    "remove it from the session"
)


def check_session_folder(session: Path) -> None:
    """Refuse (:class:`InputError` naming the entry) a symbolic link or a special file anywhere hlr-lab
    reads or writes in ``session``, and a ``frames`` or ``object`` that is not a real folder. A session
    that does not exist yet passes: it will be made of hlr-lab's own files."""
    if not session.is_dir():
        return
    _check_entries(session)
    for name in FOLDERS:
        folder = session / name
        if not folder.exists():
            continue
        if not folder.is_dir():
            raise InputError(
                "is not a folder, where a session keeps its own files: move it out of the session, or give "
                "a new --out",
                path=folder,
            )
        _check_entries(folder, recurse=name == OBJECT)  # a kept mesh may sit in subfolders (its textures)


def check_new_session(session: Path, *, option: str = "--out") -> None:
    """Refuse (:class:`InputError` naming a few of them) a folder that is not a session yet — no
    ``session.json``, no journal — but holds something else than a session's own files: a session is
    started in a new or empty folder, never among someone's files (``--out ~/thesis``), which the run's
    files would mix with and a later ``fit`` would read beside. A run that stopped before its session.json
    leaves only its own files, and resumes. ``option``: what names the folder, in the advice."""
    if not session.is_dir() or (session / SESSION).exists() or (session / JOURNAL).exists():
        return
    foreign = sorted(name for name in os.listdir(session) if name not in OWN_FILES + FOLDERS)
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise InputError(
            f"is not a session and holds other files ({shown}): a session is started in a new or empty folder; "
            f"give a new {option}",
            path=session,
        )


def _check_entries(folder: Path, *, recurse: bool = False) -> None:
    with os.scandir(folder) as entries:  # d_type: no stat per frame, so thousands of frames cost little
        for entry in entries:
            if entry.is_symlink():
                raise InputError(f"{LINK_REFUSED}; a session's files must be inside it", path=entry.path)
            if entry.is_dir(follow_symlinks=False):
                if recurse:
                    _check_entries(Path(entry.path), recurse=True)
            elif not entry.is_file(follow_symlinks=False):
                raise InputError(_SPECIAL, path=entry.path)
