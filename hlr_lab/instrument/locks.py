"""One user at a time: exclusive locks on a session directory and on every device link.

Two runs on one session journal the same frames twice; two runs on one rig photograph where the *other*
one put the arm. Each run therefore holds, for its whole life, an ``fcntl.flock`` on

* ``SESSION/acquire.lock`` (the session), and
* one lock file per device link (serial port, Modbus address, camera endpoint) in the lock directory:
  ``$HLR_LAB_LOCK_DIR``, else ``/run/lock/hlr-lab`` where it can be created, else ``hlr-lab-locks`` in
  the temporary directory. Every hlr-lab process of a machine must see the same one.

The kernel releases a flock when its holder dies, however it dies (no stale pid files). The holder writes
who it is (PID, command, since when) into the file, so a refused run can name it.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

from hlr_lab.errors import HlrLabError
from hlr_lab.files import open_regular
from hlr_lab.session.folder import LOCK, check_session_folder


class Busy(HlrLabError):
    """Another process holds what this one needs (its PID, command and start are in the message)."""


class Lock:
    """A held lock; :meth:`release` (or the process's death) frees it."""

    def __init__(self, path: Path, what: str):
        self.path, self.what = path, what
        self._fd = open_regular(path, os.O_RDWR | os.O_CREAT, 0o666)  # never through a link at its name
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(self._fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            raise Busy(f"{what} is in use by {_holder(path)}; wait for that run to end, or stop it") from None
        holder = {"pid": os.getpid(), "command": " ".join(sys.argv) or "python", "since": time.time()}
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(holder).encode(), 0)

    def release(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)  # the file stays: unlinking it would let two processes lock two files
            self._fd = -1


def _holder(path: Path) -> str:
    try:
        h = json.loads(path.read_text())
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(h["since"])))
        return f"PID {int(h['pid'])} ({h['command']}, since {since})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"  # it has the lock but has not written its name yet


def lock_directory() -> Path:
    """Where device locks live (see the module's docstring); created when missing."""
    configured = os.environ.get("HLR_LAB_LOCK_DIR")
    candidates = [Path(configured)] if configured else [Path("/run/lock/hlr-lab"), _temporary()]
    for directory in candidates:
        try:
            if not directory.is_dir():
                directory.mkdir(parents=True)
                if not configured:
                    directory.chmod(0o1777)  # every user's runs must lock the same devices
        except OSError:
            continue
        if os.access(directory, os.W_OK):
            return directory
    raise HlrLabError(
        f"no writable directory for device locks (tried {', '.join(map(str, candidates))}); "
        "set HLR_LAB_LOCK_DIR to one"
    )


def _temporary() -> Path:
    return Path(tempfile.gettempdir()) / "hlr-lab-locks"


def link_key(link: str) -> str:
    """A file name for a device link: a device path by the file it resolves to (a /dev/serial/by-id link
    and /dev/ttyUSB0 are one port), a network address as written, lower-cased."""
    if link.startswith("/"):
        link = os.path.realpath(link)
    return re.sub(r"[^A-Za-z0-9._-]+", "_", link.lower()).strip("_") + ".lock"


@contextlib.contextmanager
def hold_devices(links: Iterable[tuple[str, str]]) -> Iterator[None]:
    """Lock every ``(description, link)`` for the block, in a fixed order (no two runs can each hold
    half); :class:`Busy` names the first one taken."""
    directory = lock_directory()
    by_key: dict[str, tuple[str, str]] = {}  # two devices on one link (a bus, a gateway) share its lock
    for what, link in links:
        by_key.setdefault(link_key(link), (what, link))
    held: list[Lock] = []
    try:
        for key, (what, link) in sorted(by_key.items()):
            held.append(Lock(directory / key, f"{what} ({link})"))
        yield
    finally:
        for lock in reversed(held):
            lock.release()


@contextlib.contextmanager
def hold_session(session: Path) -> Iterator[None]:
    """Lock a session directory (created if missing) for the block; a session holding a link or a special
    file is refused first (:func:`hlr_lab.session.folder.check_session_folder`)."""
    session.mkdir(parents=True, exist_ok=True)
    check_session_folder(session)
    lock = Lock(session / LOCK, f"session {session}")
    try:
        yield
    finally:
        lock.release()
