"""Disk space: the forecast before a run, and a full disk said plainly.

A night's frames are hundreds of megabytes to gigabytes; a run that finds out at 3 a.m. that they do not
fit has wasted the night. So before anything moves, the space the missing frames need is compared with
what the session's filesystem has free, and a storing failure is one line saying which file, how much
it needed and how much is free.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from hlr_lab.errors import HlrLabError

MARGIN_BYTES = 64 * 1024 * 1024  # for the journal, the log, sidecars and the fit's outputs
PNG_OVERHEAD = 1.01  # a raw frame's noise barely compresses: a PNG is at most its raw size and headers


class DiskFull(HlrLabError):
    """The session's filesystem cannot take what must be written; the message has the numbers."""


def free_bytes(path: Path) -> int:
    """Free bytes for this user on the filesystem holding ``path`` (or its nearest existing parent)."""
    while not path.exists():
        path = path.parent
    return shutil.disk_usage(path).free


def megabytes(n: float) -> str:
    return f"{n / 1e6:,.0f} MB" if n >= 1e7 else f"{n / 1e6:.1f} MB"


def frame_bytes(width: int, height: int, channels: int = 3, bytes_per_value: int = 2) -> int:
    """An upper bound of one stored frame: 16-bit PNG of a (height, width, channels) raw frame."""
    return int(width * height * channels * bytes_per_value * PNG_OVERHEAD)


def check_room(session: Path, frames: int, bytes_per_frame: int) -> int:
    """Refuse (:class:`DiskFull`) when ``frames`` frames of ``bytes_per_frame`` and a margin do not fit
    beside ``session``; returns the forecast in bytes."""
    needed = frames * bytes_per_frame + MARGIN_BYTES
    free = free_bytes(session)
    if needed > free:
        raise DiskFull(
            f"{session}: the frames still to take need about {megabytes(needed)} ({frames} frames of up to "
            f"{megabytes(bytes_per_frame)}, and {megabytes(MARGIN_BYTES)} for records), but only "
            f"{megabytes(free)} is free there; free space or give another --out"
        )
    return needed


def storage_error(exc: OSError, session: Path, what: str, size: int) -> Exception:
    """A full disk while storing ``what`` (about ``size`` bytes) as one plain :class:`DiskFull`; any
    other OS error unchanged."""
    if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
        return exc
    free = free_bytes(session)
    return DiskFull(
        f"{session}: no space left on the device while storing {what} (about {megabytes(size)} needed, "
        f"{megabytes(free)} free); the frames before it are safe: free space, then run the same "
        "command to resume"
    )
