"""The acquisition loop: every pose of a plan → move, settle, light, capture the exposure bracket, store,
journal. Knows the devices only through the Protocols of :mod:`drivers.protocols`.

Frames are stored by a :class:`FrameWriter` thread while the next exposure or move runs. Every retry of a
device exchange (a driver's or this loop's, logged with :data:`drivers.errors.RETRY`) gets a journal
line. The run's summary ends the journal: ``run_end``, or ``stopped`` with the reason.

Resuming is the same call on the same session: frames whose journal line and files check out are
skipped; a frame whose file is missing or changed is taken again under a new attempt name, so nothing
is overwritten. The caller owns the devices and their safe state (:class:`hlr_lab.instrument.devices.RigDevices`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Protocol

import numpy as np

from drivers.errors import RETRY, ChecksumError, DeviceError, DeviceTimeout
from drivers.protocols import Camera, RawFrame, StreamCounters
from drivers.retrying import retried
from hlr_lab.acquisition.white_reference import Reading
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile, PlanPose
from hlr_lab.geometry.clipping import clip_level, clipped
from hlr_lab.instrument.devices import SafeState
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.instrument.motion import PoseTarget
from hlr_lab.session.events import (
    Axes,
    FrameFields,
    LampLine,
    LampReferenceFields,
    LampReferenceLine,
    OnReference,
    PoseLine,
    PoseState,
    RetryLine,
    RunEndLine,
    RunStartLine,
    RunSummary,
    Sidecar,
)
from hlr_lab.session.folder import check_session_folder
from hlr_lab.session.frames import FRAMES, frame_problem, load_frame, store_frame
from hlr_lab.session.journal import JOURNAL, Journal
from hlr_lab.session.lamp import (
    UNWATCHED,
    WHITE_REFERENCE,
    LampWatch,
    compared_pixels,
    relative_output,
    warm_up,
)
from hlr_lab.session.writer import FrameWriter

log = logging.getLogger(__name__)


@dataclass
class Outcome:
    """The run's summary, also the journal's last line."""

    taken: int = 0
    already_done: int = 0
    retaken: list[str] = field(default_factory=list)  # frames whose earlier copy was missing or changed
    poses_moved: int = 0  # poses the rig went to (complete poses are not even moved to)
    retries: int = 0  # device exchanges retried (each has a journal line)
    duration_s: float = 0.0
    # with a white reference beside the object: the poses taken, and those that measured the lamp on it
    reference_poses: int | None = None
    reference_measured: int = 0
    safe: SafeState | None = None  # what the devices confirmed when the run ended (set by the run's owner)
    camera_stream: dict[str, int] | None = None  # the camera's packet counters, where it counts them

    def summary(self) -> RunSummary:
        """The figures of the journal's ``run_end`` / ``stopped`` line."""
        summary = RunSummary(
            frames_taken=self.taken,
            frames_already_done=self.already_done,
            frames_retaken=len(self.retaken),
            poses_moved=self.poses_moved,
            retries=self.retries,
            duration_s=round(self.duration_s, 3),
        )
        if self.reference_poses is not None:
            summary["lamp_on_reference"] = OnReference(
                poses=self.reference_poses, measured=self.reference_measured
            )
        if self.camera_stream:
            summary["camera_stream"] = self.camera_stream
        return summary


@dataclass(frozen=True)
class Tolerance:
    """How far an axis may be from its goal and count as there (the drivers' settle tolerances):
    also how far it may move while a frame is exposed."""

    turntable_steps: int = 1
    gantry_ticks: int = 2


class AxisMoved(DeviceError):
    """An axis left its place during an exposure, again after the frame was retaken."""


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
    tolerance: Tolerance = Tolerance(),
    lamp: LampWatch = UNWATCHED,
    reference: LampMeter | None = None,
) -> Outcome:
    """Run ``plan`` (its poses already checked and converted into ``targets``) into ``session``, which
    this process alone writes (:func:`hlr_lab.instrument.locks.hold_session`).

    object_window: turntable angle (°) → (H, W) bool, where the object may appear: clipped pixels are
    counted there only (:mod:`hlr_lab.geometry.silhouette`); None counts the whole frame.
    tolerance: after each exposure the axes are read again; a frame during which one left its goal by
    more than this is not kept but taken again after the rig settles (twice: :class:`AxisMoved`).
    lamp: how the lamp is watched (:mod:`hlr_lab.session.lamp`): a warm-up, and the plan's best-lit pose
    (:func:`lamp_reference_pose`) photographed again before the first pose, every ``lamp.every`` poses
    moved to and at the end.
    reference: the lamp measured in each pose's own lit frames (a white reference beside the object:
    :mod:`hlr_lab.acquisition.white_reference`), a ``lamp`` line per pose where it can be.
    """
    outcome, started = Outcome(), time.monotonic()
    check_session_folder(session)  # before anything in it is removed or written (its own files only)
    remove_temporaries(session)
    with Journal(session / JOURNAL) as journal, _RetryJournal(journal) as retries:
        for damage in journal.damaged:
            log.warning(
                "%s: %s; set aside in journal.damaged, its frame is taken again", JOURNAL, damage.describe()
            )
        done = _intact_frames(session, journal.events, outcome.retaken)
        journal.append(
            RunStartLine(event="run_start", at=time.time(), frames_done=sum(map(len, done.values())))
        )
        writer = FrameWriter(session, journal)
        try:
            with writer:
                on_plate = _LampOnReference(journal, reference, outcome) if reference else None
                run = _Run(instruments, session, journal, writer, settle_timeout_s, bracket, object_window,
                           tolerance, on_plate)  # fmt: skip
                best = lamp_reference_pose(plan)
                watch = _LampReference(run, lamp, plan.poses[best], targets[best]) if lamp.active else None
                if watch:
                    watch.warm_up(partial(_report, progress, 0, len(targets), "lamp"))
                since_reference: int | None = None  # poses moved to since the last reference frame
                for i, (pose, target) in enumerate(zip(plan.poses, targets, strict=True)):
                    retries.pose = pose.id
                    have = done.get(pose.id, {})
                    outcome.already_done += len(have)
                    report = partial(_report, progress, i, len(targets), pose.id)
                    due = since_reference is None or since_reference >= lamp.every
                    if watch and lamp.every and due and len(have) < len(pose.exposures_s):  # a pose to take
                        watch.shoot(report)
                        since_reference = 0
                    moved = run.take_pose(pose, target, have, report) > 0
                    outcome.poses_moved += moved
                    if since_reference is not None:
                        since_reference += moved
                    report("done")
                if watch and lamp.every and since_reference:
                    watch.shoot(partial(_report, progress, len(targets) - 1, len(targets), "lamp"))
        except BaseException as exc:  # an interrupt too: the journal says why the run ended
            _finish(outcome, started, retries.count, writer.stored, instruments.camera)
            reason = str(exc) or type(exc).__name__
            journal.append_last(
                RunEndLine(event="stopped", at=time.time(), reason=reason, **outcome.summary())
            )
            raise
        _finish(outcome, started, retries.count, writer.stored, instruments.camera)
        if outcome.reference_poses and not outcome.reference_measured:
            log.warning(
                "the white reference beside the object was not seen lit in any of the %d poses taken: check "
                "run_place_m (in view, beside the object, not under it)",
                outcome.reference_poses,
            )
        journal.append_last(RunEndLine(event="run_end", at=time.time(), **outcome.summary()))
    return outcome


def remove_temporaries(session: Path) -> list[Path]:
    """Delete the temporary files a killed run left while writing a frame or a record (``.NAME.*.tmp``:
    never journaled, so never part of the session). Returns what was removed."""
    found = [p for d in (session, session / FRAMES) if d.is_dir() for p in d.glob(".*.tmp")]
    for p in found:
        p.unlink(missing_ok=True)
    if found:
        log.info("removed %d temporary file(s) of an interrupted run", len(found))
    return found


def _report(progress: Callable[[Step], None], index: int, poses: int, pose: str, action: str) -> None:
    progress(Step(index, poses, pose, action))


def _finish(outcome: Outcome, started: float, retries: int, stored: int, camera: Camera) -> None:
    """Close the account: only frames whose journal line is on disk count as taken; the camera's packet
    counters, where it keeps them."""
    outcome.duration_s, outcome.retries, outcome.taken = time.monotonic() - started, retries, stored
    if isinstance(camera, StreamCounters):
        try:
            outcome.camera_stream = camera.statistics()
        except Exception:  # a camera that failed may not answer even this: the run's last line comes first
            log.warning("the camera's stream counters could not be read", exc_info=True)


class _RetryJournal(logging.Handler):
    """Journals and counts the retries that drivers and this loop log (records tagged with ``RETRY``),
    while it is installed on their loggers."""

    LOGGERS = ("drivers", __name__)

    def __init__(self, journal: Journal):
        super().__init__(logging.WARNING)
        self.journal, self.count = journal, 0
        self.pose: str | None = None  # the pose being taken, for the journal line

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, "retry", False):
            self.count += 1
            self.journal.append(
                RetryLine(event="retry", at=record.created, pose=self.pose, source=record.name,
                          error=record.getMessage())
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
    tolerance: Tolerance
    reference: _LampOnReference | None = None

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
        place = _Place(self, pose, target)
        window = None if self.object_window is None else self.object_window(target.turntable_deg)
        instruments.lamp.set(True)
        frames: list[RawFrame] = []  # this pose's lit frames, for the lamp measured on the white reference
        shoot = partial(self._capture, place, window=window, progress=progress, kept=frames)
        for k in planned:
            lit[k] = pose.exposures_s[k]
            shortest = min(shortest, (lit[k], shoot(k, lit[k], kind="planned")))
        k = max(len(pose.exposures_s), max(lit) + 1)
        while self.bracket.wants_shorter(shortest[1], k - len(pose.exposures_s)):
            lit[k] = shortest[0] / self.bracket.factor
            shortest = min(shortest, (lit[k], shoot(k, lit[k], kind="adaptive")))
            k += 1
        instruments.lamp.set(False)
        if self.reference and frames:
            self.reference.measure(pose.id, place.state["measured"], frames)
        dark = sorted(set(lit) - darks) if self.bracket.dark_frames else []
        for k in dark:  # same pose and exposure, lamp off: the ambient light to subtract
            self._capture(place, k, lit[k], window, "dark", progress)
        return len(lit) - (len(have) - len(darks)) + len(dark)

    def _capture(
        self,
        place: _Place,
        k: int,
        exposure: float,
        window: np.ndarray | None,
        kind: str,
        progress: Callable[[str], None],
        kept: list[RawFrame] | None = None,
    ) -> int:
        """One frame, handed to the writer (and appended to ``kept``); returns its clipped-pixel count
        (inside ``window`` when given). ``kind`` is "planned", "adaptive" (shorter, because of clipping)
        or "dark" (lamp off).
        A frame during which an axis left its place is dropped and taken again once the rig has settled
        there anew; if it happens again the run stops (:class:`AxisMoved`)."""
        progress(f"exposure {exposure:g} s" + ("" if kind == "planned" else f" ({kind})"))
        adaptive, dark, pose = kind == "adaptive", kind == "dark", place.pose
        self.instruments.camera.set_exposure(exposure)
        retakes = 0
        while True:
            frame = _retry_capture(self.instruments.camera)
            moved = place.moved_during_exposure()
            if not moved:
                break
            if retakes == MOTION_RETAKES:
                raise AxisMoved(
                    f"{moved} during the exposure of {pose.id} frame {k}, again after settling anew; "
                    "check the axes for slipping couplings or an obstruction",
                    device="rig",
                )
            log.warning("%s: %s during the exposure; frame %d is taken again", pose.id, moved, k, extra=RETRY)
            progress("settling again")
            place.settle(lamp=not dark)
            retakes += 1
        clipped = _clipped(frame.pixels, frame.bits, window)
        state = place.state
        sidecar = Sidecar(
            pose=pose.id,
            exposure_index=k,
            adaptive=adaptive,
            dark=dark,
            exposure_s=frame.exposure_s,
            gain_db=frame.gain_db,
            bits=frame.bits,
            captured_at=frame.captured_at,
            clipped_pixels=clipped,
            clipped_counted_in="frame" if window is None else "object window",
            **state,
            camera=frame.meta,
        )
        name = _free_name(self.session, f"{pose.id}_e{k}" + ("_dark" if dark else ""))
        self.writer.submit(
            name,
            frame.pixels,
            sidecar,
            FrameFields(  # clipped_pixels: a resumed run decides on shorter exposures without reading frames
                pose=pose.id,
                exposure_index=k,
                exposure_s=frame.exposure_s,
                adaptive=adaptive,
                dark=dark,
                clipped_pixels=clipped,
            ),
        )
        if kept is not None:
            kept.append(frame)
        return clipped


LAMP_REFERENCE = "lamp-reference"  # the pose id of the reference frames (never a plan's: ids are p000…)


class LampMeter(Protocol):
    """The lamp measured on the white reference in a pose's lit frames, from the axes' ``measured``
    positions (``turntable_steps``, ``gantry_ticks``): a reading with ``brightness`` (S · Φ) and ``at``
    (the Unix time of the frame it comes from), or None where it cannot be measured; ``expected``: the
    S · Φ the rig file says (:class:`hlr_lab.acquisition.white_reference.ReferenceMeter`)."""

    expected: float

    def __call__(self, measured: Axes, frames: list[RawFrame]) -> Reading | None: ...


class _LampOnReference:
    """The lamp measured on the white reference in every pose: a ``lamp`` line per pose that shows it, its
    output the measured S · Φ over the rig file's (absolute: no baseline of the session's own)."""

    def __init__(self, journal: Journal, meter: LampMeter, outcome: Outcome):
        self.journal, self.meter, self.outcome = journal, meter, outcome
        outcome.reference_poses = 0

    def measure(self, pose_id: str, measured: Axes, frames: list[RawFrame]) -> None:
        self.outcome.reference_poses = (self.outcome.reference_poses or 0) + 1
        reading = self.meter(measured, frames)
        if reading is None:
            log.info("%s: no lamp measurement (the white reference hidden, shadowed or ill exposed)", pose_id)
            return
        self.outcome.reference_measured += 1
        output = reading.brightness / self.meter.expected
        self.journal.append(LampLine(event="lamp", at=reading.at, output=output, baseline=WHITE_REFERENCE,
                                     brightness=reading.brightness, pose=pose_id))  # fmt: skip
        log.info("lamp: %.4f of the rig file's sensitivity × power (white reference, %s)", output, pose_id)


LAMP_REFERENCE_MIN_ELEVATION_DEG = 20.0
# the lamp's reference frame: at least this many values well exposed, else a longer exposure, by at most
LAMP_REFERENCE_VALUES = 5_000
LAMP_REFERENCE_LONGER = 16.0


def lamp_reference_pose(plan: PlanFile) -> int:
    """Index of the pose the lamp is watched in: the one the plan expects the most diffuse-only samples
    from (the most of the object lit, so its reference frame has well-exposed pixels at the pose's
    shortest exposure) among those whose lamp is at least LAMP_REFERENCE_MIN_ELEVATION_DEG high where
    there are such; the first pose for a plan that does not say."""
    lit = np.array([sum((p.expected_diffuse or {}).values()) for p in plan.poses])
    # a lamp low over the table lights the object at grazing incidence, where the lamp's repeatability
    # moves the light most (measured: 0.36 % off the simulator's truth at −6°, within 0.1 % at 25°)
    high = np.array([p.light.elevation_deg >= LAMP_REFERENCE_MIN_ELEVATION_DEG for p in plan.poses])
    if (lit * high).any():
        lit = lit * high
    return int(np.argmax(lit)) if lit.any() else 0


class _LampReference:
    """The run's lamp watch (:mod:`hlr_lab.session.lamp`): the reference pose, the session's baseline frame
    (the first reference after any warm-up, read back on a resumed run) and its compared pixels."""

    def __init__(self, run: _Run, watch: LampWatch, pose: PlanPose, target: PoseTarget):
        self.run, self.watch, self.target = run, watch, target
        self.pose = pose.model_copy(update={"id": LAMP_REFERENCE})
        self.exposure_s = pose.exposures_s[0]
        self.exposed = False  # the exposure checked for well-exposed values (_longer)
        self.first, self.compared, self.baseline = None, None, None
        taken = [e for e in run.journal.events if e.get("event") == "lamp_reference"]
        self.count = len(taken)
        # the latest baseline counts (an earlier one may have been too dim: _longer), at its exposure; a
        # damaged one: a new one is taken
        if baselines := [e for e in taken if e.get("baseline")]:
            latest = baselines[-1]
            self.exposure_s, self.exposed = float(latest["exposure_s"]), True
            if frame_problem(run.session, latest) is None:
                self._set_baseline(load_frame(run.session, latest), latest["file"], latest["bits"])

    def _set_baseline(self, pixels: np.ndarray, name: str, bits: int) -> None:
        self.first, self.baseline = pixels, name
        self.compared = self._compared(pixels, bits, name)

    def _compared(self, pixels: np.ndarray, bits: int, name: str) -> np.ndarray:
        compared = compared_pixels(pixels, bits, self.watch.black_level_dn)
        if not compared.any():
            raise InputError(
                f"the lamp's reference frame {name} has no well-exposed pixel at {self.exposure_s:g} s: choose a "
                "plan whose first pose shows the object lit, or run with --lamp-every 0 --warm-up 0",
                field="--lamp-every",
            )
        return compared

    def _longer(self, frame: RawFrame) -> bool:
        """Whether the session's first reference frame, ``frame``, calls for a longer exposure (then set):
        it leaves fewer than LAMP_REFERENCE_VALUES values well exposed — a dark object, or a lamp far off,
        whose few bright values are its highlight, where a sharp lobe makes the sum of a hundred pixels
        jump by per cents between two frames of one lamp (measured: 117 values, a 5.3 % drop for a 0.5 %
        one). The exposure then puts the lit values' median at a third of full scale (at most
        LAMP_REFERENCE_LONGER × longer): thousands of the surface's diffuse values, the highlight clipped
        out. Asked once a session; that frame stays in the journal, the next is taken longer."""
        if self.exposed:
            return False
        self.exposed = True
        black = self.watch.black_level_dn
        if compared_pixels(frame.pixels, frame.bits, black).sum() >= LAMP_REFERENCE_VALUES:
            return False
        signal = np.asarray(frame.pixels, np.float64) - black
        span = (1 << frame.bits) - 1 - black
        lit = signal[signal > 0.02 * span]
        longer = float(np.clip(span / 3 / np.median(lit), 1.0, LAMP_REFERENCE_LONGER)) if lit.size else 1.0
        if longer <= 1.0:
            return False
        self.exposure_s *= longer
        log.info("lamp reference: %.4g s, for its diffuse values", self.exposure_s)
        return True

    def shoot(self, progress: Callable[[str], None]) -> float:
        """Photograph the reference pose and journal the lamp's output relative to the baseline (this
        frame is the baseline when there is none yet). Returns the output."""
        frame, name = self._photograph(progress, warming=False)
        if self.first is None and self._longer(frame):
            frame, name = self._photograph(progress, warming=False)
        if self.first is None:
            self._set_baseline(frame.pixels, name, frame.bits)
        assert self.first is not None  # _set_baseline sets first and compared
        assert self.compared is not None
        output = relative_output(frame.pixels, self.first, self.compared, self.watch.black_level_dn)
        self.run.journal.append(
            LampLine(event="lamp", at=frame.captured_at, output=output, baseline=self.baseline)
        )
        log.info("lamp: %.4f of the baseline (%s)", output, self.baseline)
        return output

    def warm_up(self, progress: Callable[[str], None]) -> None:
        """Keep the lamp on at the reference pose, photographing it, until its output is stable or the
        warm-up's time is up (:func:`hlr_lab.session.lamp.warm_up`; then a warning: the run goes on, its
        lamp lines show the drift). A resumed run's lamp, measured against its baseline already, is not
        waited for."""
        w = self.watch
        if w.warm_up_s <= 0 or self.baseline is not None:
            return
        compared = None

        def brightness() -> float:
            nonlocal compared
            frame, name = self._photograph(progress, warming=True)
            if compared is None and self._longer(frame):
                frame, name = self._photograph(progress, warming=True)
            if compared is None:
                compared = self._compared(frame.pixels, frame.bits, name)
            return float((np.asarray(frame.pixels, np.float64)[compared] - w.black_level_dn).sum())

        result = warm_up(brightness, w, self.run.instruments.clock, progress)
        self.run.journal.append(result.as_event())
        if not result.stable:
            log.warning("the lamp still changes by %.2f %% per minute after %.0f minutes of warm-up",
                        100 * result.per_minute, result.minutes)  # fmt: skip
        self.run.instruments.lamp.set(False)

    def _photograph(self, progress: Callable[[str], None], *, warming: bool) -> tuple[RawFrame, str]:
        """The reference pose photographed at its exposure, stored at once (a ``lamp`` line must never
        name a frame that is not on disk) and journaled; the lamp left on while ``warming``."""
        progress("lamp reference" if not warming else "warming the lamp up")
        i = self.run.instruments
        place = _Place(self.run, self.pose, self.target)
        i.lamp.set(True)
        i.camera.set_exposure(self.exposure_s)
        frame = _retry_capture(i.camera)
        if not warming:
            i.lamp.set(False)
        name = _free_name(self.run.session, f"lamp_{self.count:03d}")
        self.count += 1
        sidecar = Sidecar(pose=LAMP_REFERENCE, exposure_index=0, dark=False, exposure_s=frame.exposure_s,
                          gain_db=frame.gain_db, bits=frame.bits, captured_at=frame.captured_at, **place.state,
                          camera=frame.meta)  # fmt: skip
        stored = store_frame(self.run.session, name, frame.pixels, sidecar)
        fields = LampReferenceFields(pose=LAMP_REFERENCE, exposure_index=0, exposure_s=frame.exposure_s,
                                     dark=False, bits=frame.bits, baseline=self.first is None and not warming,
                                     warm_up=warming)  # fmt: skip
        self.run.journal.append(LampReferenceLine(event="lamp_reference", **fields, **stored.files()))
        return frame, stored.file


def _clipped(pixels: np.ndarray, bits: int, window: np.ndarray | None) -> int:
    """Pixels (inside ``window``, (H, W) bool, when given) with any channel clipped (:mod:`hlr_lab.geometry.clipping`,
    as the HDR merge judges them): their true value is unknown. pixels: (H, W, C) or (H, W)."""
    if window is not None and window.shape != pixels.shape[:2]:
        raise InputError(
            f"the camera delivers {pixels.shape[1]}×{pixels.shape[0]} frames, the rig file says "
            f"{window.shape[1]}×{window.shape[0]}: correct camera.width and camera.height (and calibrate "
            "at the camera's resolution)",
            field="camera.width",
        )
    if pixels.max() < clip_level(bits):  # the usual case, and 5× faster than counting
        return 0
    at_top = clipped(pixels, bits, channels=pixels.ndim == 3)
    return int((at_top & window).sum() if window is not None else at_top.sum())


def _retry_capture(camera: Camera) -> RawFrame:
    """Capture, retrying a dropped link or a frame cut short with growing pauses (each retry logged, so
    journaled); a refusal or a fault that stays is raised (and stops the run safely)."""
    return retried(
        camera.capture,
        retries=CAPTURE_RETRIES,
        backoff_s=RETRY_BACKOFF_S,
        on=(DeviceTimeout, ChecksumError),
        log=log,
    )


MOTION_RETAKES = 1  # a frame taken while an axis moved is retaken once; twice in a row stops the run


class _Place:
    """Where the rig stands for one pose: moved and settled on creation (journaled as a ``pose`` line),
    checked after every exposure, settled anew when an axis left."""

    def __init__(self, run: _Run, pose: PlanPose, target: PoseTarget):
        self.run, self.pose, self.target = run, pose, target
        self.state: PoseState
        self.settle(lamp=False)

    def settle(self, *, lamp: bool) -> None:
        """Move (again) to the target and wait for both axes; the lamp is off while the rig moves."""
        i = self.run.instruments
        if lamp:
            i.lamp.set(False)
        measured = _move(i, self.target, self.run.settle_timeout_s)
        temperatures = {k: v for t in i.thermometers for k, v in t.temperatures().items()}
        commanded = Axes(
            turntable_steps=self.target.turntable_steps, gantry_ticks=list(self.target.gantry_ticks)
        )
        self.state = PoseState(commanded=commanded, measured=measured, temperatures_c=temperatures)
        self.run.journal.append(PoseLine(event="pose", pose=self.pose.id, **self.state))
        log.info("%s: settled at %s, %s", self.pose.id, measured, temperatures)
        if lamp:
            i.lamp.set(True)

    def moved_during_exposure(self) -> str | None:
        """Which axis is now farther from its goal than the settle tolerance (None: none is)."""
        i, t, tol = self.run.instruments, self.target, self.run.tolerance
        (steps,) = i.turntable.position()
        ticks = i.gantry.position()
        off = []
        if abs(steps - t.turntable_steps) > tol.turntable_steps:
            off.append(f"the turntable was at {steps} steps (goal {t.turntable_steps})")
        for name, now, goal in zip(("azimuth", "elevation"), ticks, t.gantry_ticks, strict=False):
            if abs(now - goal) > tol.gantry_ticks:
                off.append(f"the {name} servo was at {now} ticks (goal {goal})")
        return ", ".join(off) or None


def _move(instruments: Instruments, target: PoseTarget, timeout_s: float) -> Axes:
    instruments.turntable.move_to((target.turntable_steps,))
    instruments.gantry.move_to(target.gantry_ticks)  # both travel at once; wait for the slower
    (steps,) = instruments.turntable.wait_settled(timeout_s)
    ticks = instruments.gantry.wait_settled(timeout_s)
    return Axes(turntable_steps=int(steps), gantry_ticks=[int(t) for t in ticks])


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
