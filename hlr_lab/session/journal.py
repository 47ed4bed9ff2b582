"""``journal.jsonl``: one JSON object per line, each on disk (fsync'ed) before :meth:`Journal.append`
returns, so an event in the journal happened and its files are complete.

A crash can cut the last line short. That line never counted (its append did not return); it is cut
off when the journal is opened again for writing. A line damaged anywhere else (not JSON, not an object,
a frame line lacking a field or holding one of the wrong type) was changed by something other than
hlr-lab: it is reported with its line number and treated as absent, so its frame counts as not taken.
Opening the journal to write (a resumed run) sets such lines aside in ``journal.damaged`` (line number,
problem, the line as it was) and rewrites the journal without them, so the run can go on and retake
those frames; nothing is thrown away.

At most one process writes a session (:mod:`hlr_lab.instrument.locks`).
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from hlr_lab.errors import DiskFull
from hlr_lab.files import atomic_write_bytes, disk_full, fsync_directory, open_regular, read_regular
from hlr_lab.session.events import JournalLine

JOURNAL = "journal.jsonl"  # the session directory's journal (docs/sessions.md)
DAMAGED = "journal.damaged"  # damaged lines set aside by a resumed run, one JSON object per line
RESERVE = "journal.reserve"  # room kept for the stop record when the disk fills up
RESERVE_BYTES = 64 * 1024
_NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
_SHA256 = re.compile(r"[0-9a-f]{64}")


@dataclass(frozen=True)
class Damage:
    """A journal line that cannot be trusted: its number (from 1), what is wrong, the line's text."""

    line: int
    problem: str
    text: str

    def describe(self) -> str:
        return f"line {self.line}: {self.problem}"


@dataclass(frozen=True)
class JournalContents:
    """A journal as read: its intact lines, the damaged ones, and the intact part's bytes."""

    events: list[JournalLine]
    damaged: list[Damage]
    intact_bytes: int  # length of everything but a torn last line
    kept: bytes  # the intact lines as they are in the file


class Journal:
    """A session's journal opened for appending (the module's docstring says what it guarantees).

    Opening it reads the lines already there into :attr:`events` (damaged ones into :attr:`damaged`, then
    set aside), cuts a crash's torn last line, and keeps a little disk for the last lines. Use it as a
    context manager; one process writes a session at a time.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        contents = load_journal(self.path)
        self.events, self.damaged = contents.events, contents.damaged
        new = not self.path.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.damaged:
            _set_aside(self.path, contents)
        self._fd = open_regular(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        if not self.damaged and os.fstat(self._fd).st_size > contents.intact_bytes:
            os.ftruncate(self._fd, contents.intact_bytes)  # the torn tail of a crash
            os.fsync(self._fd)
        if new:
            fsync_directory(self.path.parent)
        self._lock = threading.Lock()  # the frame writer appends from its own thread
        reserve(self.path.parent)

    def append(self, event: Mapping[str, object]) -> None:
        """Write ``event`` as one line and fsync it before returning (safe from the frame writer's thread);
        a full disk raises :class:`~hlr_lab.errors.DiskFull` with the journal whole."""
        line = (json.dumps(event, ensure_ascii=False, sort_keys=True) + "\n").encode()
        with self._lock:
            try:
                written = os.write(self._fd, line)
            except OSError as exc:
                if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                    raise
                written = 0
            if written != len(line):  # the disk is full: cut the part-line so the journal stays whole
                os.ftruncate(self._fd, os.fstat(self._fd).st_size - written)
                raise disk_full(self.path, len(line))
            os.fsync(self._fd)
            self.events.append(dict(event))

    def append_last(self, event: Mapping[str, object]) -> None:
        """Append the run's last line, using the room kept for it when the disk is full."""
        try:
            self.append(event)
        except DiskFull:
            (self.path.parent / RESERVE).unlink(missing_ok=True)
            self.append(event)

    def close(self) -> None:
        os.close(self._fd)

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def reserve(session: Path) -> None:
    """Keep ``RESERVE_BYTES`` of disk for the journal's last lines (a run that stops on a full disk must
    still say so); :meth:`Journal.append_last` frees it. Best effort: no room, no reserve."""
    path = session / RESERVE
    fd = open_regular(path, os.O_WRONLY | os.O_CREAT)  # a link or a FIFO here is refused, never written
    try:
        if os.fstat(fd).st_size >= RESERVE_BYTES:
            return
        with os.fdopen(os.dup(fd), "wb") as f:
            f.write(b"\0" * RESERVE_BYTES)  # real blocks (a sparse file would reserve nothing)
            f.flush()
            os.fsync(f.fileno())
    except OSError:
        path.unlink(missing_ok=True)
    finally:
        os.close(fd)


def read_journal(path: str | Path) -> list[JournalLine]:
    """The intact events of a journal (damaged lines and a torn last line left out), read only."""
    return load_journal(Path(path)).events


def load_journal(path: Path) -> JournalContents:
    """Every line checked: the intact events, and the damaged lines with what is wrong with each."""
    try:
        data = read_regular(path)  # a link, a FIFO or /dev/zero in its place is refused, never read
    except FileNotFoundError:
        return JournalContents([], [], 0, b"")
    events, damaged, kept, offset = [], [], [], 0
    lines = data.split(b"\n")
    for number, line in enumerate(lines[:-1], start=1):  # every element but the last ended in "\n"
        offset += len(line) + 1
        event, problem = _parse(line)
        if problem:
            damaged.append(Damage(number, problem, line.decode("utf-8", "replace")))
        else:
            events.append(event)
            kept.append(line + b"\n")
    return JournalContents(events, damaged, offset, b"".join(kept))  # lines[-1]: b"" or a torn tail


def _parse(line: bytes) -> tuple[JournalLine | None, str | None]:
    try:
        event = json.loads(line)
    except ValueError as exc:
        return None, f"not JSON ({exc})"
    if not isinstance(event, dict) or not isinstance(event.get("event"), str):
        return None, 'not an event (a JSON object with an "event" name)'
    problem = _frame_problem(event) if event["event"] == "frame" else None
    return (None, problem) if problem else (event, None)


def _frame_problem(e: JournalLine) -> str | None:
    """What makes a frame line unusable, or None."""
    for key, ok, wanted in (
        ("pose", lambda v: isinstance(v, str) and re.fullmatch(_NAME, v), "a pose id"),
        ("exposure_index", lambda v: type(v) is int and v >= 0, "a whole number ≥ 0"),
        ("exposure_s", lambda v: type(v) in (int, float) and math.isfinite(v) and v > 0, "seconds > 0"),
        ("clipped_pixels", lambda v: type(v) is int and v >= 0, "a whole number ≥ 0"),
        ("adaptive", lambda v: type(v) is bool, "true or false"),
        ("dark", lambda v: type(v) is bool, "true or false"),
        ("file", lambda v: isinstance(v, str) and re.fullmatch(rf"frames/{_NAME}\.png", v), "frames/NAME.png"),
        ("sidecar", lambda v: isinstance(v, str) and re.fullmatch(rf"frames/{_NAME}\.json", v),
         "frames/NAME.json"),
        ("sha256", lambda v: isinstance(v, str) and _SHA256.fullmatch(v), "a sha256"),
        ("sidecar_sha256", lambda v: isinstance(v, str) and _SHA256.fullmatch(v), "a sha256"),
    ):  # fmt: skip
        if key not in e:
            return f"frame line without {key!r}"
        if not ok(e[key]):
            return f"frame line: {key} = {e[key]!r} is not {wanted}"
    if ".." in e["file"] or ".." in e["sidecar"]:
        return "frame line: a file name with '..'"
    return None


def _set_aside(path: Path, contents: JournalContents) -> None:
    """Append the damaged lines to ``journal.damaged``, then replace the journal by its intact lines
    (the damaged record is on disk before the journal loses them)."""
    aside = path.with_name(DAMAGED)
    with os.fdopen(open_regular(aside, os.O_WRONLY | os.O_CREAT | os.O_APPEND), "a", encoding="utf-8") as f:
        for d in contents.damaged:
            f.write(
                json.dumps({"line": d.line, "problem": d.problem, "text": d.text}, ensure_ascii=False) + "\n"
            )
        f.flush()
        os.fsync(f.fileno())
    atomic_write_bytes(path, contents.kept)
