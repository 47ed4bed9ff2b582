"""Unattended campaigns: a night of jobs run one after another (docs/campaigns.md).

A campaign file (TOML) lists jobs: ``acquire`` (a plan on a rig: the run, then its fit and report) or
``calibrate`` (a procedure writing a calibrated rig file). :func:`run_campaign` forecasts the whole
night's disk space, runs the jobs in order and journals each start and end in ``campaign.jsonl``
(beside it, ``index.html``: every job's report and materials). An acquire job that stops safely on a
device fault is run again once (a new connection; the session resumes), then skipped, and the night
goes on — unless the rig could not be confirmed safe or an axis moved by itself (further motion is not
safe: everything stops), or the operator stopped it. After every job and at the end, a notification
hook hears a JSON summary.

How a job reaches its devices (the rig file's links, or a simulated world) is the caller's
(``links_for``): the command line builds simulated worlds, tests inject faults into them.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, ConfigDict, Field

from drivers.errors import DeviceError
from hlr_lab.acquisition.poses import AxisMoved, Step
from hlr_lab.campaign.events import (
    CampaignEndLine,
    CampaignStartLine,
    CampaignStoppedLine,
    JobEndLine,
    JobEndNotice,
    JobLampLine,
    JobOutcome,
    JobRetryLine,
    JobStartLine,
    NightNotice,
    RegionFigures,
)
from hlr_lab.errors import DiskFull, HlrLabError, InputError
from hlr_lab.files import StrictModel, atomic_write_text, free_bytes, read_toml, validate
from hlr_lab.formats.plan import read_plan
from hlr_lab.instrument.control import RunStopped
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.motion import estimate_duration_s, motion_targets
from hlr_lab.rig.file import RIG_FORMAT, Rig, load_rig, sim_rig
from hlr_lab.session.folder import check_new_session
from hlr_lab.session.journal import JOURNAL, Journal, read_journal
from hlr_lab.session.lamp import lamp_watch_for
from hlr_lab.session.outputs import check_outputs
from hlr_lab.session.space import MARGIN_BYTES, frame_bytes

log = logging.getLogger(__name__)

CAMPAIGN_JOURNAL = "campaign.jsonl"
INDEX = "index.html"
NOTIFY_TIMEOUT_S = 30.0


FilePath = Annotated[Path, Field(strict=False)]  # a TOML string (strict mode would want a Path object)


def _a_job_name(name: str) -> str:
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        raise ValueError(f"{name!r}: a job's name is 1–64 letters, digits, _ . and - (it names its files)")
    return name


JobName = Annotated[str, AfterValidator(_a_job_name)]


class AcquireJob(StrictModel):
    """A plan run on a rig into a session, then fitted and reported."""

    # merged with StrictModel's: the file's ``register`` and the field's own name both fill register_first
    model_config = ConfigDict(populate_by_name=True)
    kind: Literal["acquire"] = "acquire"
    name: JobName
    plan: FilePath
    rig: FilePath | None = None  # None: the built-in simulated rig (with sim = true)
    out: FilePath  # the session folder
    sim: bool = False
    true_rig: str | None = None  # with sim: the world's rig file
    scene: FilePath | None = None  # with sim: the world's scene file
    speed_factor: float = Field(default=1.0, gt=0, le=10_000)
    # None: as the rig's radiometric calibration says of its lamp (hlr_lab.session.lamp.lamp_watch_for)
    warm_up_min: float | None = Field(default=None, ge=0, le=600)
    warm_up_within: float = Field(default=0.2, ge=0.01, le=10)  # per cent per minute
    lamp_every: int | None = Field(default=None, ge=0, le=10_000)
    # ``register = true``: first measure where the object lies and run the plan made for it (OUT-placed.json);
    # named otherwise here, as pydantic's models have a ``register`` of their own
    register_first: bool = Field(default=False, alias="register")


class CalibrateJob(StrictModel):
    """A calibration procedure writing a calibrated rig file (run by the command line's calibrate)."""

    kind: Literal["calibrate"]
    name: JobName
    procedure: Literal["camera", "gantry", "radiometric", "all"]
    rig: FilePath | None = None
    output: FilePath
    sim: bool = False
    true_rig: str | None = None
    speed_factor: float = Field(default=1.0, gt=0, le=10_000)
    warm_up_min: float = Field(default=0.0, ge=0, le=600)  # radiometric: the lamp's warm-up
    warm_up_within: float = Field(default=0.2, ge=0.01, le=10)  # per cent per minute


JOB_KINDS = {"acquire": AcquireJob, "calibrate": CalibrateJob}


class _Header(StrictModel):
    name: str = "campaign"
    notify: str | None = None  # a command run with the JSON summary on stdin


@dataclass(frozen=True)
class CampaignFile:
    """A campaign file as read: its ``[campaign]`` header and its jobs, in order."""

    campaign: _Header
    job: list[AcquireJob | CalibrateJob]


@dataclass(frozen=True)
class Campaign:
    """A checked campaign: the file it came from, what it says, and the folder its night writes."""

    path: Path  # the campaign file
    file: CampaignFile
    folder: Path  # where campaign.jsonl and index.html go: NAME-campaign beside the file

    @property
    def jobs(self) -> list[AcquireJob | CalibrateJob]:
        return list(self.file.job)


def load_campaign(path: Path) -> Campaign:
    """Read and check a campaign file: every key known, every job's files there, names unique; paths in
    it are relative to the file's folder."""
    data = read_toml(path)
    unknown = set(data) - {"campaign", "job"}
    if unknown:
        raise InputError(
            f"unknown table {sorted(unknown)[0]!r}: a campaign has [campaign] and [[job]]", path=path
        )
    raw = data.get("job")
    if not isinstance(raw, list) or not raw:
        raise InputError("no [[job]] tables: list the night's jobs", path=path, field="job")
    jobs = []
    for i, job in enumerate(raw):
        kind = job.get("kind", "acquire") if isinstance(job, dict) else None
        if not isinstance(kind, str) or kind not in JOB_KINDS:
            raise InputError(
                f"kind {kind!r}: a job is 'acquire' or 'calibrate'", path=path, field=f"job[{i}].kind"
            )
        jobs.append(validate(JOB_KINDS[kind], {**job, "kind": kind}, path, at=f"job[{i}]"))
    header = validate(_Header, data.get("campaign", {}), path, at="campaign")
    base = path.parent
    names, checked = set(), []
    for i, job in enumerate(jobs):
        if job.name in names:
            raise InputError(
                f"two jobs are named {job.name!r}; give each its own name", path=path, field=f"job[{i}].name"
            )
        names.add(job.name)
        fields = {k: (base / v if isinstance(v, Path) and not v.is_absolute() else v) for k, v in job}
        job = type(job)(**fields)
        if isinstance(job, AcquireJob):
            twin = next(
                (j for j in checked if isinstance(j, AcquireJob) and _same_place(j.out, job.out)), None
            )
            if twin is not None:
                raise InputError(
                    f"job {job.name!r} would write into the session of job {twin.name!r} ({job.out}); give each "
                    "acquire job its own out",
                    path=path,
                    field=f"job[{i}].out",
                )
            try:  # a folder among someone's files is refused now, not in the middle of the night
                check_new_session(job.out, option="out for the job")
            except InputError as exc:
                raise InputError(f"job {job.name!r}: {exc}", path=path, field=f"job[{i}].out") from None
        for key in ("plan", "rig", "scene"):
            p = getattr(job, key, None)
            written = key == "rig" and p in {j.output for j in checked if isinstance(j, CalibrateJob)}
            if p is not None and not p.is_file() and not written:  # an earlier job's calibration may write it
                raise InputError(f"job {job.name!r}: no such file {p}", path=path, field=f"job[{i}].{key}")
        if job.rig is None and not job.sim:
            raise InputError(
                f"job {job.name!r}: give rig = FILE, or sim = true", path=path, field=f"job[{i}].rig"
            )
        if not job.sim and (job.true_rig or getattr(job, "scene", None)):
            raise InputError(f"job {job.name!r}: true_rig and scene describe a simulated world: add sim = true",
                             path=path, field=f"job[{i}].sim")  # fmt: skip
        checked.append(job)
    _check_calibration_outputs(path, checked)
    return Campaign(path, CampaignFile(header, checked), base / f"{path.stem}-campaign")


def _same_place(a: Path, b: Path) -> bool:
    """The same folder however written (``s``, ``x/../s``, relative or absolute, through a link)."""
    return os.path.realpath(a) == os.path.realpath(b)


def _check_calibration_outputs(path: Path, jobs: list[AcquireJob | CalibrateJob]) -> None:
    """A calibrate job writes its rig file over none of the night's inputs (the campaign file, a job's
    plan or scene, its own rig) and not into an acquire job's session; a later job may read it as its rig."""
    inputs = [path, *(getattr(j, key, None) for j in jobs for key in ("plan", "scene"))]
    sessions = [os.path.realpath(j.out) for j in jobs if isinstance(j, AcquireJob)]
    for i, job in enumerate(jobs):
        if not isinstance(job, CalibrateJob):
            continue
        try:
            check_outputs([job.output], [*inputs, job.rig], field=None, writes=[RIG_FORMAT])
        except InputError as exc:
            raise InputError(str(exc), path=path, field=f"job[{i}].output") from None
        inside = next((s for s in sessions if os.path.realpath(job.output).startswith(s + os.sep)), None)
        if inside is not None:
            raise InputError(f"{job.output} lies in the session of an acquire job ({inside}): write it elsewhere",
                             path=path, field=f"job[{i}].output")  # fmt: skip


def job_rig(job: AcquireJob | CalibrateJob) -> Rig:
    """The rig a job runs on as hlr-lab believes it: its rig file, else the built-in simulated rig."""
    return load_rig(job.rig) if job.rig is not None else sim_rig()


def _forecast_rig(campaign: Campaign, job: AcquireJob) -> Rig:
    """The rig a job will run on, as far as it is known before the night: the file, or, when an earlier
    calibration of the night writes it, the rig that calibration starts from (same camera size)."""
    for earlier in campaign.jobs:
        if earlier is job:
            break
        if (
            isinstance(earlier, CalibrateJob)
            and earlier.output == job.rig
            and not (job.rig and job.rig.is_file())
        ):
            return job_rig(earlier)
    return job_rig(job)


@dataclass(frozen=True)
class Forecast:
    """The night before it starts: per acquire job, frames still to take and their bytes; the estimated
    duration per job (seconds of motion and exposures, at the job's speed factor on a simulated rig)."""

    frames: dict[str, int]
    bytes_needed: dict[str, int]
    duration_s: dict[str, float]


def forecast(campaign: Campaign) -> Forecast:
    """Every acquire job's frames still to take (a session already there counts what it has), their
    upper-bound bytes, and each job's duration; refuses (DiskFull) when the jobs writing to one
    filesystem need more than it has free."""
    frames, needed, duration = {}, {}, {}
    by_filesystem: dict[int, list[AcquireJob]] = {}
    for job in campaign.jobs:
        if not isinstance(job, AcquireJob):
            continue
        rig, plan = _forecast_rig(campaign, job), read_plan(job.plan)
        have = {(e["pose"], e["exposure_index"]) for e in read_journal(job.out / JOURNAL)
                if e["event"] == "frame" and not e["dark"]} if (job.out / JOURNAL).is_file() else set()  # fmt: skip
        frames[job.name] = sum((p.id, k) not in have for p in plan.poses for k in range(len(p.exposures_s)))
        needed[job.name] = frames[job.name] * frame_bytes(rig.camera.width, rig.camera.height) + MARGIN_BYTES
        duration[job.name] = (
            estimate_duration_s(plan, motion_targets(plan, rig, job.plan), rig) / job.speed_factor
        )
        by_filesystem.setdefault(_device_of(job.out), []).append(job)
    for jobs in by_filesystem.values():
        names = [j.name for j in jobs]
        total, free = sum(needed[n] for n in names), free_bytes(jobs[0].out)
        if total > free:
            raise DiskFull(
                f"{campaign.path}: the night's frames need up to {total / 1e6:,.0f} MB where "
                f"{'job' if len(names) == 1 else 'jobs'} {', '.join(map(repr, names))} "
                f"{'writes' if len(names) == 1 else 'write'}, but {free / 1e6:,.0f} MB is free there; free space, or "
                "move some jobs' out elsewhere"
            )
    return Forecast(frames, needed, duration)


def _device_of(path: Path) -> int:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path.stat().st_dev


@dataclass
class JobResult:
    """How one job of the night ended, its report and (an acquire job's) fitted materials."""

    name: str
    status: str  # "done", "skipped", "stopped" (the campaign stopped there), "failed" (not a device fault)
    attempts: int = 0
    detail: str = ""
    report: str | None = None  # the job's report
    materials: list[RegionFigures] = field(default_factory=list)

    def as_dict(self) -> JobOutcome:
        """The result as the journal's ``job_end`` line and the notices carry it."""
        return JobOutcome(name=self.name, status=self.status, attempts=self.attempts, detail=self.detail,
                          report=self.report, materials=self.materials)  # fmt: skip


class CampaignStopped(HlrLabError):
    """The night stopped before its end: the operator, or a fault after which motion is not safe."""

    def __init__(self, message: str, exit_status: int):
        super().__init__(message)
        self.exit_status = exit_status


def raise_if_unfinished(results: list[JobResult]) -> None:
    """Raise :class:`HlrLabError` naming every job of the night that did not complete (a night with a
    failed job says so in the command's exit status)."""
    unfinished = [r for r in results if r.status != "done"]
    if unfinished:
        names = ", ".join(f"{r.name} ({r.status})" for r in unfinished)
        raise HlrLabError(
            f"{len(unfinished)} of {len(results)} jobs did not complete: {names}; see the table above"
        )


@dataclass(frozen=True)
class CampaignStep:
    """Progress: job ``index`` of ``total`` (its name), what happens now, and the rig seconds left."""

    index: int
    total: int
    job: str
    what: str
    eta_s: float


def run_campaign(
    campaign: Campaign,
    *,
    links_for: Callable[[AcquireJob, contextlib.ExitStack], Links],
    calibrate: Callable[[CalibrateJob], None],
    notify: str | None = None,
    progress: Callable[[CampaignStep], None] = lambda _: None,
) -> list[JobResult]:
    """Run every job (module docstring). ``links_for(job, stack)``: the links of an acquire job's devices
    (a simulated world kept open by ``stack`` for the job's attempts); ``calibrate(job)`` runs a
    calibration job; ``notify``: a shell command (default: the file's) that gets the JSON summary."""
    notify = notify or campaign.file.campaign.notify
    night = forecast(campaign)
    campaign.folder.mkdir(parents=True, exist_ok=True)
    results: list[JobResult] = []
    left = dict(night.duration_s)
    with Journal(campaign.folder / CAMPAIGN_JOURNAL) as journal:
        journal.append(CampaignStartLine(event="campaign_start", at=time.time(), file=str(campaign.path),
                                         jobs=[j.name for j in campaign.jobs], forecast_s=night.duration_s,
                                         forecast_bytes=night.bytes_needed))  # fmt: skip
        try:
            for i, job in enumerate(campaign.jobs):

                def say(what: str, done: float = 0.0, i=i, job=job) -> None:
                    """``done``: the fraction of this job's forecast already behind it."""
                    eta = sum(left.values()) - done * left.get(job.name, 0.0)
                    progress(CampaignStep(i, len(campaign.jobs), job.name, what, eta))

                journal.append(JobStartLine(event="job_start", at=time.time(), job=job.name, kind=job.kind))
                try:
                    result = _run_job(job, links_for, calibrate, say, journal)
                except KeyboardInterrupt:  # between a job's steps (its run turns it into a RunStopped)
                    raise CampaignStopped(f"stopped during job {job.name!r} (interrupted)", 130) from None
                left.pop(job.name, None)
                results.append(result)
                journal.append(
                    JobEndLine(event="job_end", at=time.time(), job=result.name, **result.as_dict())
                )
                write_index(campaign, results)
                _notify(
                    notify,
                    JobEndNotice(event="job_end", campaign=campaign.file.campaign.name, **result.as_dict()),
                )
        except CampaignStopped as exc:
            journal.append_last(
                CampaignStoppedLine(event="campaign_stopped", at=time.time(), reason=str(exc))
            )
            write_index(campaign, results)
            _notify(notify, NightNotice(event="campaign_stopped", campaign=campaign.file.campaign.name,
                                        reason=str(exc), jobs=[r.as_dict() for r in results]))  # fmt: skip
            raise
        journal.append_last(CampaignEndLine(event="campaign_end", at=time.time(),
                                            jobs={r.name: r.status for r in results}))  # fmt: skip
    _notify(notify, NightNotice(event="campaign_end", campaign=campaign.file.campaign.name,
                                jobs=[r.as_dict() for r in results]))  # fmt: skip
    return results


def _run_job(job, links_for, calibrate, say, journal: Journal) -> JobResult:
    if isinstance(job, CalibrateJob):
        say(f"calibrate {job.procedure}")
        try:
            calibrate(job)
        except KeyboardInterrupt:
            raise CampaignStopped(f"stopped during job {job.name!r} (interrupted)", 130) from None
        except HlrLabError as exc:
            return JobResult(job.name, "failed", 1, str(exc))
        return JobResult(job.name, "done", 1, f"wrote {job.output}")
    return _acquire_job(job, links_for, say, journal)


ATTEMPTS = 2  # a job stopped by a device fault is run once more (a new connection), then skipped


def _acquire_job(job: AcquireJob, links_for, say, journal: Journal) -> JobResult:
    from hlr_lab.pipeline import acquire_plan, fit_into, report_into
    from hlr_lab.registration import register_for_session

    rig = job_rig(job)
    warm_up_s = None if job.warm_up_min is None else 60 * job.warm_up_min
    watch, why = lamp_watch_for(rig, every=job.lamp_every, warm_up_s=warm_up_s,
                                stable_per_min=job.warm_up_within / 100)  # fmt: skip
    if why:
        say(why)
        journal.append(JobLampLine(event="job_lamp", at=time.time(), job=job.name, lamp=why))
    with contextlib.ExitStack() as world:
        try:
            links = links_for(job, world)
        except HlrLabError as exc:  # its simulated world could not be built (a scene file, a true rig)
            return JobResult(job.name, "failed", 0, str(exc))
        plan = job.plan
        if job.register_first:
            say("registering: where does the object lie?")
            try:
                plan, _ = register_for_session(job.plan, rig, job.out, links=links, progress=say)
            except RunStopped as stop:
                interrupted = isinstance(stop.cause, KeyboardInterrupt)
                if interrupted or not stop.safe.ok:  # as the acquisition's stops below
                    raise CampaignStopped(
                        f"job {job.name!r}, registering: {stop}", 130 if interrupted else 1
                    ) from None
                return JobResult(job.name, "failed", 0, f"registering: {stop}")
            except HlrLabError as exc:  # not found, out of range, not the plan's object: nothing to acquire
                return JobResult(job.name, "failed", 0, f"registering: {exc}")
        attempt = 0
        for attempt in range(1, ATTEMPTS + 1):
            say(f"acquiring (attempt {attempt})")

            def pose(step: Step) -> None:
                say(f"pose {step.index + 1}/{step.poses}: {step.action}", step.index / step.poses)

            try:
                acquire_plan(plan, rig, job.out, links=links, lamp=watch, progress=pose)
                break
            except RunStopped as stop:
                if isinstance(stop.cause, KeyboardInterrupt):
                    raise CampaignStopped(
                        f"stopped during job {job.name!r} (interrupted): {stop}", 130
                    ) from None
                if not stop.safe.ok or isinstance(stop.cause, AxisMoved):
                    raise CampaignStopped(f"job {job.name!r}: {stop} — the campaign stops: further motion is not "
                                          "safe until the rig is checked", 1) from None  # fmt: skip
                if isinstance(stop.cause, InputError):  # a file in the way, not the rig: again would not help
                    return JobResult(job.name, "failed", attempt, str(stop))
                journal.append(JobRetryLine(event="job_retry" if attempt < ATTEMPTS else "job_skip", at=time.time(),
                                            job=job.name, attempt=attempt, error=str(stop.cause)))  # fmt: skip
                log.warning("job %s, attempt %d: %s", job.name, attempt, stop)
                if attempt == ATTEMPTS or not isinstance(stop.cause, DeviceError | HlrLabError):
                    return JobResult(job.name, "skipped", attempt, str(stop))
            except HlrLabError as exc:  # not a stop on the rig: a plan, file or disk problem
                return JobResult(job.name, "failed", attempt, str(exc))
    say("fitting")
    try:
        fitted = fit_into(job.out)
        say("reporting")
        report, _, _ = report_into(job.out)
    except HlrLabError as exc:
        return JobResult(job.name, "failed", attempt, f"acquired; fit or report failed: {exc}")
    materials = [RegionFigures(id=e.id, rd=list(e.rd), rs=list(e.rs) if e.rs else None, n=e.n)
                 for e in fitted.materials.regions]  # fmt: skip
    return JobResult(job.name, "done", attempt, f"{job.out}", str(report), materials)


def _notify(command: str | None, summary: JobEndNotice | NightNotice) -> None:
    """Run ``command`` (a shell command line) with ``summary`` as JSON on stdin, for at most
    :data:`NOTIFY_TIMEOUT_S`; a failing or hanging hook is logged, never fatal."""
    if not command:
        return
    try:
        done = subprocess.run(command, shell=True, input=json.dumps(summary, default=str), text=True,
                              capture_output=True, timeout=NOTIFY_TIMEOUT_S, check=False)  # fmt: skip
    except subprocess.TimeoutExpired:
        log.warning("notify: %r did not finish within %g s; the campaign goes on", command, NOTIFY_TIMEOUT_S)
        return
    if done.returncode != 0:
        log.warning(
            "notify: %r exited %d: %s; the campaign goes on", command, done.returncode, done.stderr.strip()
        )


def campaign_status(campaign: Campaign) -> Iterator[str]:
    """Lines for the operator, read from the journals while the campaign runs (or after): each job's
    state, the running job's last pose and faults, the time left."""
    path = campaign.folder / CAMPAIGN_JOURNAL
    if not path.is_file():
        yield f"{campaign.path}: not started (no {path})"
        return
    events = read_journal(path)
    start = next((e for e in events if e["event"] == "campaign_start"), {})
    ended = {e["job"]: e for e in events if e["event"] == "job_end"}
    started = {e["job"] for e in events if e["event"] == "job_start"}
    finished = next((e for e in events if e["event"] in ("campaign_end", "campaign_stopped")), None)
    forecast = start.get("forecast_s")
    left = None
    if isinstance(forecast, dict) and all(_seconds(s) for s in forecast.values()):
        left = sum(s for name, s in forecast.items() if name not in ended)
    for job in campaign.jobs:
        if job.name in ended:
            e = ended[job.name]
            yield f"{job.name}: {e.get('status', '(no status)')} ({e.get('detail', '')})"
        elif job.name in started and finished is None:
            yield f"{job.name}: running" + (_session_line(job.out) if isinstance(job, AcquireJob) else "")
        else:
            yield f"{job.name}: waiting"
    if finished is None:
        yield (
            f"{path}: the forecast of its campaign_start line is damaged; time left unknown"
            if left is None
            else f"about {left / 60:.0f} min of rig time left (forecast)"
        )
    else:
        reason = str(finished.get("reason", "(no reason recorded)"))
        yield f"campaign {'ended' if finished['event'] == 'campaign_end' else 'stopped: ' + reason}"


def _seconds(value: object) -> bool:
    """A forecast entry the log can be trusted with: a finite, non-negative number of seconds."""
    return isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value < float("inf")


def _session_line(session: Path) -> str:
    if not (session / JOURNAL).is_file():
        return ", starting"
    events = read_journal(session / JOURNAL)
    poses = [e["pose"] for e in events if e["event"] == "pose"]
    retries = sum(e["event"] == "retry" for e in events)
    frames = sum(e["event"] == "frame" for e in events)
    return f", at pose {poses[-1] if poses else '—'}, {frames} frames, {retries} retries"


def write_index(campaign: Campaign, results: list[JobResult]) -> Path:
    """``index.html``: every job's status, a link to its report and its materials table."""
    from hlr_lab.report import html as h

    rows, sections = [], []
    for r in results:
        # relative to the index: the night's folders can move together
        target = os.path.relpath(Path(r.report).resolve(), campaign.folder.resolve()) if r.report else None
        link = f'<a href="{h.escape(target)}">report</a>' if target else ""
        rows.append([h.escape(r.name), h.escape(r.status), str(r.attempts), h.escape(r.detail), link])
        if r.materials:
            mat = [[str(m["id"]), " ".join(f"{v:.4f}" for v in m["rd"]),
                    " ".join(f"{v:.4f}" for v in m["rs"]) if m["rs"] else "unmeasured",
                    f"{m['n']:.1f}" if m["n"] else ""] for m in r.materials]  # fmt: skip
            sections.append(f"<h2>{h.escape(r.name)}</h2>" + h.table(["region", "Rd", "Rs", "n"], mat))
    page = (
        f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{h.escape(campaign.file.campaign.name)}'
        f"</title><style>{h.STYLE}</style></head><body><h1>{h.escape(campaign.file.campaign.name)}</h1>"
        + h.table(["job", "status", "attempts", "detail", ""], rows, numeric_from=2)
        + "".join(sections)
        + "</body></html>\n"
    )
    atomic_write_text(campaign.folder / INDEX, page)
    return campaign.folder / INDEX
