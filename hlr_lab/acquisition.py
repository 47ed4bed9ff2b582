"""The acquisition loop: every pose of a plan → move, settle, light, capture the exposure bracket, store,
journal. Knows the devices only through the Protocols of :mod:`drivers.protocols`.

Resuming is the same call on the same session: frames whose journal line and files check out are
skipped; a frame whose file is missing or changed is taken again under a new attempt name, so nothing
is overwritten. The caller owns the devices and their safe state (:class:`hlr_lab.devices.RigDevices`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from drivers.protocols import Camera, Positioner, Switch, Thermometer
from hlr_lab.formats.plan import PlanFile, PlanPose
from hlr_lab.motion import PoseTarget
from hlr_lab.session.frames import frame_problem, store_frame
from hlr_lab.session.journal import Journal

log = logging.getLogger(__name__)
JOURNAL = "journal.jsonl"


@dataclass(frozen=True)
class Instruments:
    """What acquisition drives: device-unit positioners, a camera and the lamp."""

    turntable: Positioner  # one axis, stage steps
    gantry: Positioner  # azimuth and elevation servo ticks
    camera: Camera
    lamp: Switch
    thermometers: tuple[Thermometer, ...] = ()  # read once per pose, into the pose line and sidecars


@dataclass
class Outcome:
    taken: int = 0
    already_done: int = 0
    retaken: list[str] = field(default_factory=list)  # frames whose earlier copy was missing or changed


def acquire(
    plan: PlanFile,
    targets: list[PoseTarget],
    instruments: Instruments,
    session: Path,
    *,
    settle_timeout_s: float = 60.0,
    progress: Callable[[str], None] = lambda _: None,
) -> Outcome:
    """Run ``plan`` (its poses already checked and converted into ``targets``) into ``session``."""
    outcome = Outcome()
    with Journal(session / JOURNAL) as journal:
        done = _intact_frames(session, journal.events, outcome.retaken)
        run = _Run(instruments, session, journal, settle_timeout_s, progress)
        journal.append({"event": "run_start", "at": time.time(), "frames_done": len(done)})
        try:
            for pose, target in zip(plan.poses, targets, strict=True):
                todo = [k for k in range(len(pose.exposures_s)) if (pose.id, k) not in done]
                outcome.already_done += len(pose.exposures_s) - len(todo)
                if todo:
                    outcome.taken += run.take_pose(pose, target, todo)
        except BaseException as exc:  # an interrupt too: the journal says why the run ended
            journal.append({"event": "stopped", "at": time.time(), "reason": str(exc) or type(exc).__name__})
            raise
        journal.append({"event": "run_end", "at": time.time(), "taken": outcome.taken})
    return outcome


@dataclass(frozen=True)
class _Run:
    instruments: Instruments
    session: Path
    journal: Journal
    settle_timeout_s: float
    progress: Callable[[str], None]

    def take_pose(self, pose: PlanPose, target: PoseTarget, todo: list[int]) -> int:
        """Move, settle, light, and capture the exposures ``todo`` (indices into the bracket)."""
        instruments = self.instruments
        self.progress(f"{pose.id}: moving")
        measured = _move(instruments, target, self.settle_timeout_s)
        temperatures = {k: v for t in instruments.thermometers for k, v in t.temperatures().items()}
        state = {**_positions(target, measured), "temperatures_c": temperatures}
        self.journal.append({"event": "pose", "pose": pose.id, **state})
        instruments.lamp.set(True)
        for k in todo:
            exposure = pose.exposures_s[k]
            self.progress(f"{pose.id}: exposure {exposure:g} s")
            instruments.camera.set_exposure(exposure)
            frame = instruments.camera.capture()
            sidecar = {
                "pose": pose.id,
                "exposure_index": k,
                "exposure_s": frame.exposure_s,
                "gain_db": frame.gain_db,
                "bits": frame.bits,
                "captured_at": frame.captured_at,
                **state,
                "camera": frame.meta,
            }
            stored = store_frame(self.session, _free_name(self.session, pose.id, k), frame.pixels, sidecar)
            self.journal.append(stored.as_event(pose=pose.id, exposure_index=k, exposure_s=exposure))
        instruments.lamp.set(False)
        return len(todo)


def _move(instruments: Instruments, target: PoseTarget, timeout_s: float) -> dict:
    instruments.turntable.move_to((target.turntable_steps,))
    instruments.gantry.move_to(target.gantry_ticks)  # both travel at once; wait for the slower
    (steps,) = instruments.turntable.wait_settled(timeout_s)
    ticks = instruments.gantry.wait_settled(timeout_s)
    return {"turntable_steps": int(steps), "gantry_ticks": [int(t) for t in ticks]}


def _positions(target: PoseTarget, measured: dict) -> dict:
    commanded = {"turntable_steps": target.turntable_steps, "gantry_ticks": list(target.gantry_ticks)}
    return {"commanded": commanded, "measured": measured}


def _intact_frames(session: Path, events: list[dict], retaken: list[str]) -> set[tuple[str, int]]:
    done = set()
    for event in events:
        if event.get("event") != "frame":
            continue
        problem = frame_problem(session, event)
        if problem:
            log.warning("%s; taking it again", problem)
            retaken.append(event["file"])
            continue
        done.add((event["pose"], event["exposure_index"]))
    return done


def _free_name(session: Path, pose_id: str, index: int) -> str:
    """``p003_e1``, or ``p003_e1_a2`` … when an earlier attempt left files under that name."""
    name, attempt = f"{pose_id}_e{index}", 1
    while (session / "frames" / f"{name}.png").exists() or (session / "frames" / f"{name}.json").exists():
        attempt += 1
        name = f"{pose_id}_e{index}_a{attempt}"
    return name
