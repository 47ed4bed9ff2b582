"""Frames stored on a background thread while the rig moves on.

Encoding and writing a frame takes tens of milliseconds (a 1280×960 16-bit PNG: about 30 ms here), as
long as the rest of a pose's software work together; doing it while the next exposure runs keeps it off
the critical path. The order of durability stays that of :func:`store_frame`: image, sidecar, then the
journal line, so a frame still counts only once its line is fsync'ed.

At most ``depth`` frames wait, so memory stays bounded by a few frames when storing is slower than
capturing (``submit`` then waits). Closing drains the queue: a frame that was captured is stored even
when the run stops (Ctrl-C, a device fault). Only a kill or a power cut can lose the frames in flight,
and a resumed run takes those again. A failure to store (a full disk) stops the run at the next
``submit`` or at ``close``.
"""

from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlr_lab.session.events import FrameFields, FrameLine, Sidecar
from hlr_lab.session.frames import store_frame
from hlr_lab.session.journal import Journal

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Job:
    name: str
    pixels: np.ndarray
    sidecar: Sidecar
    fields: FrameFields  # the journal line's fields besides the files' names and checksums


class FrameWriter:
    """Stores frames into ``session`` on a background thread, at most ``depth`` waiting (the module's
    docstring). Use it as a context manager: leaving the block stores every frame submitted, then raises
    the first storing failure if there was one."""

    def __init__(self, session: Path, journal: Journal, *, depth: int = 2):
        self.session, self.journal = session, journal
        self._jobs: queue.Queue[_Job | None] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None  # the first storing failure; later frames are not stored
        self.stored = 0  # frames whose journal line is on disk
        self._reported = False
        self._thread = threading.Thread(target=self._work, name="frame-writer", daemon=True)
        self._thread.start()

    def submit(self, name: str, pixels: np.ndarray, sidecar: Sidecar, fields: FrameFields) -> None:
        """Queue ``frames/NAME`` for storing (pixels: (H, W[, 3]) uint8/uint16 raw values), its journal line
        to say ``fields``; waits while ``depth`` frames are already waiting."""
        self._raise_failure()
        self._jobs.put(_Job(name, pixels, sidecar, fields))

    def close(self) -> None:
        """Store every queued frame, stop the thread, and raise a storing failure if there was one."""
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join()
        self._raise_failure()

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, exc_type, *_) -> None:
        if exc_type is None:
            self.close()
            return
        try:  # the run is ending on an error already: store what was captured, keep that error
            self.close()
        except Exception as exc:
            log.error("storing frames failed as well: %s", exc)

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            if self._error is not None:
                continue  # drain without storing: the run is stopping on this error
            try:
                stored = store_frame(self.session, job.name, job.pixels, job.sidecar)
                self.journal.append(FrameLine(event="frame", **job.fields, **stored.files()))
                self.stored += 1
            except BaseException as exc:  # a full disk is a DiskFull naming the file already
                self._error = exc

    def _raise_failure(self) -> None:
        if self._error is not None and not self._reported:
            self._reported = True
            raise self._error
