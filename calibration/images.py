"""The photographs a calibration keeps: stored as a session's frames are (16-bit PNG, sidecar, journal
line with both checksums), so that a solve can be run again from them (``--from``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.session.frames import checked_sidecar, load_frame
from hlr_lab.session.journal import JOURNAL, read_journal


def journaled_images(folder: Path) -> Iterator[tuple[dict, np.ndarray]]:
    """(sidecar, pixels) of every photograph in ``folder``, each checked against its journal line."""
    if not (folder / JOURNAL).is_file():
        raise InputError(
            "no calibration images here (no journal.jsonl); give the --out of a capture", path=folder
        )
    for e in (e for e in read_journal(folder / JOURNAL) if e["event"] == "frame"):
        sidecar, problem = checked_sidecar(folder, e)
        if problem:
            raise InputError(f"{problem}; take the calibration's photographs again", path=folder)
        yield sidecar, load_frame(folder, e)
