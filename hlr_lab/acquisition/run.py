"""Acquiring a session on a rig, from code: what ``hlr-lab acquire`` does once the plan is checked.

In order: forecast the disk space, lock (and check) an existing session, open the rig
(:func:`hlr_lab.instrument.control.open_rig`: device locks, devices, camera), create the session when it is
new, run the plan (:func:`hlr_lab.acquisition.poses.acquire`), and whatever happened, journal what the devices
confirmed of the safe state. An early end is :class:`hlr_lab.instrument.control.RunStopped`.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from hlr_lab.acquisition.poses import Bracketing, LampMeter, Outcome, Step, Tolerance, acquire
from hlr_lab.errors import HlrLabError
from hlr_lab.files import open_regular
from hlr_lab.formats.plan import PlanFile
from hlr_lab.instrument.control import NO_OVERRIDES, OpenRig, RunStopped, open_rig
from hlr_lab.instrument.devices import Links, SafeState
from hlr_lab.instrument.locks import hold_session
from hlr_lab.instrument.motion import PoseTarget
from hlr_lab.object.mesh import file_sha256
from hlr_lab.rig.file import Rig
from hlr_lab.session.folder import LOG
from hlr_lab.session.journal import JOURNAL, Journal, read_journal
from hlr_lab.session.lamp import UNWATCHED, LampWatch
from hlr_lab.session.metadata import start_or_resume
from hlr_lab.session.space import check_room, frame_bytes

log = logging.getLogger(__name__)
PLANNED_ONLY = Bracketing()  # adaptive bracketing, no dark frames


def acquire_session(
    plan: PlanFile,
    plan_path: Path,
    targets: list[PoseTarget],
    rig: Rig,
    session: Path,
    *,
    links: Links = NO_OVERRIDES,
    bracket: Bracketing = PLANNED_ONLY,
    force: bool = False,
    progress: Callable[[Step], None] = lambda _: None,
    object_window: Callable[[float], np.ndarray] | None = None,
    on_start: Callable[[bool], None] = lambda _resumed: None,
    lamp: LampWatch = UNWATCHED,
    reference: LampMeter | None = None,
) -> Outcome:
    """Run ``plan`` on ``rig`` into ``session`` (created, or resumed when it exists); see the module's
    docstring. ``on_start(resumed)`` is called once the session is open and the rig is ready; ``lamp``
    and ``reference``: how the lamp is watched (:func:`hlr_lab.acquisition.poses.acquire`)."""
    resumed: bool | None = None
    opened: OpenRig | None = None

    def open_session_directory() -> bool:
        session_held.enter_context(hold_session(session))
        resumed = start_or_resume(session, plan_path, file_sha256(plan_path), rig, force=force)
        session_held.enter_context(session_log(session / LOG))  # until after the safe state
        return resumed

    with contextlib.ExitStack() as session_held:  # outlives the rig: the safe state is journaled too
        try:
            _check_room(plan, rig, session, bracket)  # before anything is opened or switched on
            if session.is_dir():  # a second writer, a changed plan or rig: refused before anything opens
                resumed = open_session_directory()
            with open_rig(rig, links) as opened:
                if resumed is None:  # only now, with every device answering, is the session created
                    resumed = open_session_directory()
                on_start(resumed)
                outcome = acquire(
                    plan,
                    targets,
                    opened.instruments,
                    session,
                    bracket=bracket,
                    progress=progress,
                    object_window=object_window,
                    tolerance=Tolerance(rig.file.turntable.tolerance_steps, rig.file.gantry.tolerance_ticks),
                    lamp=replace(lamp, black_level_dn=rig.file.sensor.black_level_dn),
                    reference=reference,
                )
                log.info("run summary: %s", outcome.summary())
        except RunStopped as stop:
            if (session / JOURNAL).exists():
                _journal_safe_state(stop.safe, session)
            raise
        safe = opened.devices.safe
        assert safe is not None  # open_rig's block is left: the rig was made safe and confirmed
        _journal_safe_state(safe, session)
    outcome.safe = safe
    return outcome


def _check_room(plan: PlanFile, rig: Rig, session: Path, bracket: Bracketing) -> None:
    """Refuse before anything moves when the frames still to take will not fit on the disk."""
    have = {
        (e["pose"], e["exposure_index"])
        for e in read_journal(session / JOURNAL)
        if e["event"] == "frame" and not e["dark"]
    }
    missing = sum((p.id, k) not in have for p in plan.poses for k in range(len(p.exposures_s)))
    frames = missing * (2 if bracket.dark_frames else 1)
    check_room(session, frames, frame_bytes(rig.camera.width, rig.camera.height))


def _journal_safe_state(safe: SafeState, session: Path) -> None:
    """What the devices confirmed when the run ended, as the journal's ``safe_state`` line (the session
    log has it already: :meth:`hlr_lab.instrument.devices.RigDevices.safe_state` logs it)."""
    try:
        with Journal(session / JOURNAL) as journal:
            journal.append_last(safe.as_event())
    except (OSError, HlrLabError) as exc:  # the console and the log still say it
        log.error("could not journal the safe state: %s", exc)


@contextlib.contextmanager
def session_log(path: Path) -> Iterator[None]:
    """Everything the drivers and hlr-lab log during the run (retries, reboots, warnings, the safe state),
    appended to the session's log file."""
    stream = os.fdopen(open_regular(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND), "a", encoding="utf-8")
    handler = logging.StreamHandler(stream)  # a FileHandler would follow a link at the log's name
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    loggers = [logging.getLogger(name) for name in ("drivers", "hlr_lab", "pymodbus")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)
        handler.close()
        stream.close()
