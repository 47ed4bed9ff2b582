"""The one retry policy (drivers/retrying.py): what is retried, how often, in what order the hooks run,
what is logged and what is raised."""

from __future__ import annotations

import logging

import pytest

from drivers.errors import ChecksumError, DeviceFault, DeviceTimeout
from drivers.retrying import retried

log = logging.getLogger("tests.retrying")


def flaky(failures: list[BaseException], calls: list[str]):
    """An operation that raises ``failures`` in turn, then answers 42."""

    def operation() -> int:
        calls.append("try")
        if failures:
            raise failures.pop(0)
        return 42

    return operation


def test_lost_replies_are_retried_with_the_hooks_around_each_pause(caplog):
    calls: list[str] = []
    errors = [DeviceTimeout("no reply", device="servo 1"), ChecksumError("bad CRC", device="servo 1")]
    with caplog.at_level(logging.WARNING, logger="tests.retrying"):
        value = retried(
            flaky(errors, calls),
            retries=3,
            backoff_s=0.001,
            on=(DeviceTimeout, ChecksumError),
            log=log,
            before_retry=lambda e: calls.append(f"before {type(e).__name__}"),
            after_pause=lambda: calls.append("after pause"),
        )
    assert value == 42
    assert calls == ["try", "before DeviceTimeout", "after pause", "try", "before ChecksumError", "after pause",
                     "try"]  # fmt: skip
    lines = [r for r in caplog.records if r.name == "tests.retrying"]
    assert [r.getMessage().split("; ")[1] for r in lines] == ["retrying (1 of 3)", "retrying (2 of 3)"]
    assert all(getattr(r, "retry", False) for r in lines)  # tagged: the acquisition journals them


def test_the_last_error_and_any_other_kind_are_raised_as_they_are(caplog):
    calls: list[str] = []
    timeouts = [DeviceTimeout(f"no reply {i}", device="stage") for i in range(5)]
    with pytest.raises(DeviceTimeout, match="no reply 2"):
        retried(flaky(timeouts, calls), retries=2, backoff_s=0.001, on=(DeviceTimeout,), log=log)
    assert calls == ["try"] * 3  # the first try and two retries
    calls.clear()
    with pytest.raises(DeviceFault, match="refused"):
        retried(flaky([DeviceFault("refused", device="stage", code=2)], calls), retries=2, backoff_s=0.001,
                on=(DeviceTimeout,), log=log)  # fmt: skip
    assert calls == ["try"]  # a refusal is not retried


def test_an_untagged_policy_logs_without_the_journal_tag(caplog):
    with caplog.at_level(logging.WARNING, logger="tests.retrying"):
        retried(flaky([DeviceTimeout("x", device="lamp")], []), retries=1, backoff_s=0.001, on=(DeviceTimeout,),
                log=log, message="safe state: %s; again (%d of %d)", journaled=False)  # fmt: skip
    (line,) = [r for r in caplog.records if r.name == "tests.retrying"]
    assert line.getMessage().endswith("again (1 of 1)")
    assert not getattr(line, "retry", False)
