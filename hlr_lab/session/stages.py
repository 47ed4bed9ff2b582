"""An adaptive session's plans (docs/sessions.md, "Adaptive sessions"): the pilot's, then each re-plan made
from what the photographs so far measured (one per round), each kept in the session's ``object/`` beside
the plan it was started with and named by a journal line (``pilot``, ``replan``) with its sha256.

The journal says which plan the session runs: the last such line's, else the plan it was started with. A
fit, a report and a resumed run all read the session's plan through :func:`current_plan`, so an adaptive
session is fitted from its pilot's poses when the run stopped before the re-plan, and from the re-plan's
(which holds the pilot's poses) after it.
"""

from __future__ import annotations

from pathlib import Path

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile, read_plan, write_plan
from hlr_lab.object.mesh import file_sha256
from hlr_lab.session.events import JournalLine, StagePlan
from hlr_lab.session.kept_object import OBJECT, checked_file

STAGES = ("pilot", "replan")  # the journal lines that name a plan, in the order a run writes them
_NAMES = {"pilot": "pilot's plan", "replan": "re-plan"}


def stage_file(stage: str, round_: int = 1) -> str:
    """Where a stage's plan is kept, relative to the session (beside the kept plan: the mesh it names is
    the kept one); a re-plan's after the first (``round_``) with its round in the name."""
    return f"{OBJECT}/plan-{stage}.json" if round_ == 1 else f"{OBJECT}/plan-{stage}-{round_}.json"


def stage_round(line: JournalLine) -> int:
    """A ``replan`` line's round (1 for the re-plan from the pilot; lines written before rounds have none)."""
    return int(line.get("round", 1))


def keep_stage_plan(session: Path, stage: str, plan: PlanFile, round_: int = 1) -> StagePlan:
    """Write ``plan`` as ``stage``'s plan (of ``round_``) in ``session`` (atomically) and return what its
    journal line names: the file and its sha256. Its mesh and texture must be named as the kept plan names
    them."""
    name = stage_file(stage, round_)
    write_plan(session / name, plan)
    return StagePlan(file=name, sha256=file_sha256(session / name))


def stage_lines(events: list[JournalLine]) -> dict[str, JournalLine]:
    """The last ``pilot`` and ``replan`` lines of a journal, by event name (the last re-plan's round is the
    session's)."""
    return {e["event"]: e for e in events if e.get("event") in STAGES}


def current_plan(
    session: Path, kept: tuple[PlanFile, Path], events: list[JournalLine]
) -> tuple[PlanFile, Path]:
    """The plan ``session`` runs: the last stage line's plan (checked against its sha256), else ``kept``
    (the plan it was started with, as :func:`hlr_lab.session.metadata.session_plan` gives it)."""
    lines = stage_lines(events)
    for stage in reversed(STAGES):
        if stage in lines:
            return stage_plan(session, lines[stage])
    return kept


def stage_plan(session: Path, line: JournalLine) -> tuple[PlanFile, Path]:
    """The plan a ``pilot`` or ``replan`` line names, and its path, checked against the line's sha256."""
    named = line.get("plan")
    if (
        not isinstance(named, dict)
        or not isinstance(line.get("round", 1), int)
        or named.get("file") != stage_file(line["event"], stage_round(line))
        or not isinstance(named.get("sha256"), str)
    ):
        raise InputError(
            f"the journal's {line.get('event')} line does not name its plan ({named!r}); restore the journal "
            "from a backup of the session",
            path=session / "journal.jsonl",
        )
    path = checked_file(session, named["file"], named["sha256"], _NAMES[line["event"]], "the run wrote it")
    return read_plan(path), path
