"""The one retry policy of the project's exchanges with devices, on tenacity: a fixed number of retries
after the first try, pauses growing ×2 from ``backoff_s``, only for the errors a retry can mend (a lost or
corrupted reply, a dropped link), each retry logged as a warning tagged :data:`drivers.errors.RETRY` (the
acquisition journals those lines); the last error is raised as it is."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

from tenacity import RetryCallState, Retrying, retry_if_exception_type, stop_after_attempt, wait_exponential

from drivers.errors import RETRY

T = TypeVar("T")


def retried(
    operation: Callable[[], T],
    *,
    retries: int,
    backoff_s: float,
    on: tuple[type[BaseException], ...],
    log: logging.Logger,
    message: str = "%s; retrying (%d of %d)",
    before_retry: Callable[[BaseException], None] = lambda _: None,
    after_pause: Callable[[], None] = lambda: None,
    journaled: bool = True,
) -> T:
    """``operation()``, tried again up to ``retries`` times when it raises one of ``on``: the n-th retry
    after ``backoff_s`` · 2ⁿ⁻¹ s. Before each pause ``before_retry(error)`` runs (count it, clear a port)
    and the retry is logged with ``message`` % (error, n, retries); after it, ``after_pause()`` (reconnect
    a dropped link). ``journaled``: the log line is tagged :data:`~drivers.errors.RETRY`. Any other error,
    and the last one, is raised as it is."""

    def announce(state: RetryCallState) -> None:
        assert state.outcome is not None  # tenacity calls this after a failed attempt
        error = state.outcome.exception()
        assert error is not None
        before_retry(error)
        log.warning(message, error, state.attempt_number, retries, extra=RETRY if journaled else None)

    def before(state: RetryCallState) -> None:
        if state.attempt_number > 1:
            after_pause()

    policy = Retrying(
        before=before,
        stop=stop_after_attempt(retries + 1),
        wait=wait_exponential(multiplier=backoff_s, exp_base=2, min=0),
        retry=retry_if_exception_type(on),
        before_sleep=announce,
        reraise=True,
    )
    return policy(operation)
