"""SIGINT and SIGTERM stop a command once, and never interrupt the stop itself.

The first signal raises :class:`KeyboardInterrupt` ("signal SIGTERM") in the main thread, so a run unwinds
through its ``finally`` blocks: the journal says why it ended and the rig is made safe. Any later signal
is only noted: an operator pressing Ctrl-C twice, or a service manager sending SIGTERM then SIGINT, must
not cut the safe stop short (an interrupted torque-off leaves the servos powered).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

STOPPING = (signal.SIGINT, signal.SIGTERM)


class _StopOnce:
    def __init__(self) -> None:
        self.received: str | None = None

    def __call__(self, signum: int, _frame) -> None:
        name = signal.Signals(signum).name
        if self.received is None:
            self.received = name
            raise KeyboardInterrupt(f"signal {name}")
        # os.write: a signal handler must not re-enter a buffered stream that may be mid-write
        os.write(2, f"{name} received: already stopping safely ({self.received}); please wait\n".encode())


@contextlib.contextmanager
def stop_once_on_signals() -> Iterator[None]:
    """Within the block, the first SIGINT/SIGTERM raises KeyboardInterrupt and later ones are ignored
    (said on stderr). Once a signal has stopped the block, both signals are left ignored: the process is
    ending, and a second signal arriving as it exits must not turn exit status 130 into death by signal
    (Python puts its own handlers back to the default while it shuts down; an ignored signal it leaves
    ignored). Outside the main thread, where Python cannot set handlers, it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = _StopOnce()
    previous = {s: signal.signal(s, handler) for s in STOPPING}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old if handler.received is None else signal.SIG_IGN)
