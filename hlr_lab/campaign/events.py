"""The lines of a night's ``campaign.jsonl`` and the summaries ``--notify`` receives, as typed
dictionaries (docs/campaigns.md, "What it leaves"). Times ``at`` in Unix seconds."""

from __future__ import annotations

from typing import Literal, NotRequired, TypedDict


class RegionFigures(TypedDict):
    """One region's fitted material, as a job's result lists it (Rd and Rs linear RGB; n None unmeasured)."""

    id: int
    rd: list[float]
    rs: list[float] | None
    n: float | None


class JobOutcome(TypedDict):
    """A job's result: ``status`` done, skipped, stopped (the campaign stopped there) or failed."""

    name: str
    status: str
    attempts: int
    detail: str
    report: str | None
    materials: list[RegionFigures]


class CampaignStartLine(TypedDict):
    """The night starts: its jobs, and the forecast it was checked against."""

    event: Literal["campaign_start"]
    at: float
    file: str
    jobs: list[str]
    forecast_s: dict[str, float]  # per job
    forecast_bytes: dict[str, int]  # per acquire job


class JobStartLine(TypedDict):
    """A job starts."""

    event: Literal["job_start"]
    at: float
    job: str
    kind: str


class JobLampLine(TypedDict):
    """How an acquire job left to the defaults watches its lamp, and why: the sentence
    :func:`hlr_lab.session.lamp.lamp_watch_for` gives where the rig's radiometric record chose it."""

    event: Literal["job_lamp"]
    at: float
    job: str
    lamp: str


class JobRetryLine(TypedDict):
    """A job stopped by a device fault: run again (``job_retry``) or given up (``job_skip``)."""

    event: Literal["job_retry", "job_skip"]
    at: float
    job: str
    attempt: int
    error: str


class JobEndLine(JobOutcome):
    """A job ended, with its outcome."""

    event: Literal["job_end"]
    at: float
    job: str


class CampaignStoppedLine(TypedDict):
    """The night stopped before its end, and why."""

    event: Literal["campaign_stopped"]
    at: float
    reason: str


class CampaignEndLine(TypedDict):
    """The night ended: every job's status."""

    event: Literal["campaign_end"]
    at: float
    jobs: dict[str, str]  # job → status


class JobEndNotice(JobOutcome):
    """What ``--notify`` receives after every job."""

    event: Literal["job_end"]
    campaign: str


class NightNotice(TypedDict):
    """What ``--notify`` receives at the end or stop of the night."""

    event: Literal["campaign_end", "campaign_stopped"]
    campaign: str
    jobs: list[JobOutcome]
    reason: NotRequired[str]
