"""The application's errors: one tree rooted at :class:`HlrLabError` (see :mod:`drivers.errors`)."""

from __future__ import annotations

import errno
from pathlib import Path

from drivers.errors import HlrLabError

__all__ = [
    "DiskFull",
    "HlrLabError",
    "InputError",
    "PlacementError",
    "PlanningError",
    "RigNotReady",
    "os_error_line",
]


class InputError(HlrLabError):
    """Bad input: names the offending file and field, and says what to do.

    ``str(err)`` is the one line shown to the user, e.g.
    ``plan.json: poses[3].light.elevation_deg: 97 is outside [-10, 85]; re-plan with this rig``.
    """

    def __init__(self, message: str, *, path: str | Path | None = None, field: str | None = None):
        self.path = None if path is None else Path(path)
        self.field = field
        where = ": ".join(str(p) for p in (path, field) if p is not None)
        super().__init__(f"{where}: {message}" if where else message)


class PlanningError(HlrLabError):
    """The planner cannot work with this geometry (e.g. the object does not fit inside the sphere)."""


class PlacementError(HlrLabError):
    """Where the object lies cannot be measured from these photographs (nothing lit, the object out of
    view, a mesh that does not match them, a placement outside the search range); the message names the
    view or the figure and says what to do."""


class RigNotReady(HlrLabError):
    """``hlr-lab doctor`` found problems (it has printed them, each with what to do)."""


class DiskFull(HlrLabError):
    """A file could not be written for want of space; the message names it and says how much is free."""


def os_error_line(exc: OSError) -> str:
    """One line for an operating-system refusal: the file, what the system said, what to do."""
    where = exc.filename if exc.filename is not None else "a file"
    advice = {
        errno.EACCES: "check the folder's permissions, or give another output path",
        errno.EROFS: "the file system is read-only: give an output path elsewhere",
        errno.EISDIR: "that is a folder: give a file name",
        errno.ENOTDIR: "a part of that path is a file, not a folder",
        errno.ENOENT: "no such file or folder: check the path",
        errno.ENOSPC: "the disk is full: free space, or write elsewhere",
    }.get(exc.errno or 0, "check the path")  # (errno 0 is no error: not a key)
    return f"{where}: {exc.strerror or exc}; {advice}"
