"""The acquisition loop: every pose of a plan → move, settle, light, capture the exposure bracket, store,
journal. Knows the devices only through the Protocols of :mod:`drivers.protocols`.

Frames are stored by a :class:`FrameWriter` thread while the next exposure or move runs. Every retry of a
device exchange (a driver's or this loop's, logged with :data:`drivers.errors.RETRY`) gets a journal
line. The run's summary ends the journal: ``run_end``, or ``stopped`` with the reason.

Resuming is the same call on the same session: frames whose journal line and files check out are
skipped; a frame whose file is missing or changed is taken again under a new attempt name, so nothing
is overwritten. The caller owns the devices and their safe state (:class:`hlr_lab.devices.RigDevices`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from drivers.errors import RETRY, ChecksumError, DeviceTimeout
from drivers.protocols import Camera, Positioner, RawFrame, Switch, Thermometer
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile, PlanPose
from hlr_lab.motion import PoseTarget
from hlr_lab.session.frames import frame_problem
from hlr_lab.session.journal import JOURNAL, Journal
from hlr_lab.session.writer import FrameWriter

log = logging.getLogger(__name__)


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
    """The run's summary, also the journal's last line."""

    taken: int = 0
    already_done: int = 0
    retaken: list[str] = field(default_factory=list)  # frames whose earlier copy was missing or changed
    poses_moved: int = 0  # poses the rig went to (complete poses are not even moved to)
    retries: int = 0  # device exchanges retried (each has a journal line)
    duration_s: float = 0.0

    def summary(self) -> dict:
        return {
            "frames_taken": self.taken,
            "frames_already_done": self.already_done,
            "frames_retaken": len(self.retaken),
            "poses_moved": self.poses_moved,
            "retries": self.retries,
            "duration_s": round(self.duration_s, 3),
        }


@dataclass(frozen=True)
class Step:
    """Where the run is, for a progress display: pose ``index`` of ``poses`` and what happens now;
    ``action`` "done" closes each pose (also one that was complete already)."""

    index: int
    poses: int
    pose: str
    action: str


CAPTURE_RETRIES, RETRY_BACKOFF_S = 3, 0.2  # a camera link that drops now and then; then give up


@dataclass(frozen=True)
class Bracketing:
    """Adaptive bracketing: while the shortest frame of a pose has clipped pixels, add a frame ``factor``
    times shorter, at most ``max_extra`` of them, so that the HDR merge never needs a clipped value."""

    max_extra: int = 3
    factor: float = 4.0
    max_clipped: int = 0  # clipped pixels tolerated in the shortest frame
    dark_frames: bool = False  # also each exposure with the lamp off, for ambient subtraction

    def wants_shorter(self, clipped_in_shortest: int, extra_so_far: int) -> bool:
        return extra_so_far < self.max_extra and clipped_in_shortest > self.max_clipped


def acquire(
    plan: PlanFile,
    targets: list[PoseTarget],
    instruments: Instruments,
    session: Path,
    *,
    settle_timeout_s: float = 60.0,
    bracket: Bracketing = Bracketing(),
    progress: Callable[[Step], None] = lambda _: None,
    object_window: Callable[[float], np.ndarray] | None = None,
) -> Outcome:
    """Run ``plan`` (its poses already checked and converted into ``targets``) into ``session``.

    object_window: turntable angle (°) → (H, W) bool, where the object may appear: clipped pixels are
    counted there only (:mod:`hlr_lab.silhouette`); None counts the whole frame.
    """
    outcome, started = Outcome(), time.monotonic()
    with Journal(session / JOURNAL) as journal, _RetryJournal(journal) as retries:
        done = _intact_frames(session, journal.events, outcome.retaken)
        journal.append({"event": "run_start", "at": time.time(), "frames_done": sum(map(len, done.values()))})
        try:
            with FrameWriter(session, journal) as writer:
                run = _Run(instruments, session, journal, writer, settle_timeout_s, bracket, object_window)
                for i, (pose, target) in enumerate(zip(plan.poses, targets, strict=True)):
                    retries.pose = pose.id
                    have = done.get(pose.id, {})
                    outcome.already_done += len(have)
                    report = partial(_report, progress, i, len(targets), pose.id)
                    taken = run.take_pose(pose, target, have, report)
                    outcome.taken += taken
                    outcome.poses_moved += taken > 0
                    report("done")
        except BaseException as exc:  # an interrupt too: the journal says why the run ended
            _finish(outcome, started, retries.count)
            reason = str(exc) or type(exc).__name__
            journal.append({"event": "stopped", "at": time.time(), "reason": reason, **outcome.summary()})
            raise
        _finish(outcome, started, retries.count)
        journal.append({"event": "run_end", "at": time.time(), **outcome.summary()})
    return outcome


def _report(progress: Callable[[Step], None], index: int, poses: int, pose: str, action: str) -> None:
    progress(Step(index, poses, pose, action))


def _finish(outcome: Outcome, started: float, retries: int) -> None:
    outcome.duration_s, outcome.retries = time.monotonic() - started, retries


class _RetryJournal(logging.Handler):
    """Journals and counts the retries that drivers and this loop log (records tagged with ``RETRY``),
    while it is installed on their loggers."""

    LOGGERS = ("drivers", __name__)

    def __init__(self, journal: Journal):
        super().__init__(logging.WARNING)
        self.journal, self.count, self.pose = journal, 0, None

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, "retry", False):
            self.count += 1
            self.journal.append(
                {"event": "retry", "at": record.created, "pose": self.pose, "source": record.name,
                 "error": record.getMessage()}
            )  # fmt: skip

    def __enter__(self) -> _RetryJournal:
        for name in self.LOGGERS:
            logging.getLogger(name).addHandler(self)
        return self

    def __exit__(self, *exc) -> None:
        for name in self.LOGGERS:
            logging.getLogger(name).removeHandler(self)


@dataclass(frozen=True)
class _Run:
    instruments: Instruments
    session: Path
    journal: Journal
    writer: FrameWriter
    settle_timeout_s: float
    bracket: Bracketing
    object_window: Callable[[float], np.ndarray] | None

    def take_pose(
        self,
        pose: PlanPose,
        target: PoseTarget,
        have: dict[tuple[int, bool], dict],
        progress: Callable[[str], None],
    ) -> int:
        """The planned exposures not in ``have`` ((index, dark) → journaled frame), then shorter ones while
        the shortest frame still clips, then the dark frames; nothing (and no motion) when the pose is
        complete. Returns the number of frames taken."""
        lit = {k: e["exposure_s"] for (k, dark), e in have.items() if not dark}  # index → exposure
        darks = {k for k, dark in have if dark}
        planned = [k for k in range(len(pose.exposures_s)) if k not in lit]
        # (exposure, clipped pixels) of the shortest frame of this pose so far, from the journal
        shortest = min(
            ((e["exposure_s"], e["clipped_pixels"]) for (_, dark), e in have.items() if not dark),
            default=(float("inf"), 0),
        )
        extra = len(lit) - len(pose.exposures_s) + len(planned)
        wants_dark = self.bracket.dark_frames and bool(set(lit) - darks)
        if not planned and not wants_dark and not self.bracket.wants_shorter(shortest[1], extra):
            return 0
        instruments = self.instruments
        progress("moving")
        measured = _move(instruments, target, self.settle_timeout_s)
        temperatures = {k: v for t in instruments.thermometers for k, v in t.temperatures().items()}
        state = {**_positions(target, measured), "temperatures_c": temperatures}
        window = None if self.object_window is None else self.object_window(target.turntable_deg)
        self.journal.append({"event": "pose", "pose": pose.id, **state})
        log.info("%s: settled at %s, %s", pose.id, measured, temperatures)
        instruments.lamp.set(True)
        for k in planned:
            lit[k] = pose.exposures_s[k]
            shortest = min(
                shortest, (lit[k], self._capture(pose, k, lit[k], state, window, "planned", progress))
            )
        k = max(len(pose.exposures_s), max(lit) + 1)
        while self.bracket.wants_shorter(shortest[1], k - len(pose.exposures_s)):
            lit[k] = shortest[0] / self.bracket.factor
            shortest = min(
                shortest, (lit[k], self._capture(pose, k, lit[k], state, window, "adaptive", progress))
            )
            k += 1
        instruments.lamp.set(False)
        dark = sorted(set(lit) - darks) if self.bracket.dark_frames else []
        for k in dark:  # same pose and exposure, lamp off: the ambient light to subtract
            self._capture(pose, k, lit[k], state, window, "dark", progress)
        return len(lit) - (len(have) - len(darks)) + len(dark)

    def _capture(
        self,
        pose: PlanPose,
        k: int,
        exposure: float,
        state: dict,
        window: np.ndarray | None,
        kind: str,
        progress: Callable[[str], None],
    ) -> int:
        """One frame, handed to the writer; returns its clipped-pixel count (inside ``window`` when
        given). ``kind`` is "planned", "adaptive" (shorter, because of clipping) or "dark" (lamp off)."""
        progress(f"exposure {exposure:g} s" + ("" if kind == "planned" else f" ({kind})"))
        adaptive, dark = kind == "adaptive", kind == "dark"
        self.instruments.camera.set_exposure(exposure)
        frame = _retry_capture(self.instruments.camera)
        clipped = _clipped(frame.pixels, frame.bits, window)
        sidecar = {
            "pose": pose.id,
            "exposure_index": k,
            "adaptive": adaptive,
            "dark": dark,
            "exposure_s": frame.exposure_s,
            "gain_db": frame.gain_db,
            "bits": frame.bits,
            "captured_at": frame.captured_at,
            "clipped_pixels": clipped,
            "clipped_counted_in": "frame" if window is None else "object window",
            **state,
            "camera": frame.meta,
        }
        name = _free_name(self.session, f"{pose.id}_e{k}" + ("_dark" if dark else ""))
        self.writer.submit(
            name,
            frame.pixels,
            sidecar,
            pose=pose.id,
            exposure_index=k,
            exposure_s=exposure,
            adaptive=adaptive,
            dark=dark,
            clipped_pixels=clipped,  # a resumed run decides on shorter exposures without reading frames
        )
        return clipped


def _clipped(pixels: np.ndarray, bits: int, window: np.ndarray | None) -> int:
    """Pixels (inside ``window``, (H, W) bool, when given) with any channel at the top code: their true
    value is unknown. pixels: (H, W, C) or (H, W)."""
    if window is not None and window.shape != pixels.shape[:2]:
        raise InputError(
            f"the camera delivers {pixels.shape[1]}×{pixels.shape[0]} frames, the rig file says "
            f"{window.shape[1]}×{window.shape[0]}: correct camera.width and camera.height (and calibrate "
            "at the camera's resolution)",
            field="camera.width",
        )
    top = (1 << bits) - 1
    if pixels.max() < top:  # the usual case, and 5× faster than counting
        return 0
    at_top = (pixels >= top).any(axis=-1) if pixels.ndim == 3 else pixels >= top
    return int((at_top & window).sum() if window is not None else at_top.sum())


def _retry_capture(camera: Camera) -> RawFrame:
    """Capture, retrying a dropped link or a frame cut short with growing pauses (each retry logged, so
    journaled); a refusal or a fault that stays is raised (and stops the run safely)."""
    for attempt in range(CAPTURE_RETRIES + 1):
        try:
            return camera.capture()
        except (DeviceTimeout, ChecksumError) as exc:
            if attempt == CAPTURE_RETRIES:
                raise
            log.warning("%s; retrying (%d of %d)", exc, attempt + 1, CAPTURE_RETRIES, extra=RETRY)
            time.sleep(RETRY_BACKOFF_S * 2**attempt)
    raise AssertionError("unreachable")


def _move(instruments: Instruments, target: PoseTarget, timeout_s: float) -> dict:
    instruments.turntable.move_to((target.turntable_steps,))
    instruments.gantry.move_to(target.gantry_ticks)  # both travel at once; wait for the slower
    (steps,) = instruments.turntable.wait_settled(timeout_s)
    ticks = instruments.gantry.wait_settled(timeout_s)
    return {"turntable_steps": int(steps), "gantry_ticks": [int(t) for t in ticks]}


def _positions(target: PoseTarget, measured: dict) -> dict:
    commanded = {"turntable_steps": target.turntable_steps, "gantry_ticks": list(target.gantry_ticks)}
    return {"commanded": commanded, "measured": measured}


def _intact_frames(
    session: Path, events: list[dict], retaken: list[str]
) -> dict[str, dict[tuple[int, bool], dict]]:
    """pose → (exposure index, dark) → journal line, for the frames whose files check out."""
    done: dict[str, dict[tuple[int, bool], dict]] = {}
    for event in events:
        if event.get("event") != "frame":
            continue
        problem = frame_problem(session, event)
        if problem:
            log.warning("%s; taking it again", problem)
            retaken.append(event["file"])
            continue
        done.setdefault(event["pose"], {})[(event["exposure_index"], bool(event.get("dark")))] = event
    return done


def _free_name(session: Path, base: str) -> str:
    """``p003_e1``, or ``p003_e1_a2`` … when an earlier attempt left files under that name."""
    name, attempt = base, 1
    while (session / "frames" / f"{name}.png").exists() or (session / "frames" / f"{name}.json").exists():
        attempt += 1
        name = f"{base}_a{attempt}"
    return name
