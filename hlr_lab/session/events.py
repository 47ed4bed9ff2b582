"""The lines of a session's ``journal.jsonl`` and its frames' sidecars, as typed dictionaries: what hlr-lab
writes, checked by the type checker where each line is made (docs/sessions.md has the same table for
people). Units: times ``at``/``captured_at`` in Unix seconds, exposures in seconds, gains in dB.

Lines read back are JSON from disk, :data:`JournalLine`: only frame lines are checked field by field
(:mod:`hlr_lab.session.journal`); a reader of any other line checks what it uses.
"""

from __future__ import annotations

from typing import Any, Literal, NotRequired, TypedDict

JournalLine = dict[str, Any]  # a line as read back from disk (an object with an "event" name)


class Axes(TypedDict):
    """Axis positions in device units: the stage's steps, the gantry's servo ticks (azimuth, elevation)."""

    turntable_steps: int
    gantry_ticks: list[int]


class PoseState(TypedDict):
    """Where the rig stood for a pose: commanded and measured positions, the servos' temperatures (°C)."""

    commanded: Axes
    measured: Axes
    temperatures_c: dict[str, float]


class Sidecar(PoseState):
    """``frames/NAME.json``: what the rig recorded with one frame (``image_sha256`` added on storing)."""

    pose: str
    exposure_index: int
    dark: bool
    exposure_s: float
    gain_db: float
    bits: int
    captured_at: float
    camera: dict[str, Any]  # what the camera reported back, in its own words
    adaptive: NotRequired[bool]  # a plan pose's frames: the exposure was chosen on the rig
    clipped_pixels: NotRequired[int]
    clipped_counted_in: NotRequired[Literal["frame", "object window"]]
    image_sha256: NotRequired[str]


class FrameFields(TypedDict):
    """What a frame's journal line says of it besides its files (a resumed run decides from these)."""

    pose: str
    exposure_index: int
    exposure_s: float
    adaptive: bool
    dark: bool
    clipped_pixels: int


class StoredFiles(TypedDict):
    """A stored frame's files, relative to the session, and their SHA-256 checksums."""

    file: str
    sha256: str
    sidecar: str
    sidecar_sha256: str


class FrameLine(FrameFields, StoredFiles):
    """A stored frame of the plan: written once its two files are on disk."""

    event: Literal["frame"]


class LampReferenceFields(TypedDict):
    """A photograph of the lamp's reference pose (``--lamp-every``, ``--warm-up``)."""

    pose: str
    exposure_index: int
    exposure_s: float
    dark: bool
    bits: int
    baseline: bool  # the session's first after any warm-up: every lamp output is relative to it
    warm_up: bool


class LampReferenceLine(LampReferenceFields, StoredFiles):
    """A stored photograph of the lamp's reference pose."""

    event: Literal["lamp_reference"]


class RunStartLine(TypedDict):
    """A run starts (and how many intact frames it found)."""

    event: Literal["run_start"]
    at: float
    frames_done: int  # intact frames found


class PoseLine(PoseState):
    """The rig has settled at a pose (again after an axis moved during an exposure)."""

    event: Literal["pose"]
    pose: str


class RetryLine(TypedDict):
    """A retried device exchange, or a frame retaken because an axis moved."""

    event: Literal["retry"]
    at: float
    pose: str | None
    source: str  # the logger that reported it
    error: str


class OnReference(TypedDict):
    """With a white reference beside the object: the poses taken, and those that measured the lamp."""

    poses: int | None  # taken with the white reference beside the object
    measured: int  # of which the lamp was measured on it


class RunSummary(TypedDict):
    """The figures of a run, as its last line gives them."""

    frames_taken: int  # stored frames only
    frames_already_done: int
    frames_retaken: int
    poses_moved: int
    retries: int
    duration_s: float
    lamp_on_reference: NotRequired[OnReference]
    # a camera that counts its stream's packets (GigE Vision): Aravis's counters over the run
    camera_stream: NotRequired[dict[str, int]]


class RunEndLine(RunSummary):
    """The run's end: ``run_end``, or ``stopped`` with the reason."""

    event: Literal["run_end", "stopped"]
    at: float
    reason: NotRequired[str]  # "stopped" only


class SafeStepLine(TypedDict):
    """One device's safe state, as it confirmed it (or why it could not)."""

    device: str  # "lamp", "turntable", "gantry"
    ok: bool
    detail: str  # what it confirmed, or why it could not


class SafeStateLine(TypedDict):
    """After every run that switched devices on: what the safe state reached, device by device."""

    event: Literal["safe_state"]
    ok: bool
    steps: list[SafeStepLine]


class LampLine(TypedDict):
    """The lamp's output: relative to the baseline frame, or on the white reference beside the object
    relative to the rig file's sensitivity × power (then with its ``brightness`` S · Φ and ``pose``)."""

    event: Literal["lamp"]
    at: float
    output: float
    baseline: str | None
    brightness: NotRequired[float]
    pose: NotRequired[str]


class WarmUpLine(TypedDict):
    """A warm-up ended."""

    event: Literal["warm_up"]
    at: float
    stable: bool
    minutes: float  # rig time
    per_minute: float  # the lamp's trend at the end, a fraction


class StagePlan(TypedDict):
    """The plan an adaptive run's stage wrote into the session: its file (relative to the session) and
    sha256."""

    file: str
    sha256: str


class PilotLine(TypedDict):
    """An adaptive run's pilot: the poses of the plan it photographs first (one highlight per region), its
    plan (the plan's poses cut to those), and the precision asked of the run (per cent), if any."""

    event: Literal["pilot"]
    at: float
    poses: list[str]
    plan: StagePlan
    precision_pct: NotRequired[float]


class RegionThetaC(TypedDict):
    """A region's θc for the re-plan: measured on the pilot's photographs (with the fitted n), or the
    prior (the plan's θc) with why it was not measured."""

    theta_c_deg: float
    source: Literal["measured", "prior"]
    n: NotRequired[float]
    reason: NotRequired[str]


class RegionNeedLine(TypedDict):
    """A region's samples for the re-plan when a precision was asked: highlight (Rs, n) and diffuse-only
    (Rd) samples as multiples of what the photographs so far gave it, their fit's largest relative standard
    errors (%) of the parameters each serves and the pixels behind them, and why a factor is 0 (no more
    samples asked) or held at its cap."""

    highlight_factor: float
    diffuse_factor: float
    highlight_se_pct: NotRequired[float]
    diffuse_se_pct: NotRequired[float]
    highlight_pixels: NotRequired[int]
    diffuse_pixels: NotRequired[int]
    reason: NotRequired[str]


class ReplanLine(TypedDict):
    """An adaptive run's re-plan (``round`` 1 from the pilot's photographs, each later one from all the
    photographs before it): each region's θc (and, with a precision asked, its samples), the poses it adds
    after those taken, the regions it leaves short (id → why), its plan (the poses taken first), and, where
    the pilot confirmed the plan's cones, why the rest is the plan as made."""

    event: Literal["replan"]
    at: float
    round: NotRequired[int]
    regions: dict[str, RegionThetaC]
    needs: NotRequired[dict[str, RegionNeedLine]]
    added: list[str]
    short: dict[str, str]
    plan: StagePlan
    plan_as_made: NotRequired[str]  # why the re-plan is the rest of the plan as made (the pilot confirmed it)


SessionEvent = (
    RunStartLine
    | PoseLine
    | FrameLine
    | LampReferenceLine
    | RetryLine
    | RunEndLine
    | SafeStateLine
    | LampLine
    | WarmUpLine
    | PilotLine
    | ReplanLine
)
