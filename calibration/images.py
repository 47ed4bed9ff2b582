"""The photographs a calibration keeps: stored as a session's frames are (16-bit PNG, sidecar, journal
line with both checksums), so that a solve can be run again from them (``--from``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import TypedDict

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.session.events import FrameLine
from hlr_lab.session.frames import StoredFrame, checked_sidecar, load_frame
from hlr_lab.session.journal import JOURNAL, read_journal


class PhotographFields(TypedDict):
    """What a calibration photograph's journal line and its sidecar both say of it."""

    pose: str
    exposure_index: int
    dark: bool
    exposure_s: float


def photograph_line(
    stored: StoredFrame, pose: str, exposure_index: int, exposure_s: float, dark: bool
) -> FrameLine:
    """The journal line of a calibration photograph (never adaptive; clipping is the solve's business)."""
    return FrameLine(event="frame", pose=pose, exposure_index=exposure_index, exposure_s=exposure_s, dark=dark,
                     adaptive=False, clipped_pixels=0, **stored.files())  # fmt: skip


def journaled_images(
    folder: Path, procedure: str, fields: tuple[str, ...]
) -> Iterator[tuple[dict, np.ndarray]]:
    """(sidecar, pixels) of every photograph in ``folder``, each checked against its journal line; the
    folder must hold ``procedure``'s photographs (e.g. "calibrate gantry", as its journal's run_start
    line says) and every sidecar the ``fields`` that procedure's solve reads."""
    for event, sidecar in _journaled(folder, procedure, fields):
        yield sidecar, load_frame(folder, event)


def journaled_sidecars(folder: Path, procedure: str) -> list[dict]:
    """The sidecars of ``folder``'s photographs, checked as :func:`journaled_images` checks them, without
    decoding any image."""
    return [sidecar for _, sidecar in _journaled(folder, procedure, ())]


def _journaled(folder: Path, procedure: str, fields: tuple[str, ...]) -> Iterator[tuple[dict, dict]]:
    """(journal line, sidecar) of every photograph (see :func:`journaled_images`)."""
    if not (folder / JOURNAL).is_file():
        raise InputError(
            "no calibration images here (no journal.jsonl); give the --out of a capture", path=folder
        )
    events = read_journal(folder / JOURNAL)
    taken_by = next((e.get("procedure") for e in events if e["event"] == "run_start"), None)
    if taken_by != procedure:
        raise InputError(
            f"these are not the photographs of hlr-lab {procedure} (the journal says "
            f"{taken_by or 'nothing of a procedure'}); give the --out of a {procedure} run",
            path=folder,
        )
    for e in (e for e in events if e["event"] == "frame"):
        sidecar, problem = checked_sidecar(folder, e)
        if problem or sidecar is None:
            raise InputError(f"{problem}; take the calibration's photographs again", path=folder)
        missing = [f for f in fields if f not in sidecar]
        if missing:
            raise InputError(
                f"{e.get('file', 'a frame')}'s sidecar lacks {', '.join(missing)}; take the photographs again",
                path=folder,
            )
        yield e, sidecar
