"""``journal.jsonl``: one JSON object per line, each on disk (fsync'ed) before :meth:`Journal.append`
returns, so an event in the journal happened and its files are complete.

A crash can cut the last line short. That line never counted (its append did not return); it is cut
off when the journal is opened again, and is the only change ever made to existing lines. Damage
anywhere else is not a crash but corruption, and is refused.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

from hlr_lab.errors import InputError
from hlr_lab.formats.io import fsync_directory

JOURNAL = "journal.jsonl"  # the session directory's journal (DESIGN §4)


class Journal:
    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.events, intact_bytes = _read(self.path)
        new = not self.path.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        if os.fstat(self._fd).st_size > intact_bytes:
            os.ftruncate(self._fd, intact_bytes)
            os.fsync(self._fd)
        if new:
            fsync_directory(self.path.parent)
        self._lock = threading.Lock()  # the frame writer appends from its own thread

    def append(self, event: dict) -> None:
        line = (json.dumps(event, ensure_ascii=False, sort_keys=True) + "\n").encode()
        with self._lock:
            written = os.write(self._fd, line)
            if written != len(line):  # a full disk: cut the part-line so the journal stays whole
                os.ftruncate(self._fd, os.fstat(self._fd).st_size - written)
                raise OSError(f"{self.path}: the disk took {written} of {len(line)} bytes; free some space")
            os.fsync(self._fd)
            self.events.append(event)

    def close(self) -> None:
        os.close(self._fd)

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_journal(path: str | Path) -> list[dict]:
    """The events of a journal (a torn last line ignored), without opening it for writing."""
    return _read(Path(path))[0]


def _read(path: Path) -> tuple[list[dict], int]:
    """Events and the length in bytes of the intact part."""
    if not path.exists():
        return [], 0
    data = path.read_bytes()
    events, offset = [], 0
    lines = data.split(b"\n")
    for number, line in enumerate(lines[:-1], start=1):  # every element but the last ended in "\n"
        try:
            event = json.loads(line)
            if not isinstance(event, dict):
                raise ValueError("not an object")
        except ValueError as exc:
            raise InputError(
                f"line {number} is damaged ({exc}); the journal was changed by something other than "
                "hlr-lab: restore it from a backup or start a new session directory",
                path=path,
            ) from exc
        events.append(event)
        offset += len(line) + 1
    return events, offset  # lines[-1] is b"" after a clean write, else the torn tail
