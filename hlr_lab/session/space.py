"""Disk space: the forecast before a run, and a full disk said plainly.

A night's frames are hundreds of megabytes to gigabytes; a run that finds out at 3 a.m. that they do not
fit has wasted the night. So before anything moves, the space the missing frames need is compared with
what the session's filesystem has free. Writing a file (or a journal line) that does not fit is a
:class:`hlr_lab.errors.DiskFull` naming it (:func:`hlr_lab.files.disk_full`).
"""

from __future__ import annotations

from pathlib import Path

from hlr_lab.errors import DiskFull
from hlr_lab.files import free_bytes

MARGIN_BYTES = 64 * 1024 * 1024  # for the journal, the log, sidecars and the fit's outputs
PNG_OVERHEAD = 1.01  # a raw frame's noise barely compresses: a PNG is at most its raw size and headers


def frame_bytes(width: int, height: int, channels: int = 3, bytes_per_value: int = 2) -> int:
    """An upper bound of one stored frame: a 16-bit PNG of a (height, width, channels) raw frame."""
    return int(width * height * channels * bytes_per_value * PNG_OVERHEAD)


def check_room(session: Path, frames: int, bytes_per_frame: int) -> int:
    """Refuse (:class:`DiskFull`) when ``frames`` frames of ``bytes_per_frame`` and a margin do not fit
    where ``session`` is; returns the forecast in bytes."""
    needed = frames * bytes_per_frame + MARGIN_BYTES
    free = free_bytes(session)
    if needed > free:
        raise DiskFull(
            f"{session}: the frames still to take need up to {needed / 1e6:,.0f} MB ({frames} frames of up "
            f"to {bytes_per_frame / 1e6:.1f} MB and {MARGIN_BYTES / 1e6:.0f} MB for records), but "
            f"{free / 1e6:,.0f} MB is free there; free space or give another --out"
        )
    return needed
