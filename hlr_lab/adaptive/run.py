"""The adaptive run as one function (see the package's docstring): pilot, fit, re-plan, the rest — in
rounds when a precision is asked.

Stages, each journaled before the next begins, so that a stopped run resumes where it stopped:

1. the pilot: the plan cut to :func:`~hlr_lab.adaptive.pilot.pilot_poses`, kept in the session as
   ``object/plan-pilot.json`` and named by a ``pilot`` line, then photographed as any plan is;
2. the photographs so far fitted (``theta_c_deg="auto"``, in memory: the session's materials.json is the
   whole run's), each region's θc taken from its fit (:func:`~hlr_lab.adaptive.theta_c.region_cones`) and,
   with a precision asked, its samples from its standard errors (:mod:`~hlr_lab.adaptive.precision`);
3. the re-plan: the plan's settings with those θc, the poses photographed counted as taken, kept as
   ``object/plan-replan.json`` (round 2 on: ``plan-replan-2.json`` …) and named by a ``replan`` line (the
   round, the θc per region, the poses added, the regions left short);
4. the re-plan photographed: the poses taken are in the session already, only the added ones move (and
   when it adds none, the rig is not opened again);
5. with rounds left (``rounds``: by default :data:`PRECISION_ROUNDS` with a precision asked, one without)
   and poses added, back to 2 with every photograph so far: a region the first re-plan left short of its
   precision (a lobe the pilot did not see, a factor held at its cap) is asked again from what the added
   poses measured, and one whose standard error stopped following its pixels is asked for nothing more.

The rig is opened for the pilot and again for each round: while the photographs are fitted and the object
planned again (seconds to a minute), the lamp is off and the axes are left safe, as after any run.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hlr_lab.acquisition.poses import Bracketing, Outcome, Step
from hlr_lab.acquisition.run import PLANNED_ONLY
from hlr_lab.adaptive.pilot import cut_to, pilot_poses
from hlr_lab.adaptive.precision import RegionNeed, region_needs
from hlr_lab.adaptive.theta_c import RegionCone, confirmed, region_cones, replan_cones
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile, PlanPose, read_plan
from hlr_lab.formats.planned_object import load_planned_mesh, mesh_to_turntable, planned_segmentation
from hlr_lab.instrument.control import NO_OVERRIDES
from hlr_lab.instrument.devices import Links
from hlr_lab.object.procedural import BUILTIN_PREFIX
from hlr_lab.pipeline import acquire_plan, plan_object, plan_settings
from hlr_lab.planning.planner import TakenLight
from hlr_lab.reflectance.session_fit import fit_session, open_session
from hlr_lab.rig.file import Rig
from hlr_lab.session.events import JournalLine, PilotLine, ReplanLine
from hlr_lab.session.folder import check_session_folder
from hlr_lab.session.journal import JOURNAL, Journal, read_journal
from hlr_lab.session.lamp import LampWatch
from hlr_lab.session.metadata import read_record, session_plan
from hlr_lab.session.stages import keep_stage_plan, stage_file, stage_lines, stage_plan, stage_round

MAX_PRECISION_PCT = 100.0  # a standard error, per cent of the value
# Re-plans a run with a precision asked makes by default: the first from the pilot, a second from what the
# first's poses measured (a lobe the pilot did not see, a factor held at MAX_FACTOR, poses that served
# several regions), a third from what the second's did. On Spot a dim lobe the pilot missed was measured
# at ±10 % from the first re-plan's poses and asked 16× again by the second (docs/planning.md, "A
# precision asked"); on the pebble the second round of ±0.1 % finds every region there and adds nothing
PRECISION_ROUNDS = 3
MAX_ROUNDS = 10


@dataclass(frozen=True)
class Replanned:
    """What a re-plan made of the photographs before it: its round (1: from the pilot's), each region's θc,
    the plan it runs (the poses taken first), the poses it added, the regions it leaves short (id → why),
    each region's samples when a precision was asked, and why it is the plan as made where the pilot
    confirmed it (:func:`~hlr_lab.adaptive.theta_c.confirmed`)."""

    cones: list[RegionCone]
    plan: PlanFile
    added: list[str]
    short: dict[int, str]
    needs: list[RegionNeed] | None = None
    round: int = 1
    plan_as_made: str | None = None


@dataclass
class AdaptiveOutcome:
    """An adaptive run: the pilot's poses, its run (None when a resumed run found it done), the last
    re-plan, the last run (the pilot's, when the first re-plan added nothing), how many poses the plan it
    started from had, the precision it was asked (per cent, or None), and the poses each round added."""

    pilot: list[str]
    pilot_run: Outcome | None
    replanned: Replanned
    run: Outcome
    planned_poses: int
    precision_pct: float | None = None
    added_per_round: tuple[int, ...] = ()

    @property
    def photographed_poses(self) -> int:
        """The poses the session holds: the pilot's and those the re-plans added."""
        return len(self.replanned.plan.poses)


def acquire_adaptive(
    plan_path: Path,
    rig: Rig,
    session: Path,
    *,
    links: Links = NO_OVERRIDES,
    bracket: Bracketing = PLANNED_ONLY,
    force: bool = False,
    progress: Callable[[Step], None] = lambda _: None,
    on_start: Callable[[bool], None] = lambda _resumed: None,
    lamp: LampWatch | None = None,
    on_stage: Callable[[str], None] = lambda _: None,
    precision_pct: float | None = None,
    rounds: int | None = None,
) -> AdaptiveOutcome:
    """Run the plan at ``plan_path`` adaptively into ``session`` (created, or resumed at its stage); see
    the module's docstring. ``precision_pct``: the standard error (per cent) asked of every region's Rd, Rs
    and n; each re-plan gives each region the samples its standard errors so far say that takes
    (:mod:`~hlr_lab.adaptive.precision`; None: the plan's M). ``rounds``: the most re-plans the session
    holds (default PRECISION_ROUNDS with a precision, else 1; a resumed run may be given more). ``on_stage``
    hears each stage begin, in a sentence; the other arguments are :func:`hlr_lab.pipeline.acquire_plan`'s."""
    original = read_plan(plan_path)
    lines = _stage_lines(session)
    precision_pct = _precision(original, plan_path, lines, precision_pct)
    rounds = _rounds(rounds, precision_pct)
    run = functools.partial(acquire_plan, plan_path, rig, session, links=links, bracket=bracket, force=force,
                            progress=progress, lamp=lamp)  # fmt: skip
    last_run, announced = None, False
    pilot = list(lines["pilot"]["poses"]) if "pilot" in lines else pilot_poses(original)
    if not pilot:
        raise InputError(
            "no pose of the plan puts a highlight on any region, so there is no pilot to measure θc from; plan "
            "again (hlr-lab plan says which regions it cannot reach and why)",
            path=plan_path,
        )
    if "replan" not in lines:
        stage = (
            stage_plan(session, lines["pilot"]) if "pilot" in lines else (cut_to(original, pilot), plan_path)
        )

        def started(resumed: bool) -> None:
            on_start(resumed)
            if "pilot" not in lines:
                _journal_pilot(session, pilot, precision_pct)

        on_stage(
            f"pilot: {len(pilot)} of the plan's {len(original.poses)} poses, a highlight on every region"
        )
        last_run, announced = run(on_start=started, stage=stage), True
        on_stage("fitting the pilot's photographs for each region's lobe")
        _replan(session, rig, on_stage, precision_pct, round_=1)
    pilot_run = last_run
    while True:
        replanned = _replanned(session)
        taken = len(replanned.plan.poses) - len(replanned.added)
        n, r = len(replanned.added), replanned.round
        on_stage(f"the re-plan: {n} pose(s) added to the pilot's {taken}" if r == 1
                 else f"re-plan {r}: {n} pose(s) added to the {taken} taken")  # fmt: skip
        if replanned.added:
            stage = (replanned.plan, session / stage_file("replan", replanned.round))
            last_run = run(on_start=(lambda _resumed: None) if announced else on_start, stage=stage)
            announced = True
        if not replanned.added or replanned.round >= rounds:
            break
        on_stage(f"fitting all {len(replanned.plan.poses)} poses' photographs for each region's lobe")
        _replan(session, rig, on_stage, precision_pct, round_=replanned.round + 1, previous=replanned.needs)
    if last_run is None:  # a finished session resumed, whose last re-plan added nothing: nothing to take
        stage = (replanned.plan, session / stage_file("replan", replanned.round))
        last_run = run(on_start=on_start, stage=stage)
    added = tuple(len(line["added"]) for line in _replan_lines(session))
    return AdaptiveOutcome(pilot, pilot_run, replanned, last_run, len(original.poses), precision_pct, added)


def _rounds(asked: int | None, precision_pct: float | None) -> int:
    """The most re-plans a run makes: ``asked``, checked, or the default for its precision."""
    if asked is None:
        return PRECISION_ROUNDS if precision_pct is not None else 1
    if not 1 <= asked <= MAX_ROUNDS:
        raise InputError(f"the rounds must be 1 to {MAX_ROUNDS}, got {asked}", field="--rounds")
    return asked


def _stage_lines(session: Path) -> dict[str, JournalLine]:
    """The session's pilot and re-plan lines; a session with frames but no pilot line was not started by an
    adaptive run and is refused."""
    if not session.is_dir():
        return {}
    check_session_folder(session)
    journal = session / JOURNAL
    events = read_journal(journal) if journal.is_file() else []
    lines = stage_lines(events)
    poses = lines["pilot"].get("poses") if "pilot" in lines else []
    if not (isinstance(poses, list) and all(isinstance(p, str) for p in poses)):
        raise InputError(
            f"the journal's pilot line does not list its poses ({poses!r}); restore the journal from a backup "
            "of the session",
            path=journal,
        )
    if not lines and any(e.get("event") == "frame" for e in events):
        raise InputError(
            "this session was started without --adaptive: continue it without --adaptive, or give a new --out",
            path=session,
        )
    return lines


def _precision(
    plan: PlanFile, plan_path: Path, lines: dict[str, JournalLine], asked: float | None
) -> float | None:
    """The precision the run goes by: the one its pilot line recorded when resumed (a different one
    asked is refused: the pilot was photographed for it), else ``asked``, checked."""
    if "pilot" in lines:
        recorded = lines["pilot"].get("precision_pct")
        if asked is not None and asked != recorded:
            was = "none" if recorded is None else f"{recorded:g} %"
            raise InputError(
                f"this adaptive session was started with precision {was}, not {asked:g} %: resume it without "
                "--precision (or with the same), or give a new --out",
                field="--precision",
            )
        return None if recorded is None else float(recorded)
    if asked is None:
        return None
    if not (math.isfinite(asked) and 0 < asked <= MAX_PRECISION_PCT):
        raise InputError(f"the precision must be above 0 and at most {MAX_PRECISION_PCT:g} %, got {asked:g}",
                         field="--precision")  # fmt: skip
    if plan.parameters.count != "pixels":
        raise InputError(
            "a precision can only be asked of a plan that counts pixels (the pilot's standard errors are "
            "of pixels); plan again without --count vertices",
            path=plan_path,
            field="--precision",
        )
    return float(asked)


def _journal_pilot(session: Path, pilot: list[str], precision_pct: float | None) -> None:
    """Keep the pilot's plan in the session (its object's files named as the kept plan names them) and
    journal it, before its first frame."""
    kept, _ = session_plan(session, read_record(session))
    stage = keep_stage_plan(session, "pilot", cut_to(kept, pilot))
    line = PilotLine(event="pilot", at=time.time(), poses=pilot, plan=stage)
    if precision_pct is not None:
        line["precision_pct"] = precision_pct
    with Journal(session / JOURNAL) as journal:
        journal.append(line)


def _replan(
    session: Path,
    rig: Rig,
    on_stage: Callable[[str], None],
    precision_pct: float | None,
    *,
    round_: int,
    previous: list[RegionNeed] | None = None,
) -> None:
    """Fit every photograph so far (the pilot's for ``round_`` 1), plan the rest with each region's θc
    (and, with a precision asked, its samples; ``previous`` the last round's), keep the re-plan and journal
    it. Without a precision each region's samples are counted in its lobe's core, or in the plan's cone
    where the core confirms it, and a pilot that confirms every one is followed by the rest of the plan
    (:func:`~hlr_lab.adaptive.theta_c.replan_cones`)."""
    fitted = fit_session(open_session(session), systematic=False).materials
    kept, kept_path = session_plan(session, read_record(session))
    lines = _stage_lines(session)
    taken_plan, _ = stage_plan(session, lines["replan" if "replan" in lines else "pilot"])
    cones = region_cones(kept, fitted)
    as_made = confirmed(kept, cones) if precision_pct is None and round_ == 1 else None
    if as_made is not None:
        on_stage("each region's θc measured: " + ", ".join(f"{c.region} {c.theta_c_deg:.1f}°" for c in cones))
        on_stage(f"the plan as made: {as_made}")
        _journal_replan(
            session,
            round_,
            cones,
            rest_of_plan(kept, taken_plan),
            len(taken_plan.poses),
            plan_as_made=as_made,
        )
        return
    by_id = (
        {c.region: c.theta_c_deg for c in cones} if precision_pct is not None else replan_cones(kept, cones)
    )
    on_stage(
        "re-planning with each region's θc: "
        + ", ".join(
            f"{c.region} {by_id[c.region]:.1f}°"
            + ("" if by_id[c.region] == c.theta_c_deg else f" (θc measured {c.theta_c_deg:.1f}°)")
            for c in cones
        )
    )
    mesh = load_planned_mesh(kept, kept_path)
    settings = replace(
        plan_settings(kept), region_theta_c_deg=tuple(by_id[r.id] for r in kept.object.regions)
    )
    needs = None
    if precision_pct is not None:
        needs = region_needs(kept, fitted, precision_pct, {n.region: n for n in previous or []})
        settings = replace(settings, highlight_factor=tuple(n.highlight_factor for n in needs),
                           diffuse_factor=tuple(n.diffuse_factor for n in needs))  # fmt: skip
        on_stage(
            f"samples for ±{precision_pct:g} %, times those so far (highlight/diffuse-only): "
            + ", ".join(f"{n.region} {n.highlight_factor:.2g}/{n.diffuse_factor:.2g}" for n in needs)
        )
    taken = [TakenLight(p.turntable_deg, np.array(p.light.position_m)) for p in taken_plan.poses]
    ref = kept.object.mesh
    spec = ref if ref.startswith(BUILTIN_PREFIX) else str(kept_path.parent / ref)
    planned, _ = plan_object(mesh, planned_segmentation(kept, mesh), rig, settings, mesh_spec=spec,
                             plan_folder=kept_path.parent, up=kept.object.up, scale=kept.object.scale,
                             to_turntable=mesh_to_turntable(kept), taken=taken)  # fmt: skip
    _journal_replan(session, round_, cones, _named(planned, kept, taken_plan), len(taken), needs=needs)


def _journal_replan(
    session: Path,
    round_: int,
    cones: list[RegionCone],
    planned: PlanFile,
    n_taken: int,
    *,
    needs: list[RegionNeed] | None = None,
    plan_as_made: str | None = None,
) -> None:
    """Keep a round's plan (its first ``n_taken`` poses those photographed) and journal its line."""
    stage = keep_stage_plan(session, "replan", planned, round_)
    added = [p.id for p in planned.poses[n_taken:]]
    short = {str(u.region): u.reason for u in planned.uncovered}
    line = ReplanLine(event="replan", at=time.time(), round=round_,
                      regions={str(c.region): c.as_line() for c in cones}, added=added, short=short,
                      plan=stage)  # fmt: skip
    if needs is not None:
        line["needs"] = {str(n.region): n.as_line() for n in needs}
    if plan_as_made is not None:
        line["plan_as_made"] = plan_as_made
    with Journal(session / JOURNAL) as journal:
        journal.append(line)


def rest_of_plan(kept: PlanFile, taken: PlanFile) -> PlanFile:
    """The plan as made as a re-plan lists it: the poses ``taken`` first (their frames are in the session),
    then the plan's others in its order, under their own ids."""
    done = {p.id for p in taken.poses}
    rest = [p for p in kept.poses if p.id not in done]
    return kept.model_copy(
        update={"poses": [*(p.model_copy(update={"purpose": "taken"}) for p in taken.poses), *rest]}
    )


def _named(planned: PlanFile, kept: PlanFile, taken: PlanFile) -> PlanFile:
    """The re-plan with the poses ``taken`` (the pilot's, or the last re-plan's) under their own ids and
    exposures (their frames are in the session), the added ones under ids neither the plan nor they use,
    and the object as the kept plan has it (its placement record too)."""
    used = {p.id for p in kept.poses} | {p.id for p in taken.poses}
    fresh = (f"p{k:03d}" for k in range(len(kept.poses), 10**6) if f"p{k:03d}" not in used)
    poses: list[PlanPose] = []
    for i, pose in enumerate(planned.poses):
        if i < len(taken.poses):
            was = taken.poses[i]
            poses.append(pose.model_copy(update={"id": was.id, "exposures_s": was.exposures_s}))
        else:
            poses.append(pose.model_copy(update={"id": next(fresh)}))
    return planned.model_copy(update={"poses": poses, "object": kept.object})


def _replanned(session: Path) -> Replanned:
    """The last re-plan as the journal and the session's files record it."""
    line = _stage_lines(session)["replan"]
    plan, _ = stage_plan(session, line)
    cones = [
        RegionCone(int(rid), float(c["theta_c_deg"]), c["source"], n=c.get("n"), reason=c.get("reason"))
        for rid, c in line["regions"].items()
    ]
    needs = None
    if "needs" in line:
        needs = [
            RegionNeed(
                int(rid),
                float(n["highlight_factor"]),
                float(n["diffuse_factor"]),
                n.get("highlight_se_pct"),
                n.get("diffuse_se_pct"),
                n.get("reason"),
                n.get("highlight_pixels"),
                n.get("diffuse_pixels"),
            )
            for rid, n in line["needs"].items()
        ]
    short = {int(k): v for k, v in line["short"].items()}
    return Replanned(
        cones, plan, list(line["added"]), short, needs, stage_round(line), line.get("plan_as_made")
    )


def _replan_lines(session: Path) -> list[ReplanLine]:
    """The session's re-plan lines, a round each, in order."""
    return [e for e in read_journal(session / JOURNAL) if e.get("event") == "replan"]  # type: ignore[misc]
