"""``hlr-lab acquire``: run a plan on the rig (or the simulated rig) into a session directory."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict

import click
from rich.markup import escape

from hlr_lab.acquisition.poses import Bracketing, Step
from hlr_lab.adaptive.pilot import pilot_poses
from hlr_lab.adaptive.run import MAX_ROUNDS, PRECISION_ROUNDS, AdaptiveOutcome, acquire_adaptive
from hlr_lab.adaptive.theta_c import plan_cones
from hlr_lab.cli.common import (
    FILE,
    FOLDER,
    believed_rig,
    object_offset_option,
    speed_factor_option,
    true_rig_option,
    warm_up_options,
)
from hlr_lab.cli.console import console
from hlr_lab.cli.plan_cmd import EXIT_UNCOVERED
from hlr_lab.cli.register_cmd import show_registered
from hlr_lab.display.acquire import motion_table, pose_progress, run_table
from hlr_lab.display.adaptive import adaptive_lines, cones_table, needs_table
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile, read_plan
from hlr_lab.formats.planned_object import load_planned_mesh, placement_line
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.motion import estimate_duration_s, motion_targets
from hlr_lab.pipeline import acquire_plan
from hlr_lab.placement.photographs import registration_lamps
from hlr_lab.registration import register_for_session
from hlr_lab.registration.capture import VIEWS
from hlr_lab.rig.file import Rig
from hlr_lab.session.lamp import LampWatch, lamp_watch_for


@click.command("acquire")
@click.option("--plan", "plan_path", type=FILE, required=True, help="plan.json.")
@click.option("--rig", "rig_path", type=FILE, help="Rig file (rig.toml).")
@click.option(
    "--sim",
    is_flag=True,
    help="Run on the simulated rig (servos, turntable, lamp, Mitsuba camera); with --rig, a simulated "
    "world built as that rig file says, reached through the simulator's own links.",
)
@true_rig_option
@click.option(
    "--scene",
    "scene_path",
    type=FILE,
    help="With --sim: the simulated world (sim scene file; its mesh must be the plan's). Default: the "
    "plan's mesh with a default material per region.",
)
@object_offset_option
@click.option(
    "--out",
    "out",
    type=FOLDER,
    help="Session directory (default: PLAN-session beside the plan). Given again, the run resumes.",
)
@click.option(
    "--dark-frames",
    is_flag=True,
    help="Also take each exposure with the lamp off (ambient light to subtract).",
)
@click.option(
    "--lamp-every",
    type=click.IntRange(min=0),
    default=None,
    metavar="N",
    help="Watch the lamp: photograph the plan's best-lit pose again before the first pose, every N poses and "
    "at the end; fit divides each pose's light by the lamp's output then (0: do not watch). Default: 5 where "
    "the rig's radiometric calibration saw the lamp warm up or drift, else 0 (docs/sessions.md, \"The "
    'lamp"). A rig whose white reference lies beside the object (run_place_m) watches it in every pose '
    "without this.",
)
@warm_up_options("Before the first pose", "; a resumed run does not wait again", as_calibrated=True)
@click.option(
    "--register",
    "register_first",
    is_flag=True,
    help="First measure where the object lies (hlr-lab register: photographs in SESSION-registration, the "
    "plan made again for it in SESSION-placed.json), then run that plan. A resumed session keeps its plan.",
)
@click.option(
    "--adaptive",
    is_flag=True,
    help="Photograph a pilot first (the plan's poses that put a highlight on every region once), measure each "
    "region's lobe, plan the rest again in each lobe's core (or the plan's cone, where the core confirms it) and "
    "take what the re-plan adds: where every lobe confirms the plan, the rest of the plan as made "
    "(docs/planning.md). Exit status 3 when the re-plan leaves a region short.",
)
@click.option(
    "--precision",
    "precision_pct",
    type=float,
    default=None,
    metavar="PCT",
    help="With --adaptive: the standard error asked of every region's Rd, Rs and n, per cent of the value; "
    "the re-plan gives each region the samples its pilot's standard errors say that takes (at least the "
    "plan's M, at most 16× what the pilot gave it; plan --max-lights bounds the photographs). A region the "
    "rig cannot give them is named (exit status 3). Default: the plan's M.",
)
@click.option(
    "--rounds",
    type=click.IntRange(1, MAX_ROUNDS),
    default=None,
    help="With --adaptive: the most re-plans, each from every photograph so far (a lobe the pilot missed, a "
    "precision not yet reached); the run ends sooner when one adds nothing. Default: "
    f"{PRECISION_ROUNDS} with --precision, else 1. A session whose rounds ran out goes on when resumed with more.",
)
@click.option("--dry-run", is_flag=True, help="Check the plan against the rig, print the motions, stop.")
@click.option("--force", is_flag=True, help="Resume a session although the plan or rig file changed.")
@speed_factor_option("With --sim: simulated")
def acquire_cmd(plan_path, rig_path, sim, true_rig, scene_path, object_offset, out, dark_frames, lamp_every,
                warm_up_min, warm_up_within, register_first, adaptive, precision_pct, rounds, dry_run, force,
                speed_factor):  # fmt: skip
    """Move to every pose of the plan, capture its exposure bracket, and journal every frame.

    A frame counts once its file and its journal line are on disk; killing the run loses at most the
    frames in flight. Running the same command again resumes: finished frames are checked and kept,
    the rest are taken. Whatever happens, the lamp ends off, the turntable stopped and the gantry
    parked as the rig file says (torque off by default), each read back from the device; the last line
    says what was confirmed. Ctrl-C or kill: exit status 130 (a second signal does not cut the safe
    stop short); exit status 1 when a device failed or the rig could not be confirmed safe. One run
    at a time per session and per device: a second one is refused, naming the first.

    \b
    Examples:
      hlr-lab acquire --plan plan.json --sim
      hlr-lab acquire --plan plan.json --rig rig.toml --dry-run
      hlr-lab acquire --plan plan.json --rig rig.toml --out sessions/bunny-1
      hlr-lab acquire --plan plan.json --sim --true-rig builtin:bench-offsets   # a rig off its drawing
      hlr-lab acquire --plan plan.json --sim --object-offset 2,-1.5,3   # the object not where planned
      hlr-lab acquire --plan plan.json --rig rig.toml --warm-up 30 --lamp-every 5   # overnight
      hlr-lab acquire --plan plan.json --rig rig.toml --register --out sessions/bunny-2   # placed by hand
      hlr-lab acquire --plan plan.json --rig rig.toml --adaptive   # θc measured on a pilot, then re-planned
      hlr-lab acquire --plan plan.json --rig rig.toml --adaptive --precision 0.5   # every parameter to ±0.5 %
    """
    for given, option in ((scene_path, "--scene"), (object_offset, "--object-offset")):
        if given is not None and not sim:
            raise InputError("describes the simulated world: use it with --sim", field=option)
    if precision_pct is not None and not adaptive:
        raise InputError(
            "is what an adaptive run re-plans for: use it with --adaptive (a plan's own samples are its M: "
            "plan again with a larger --min-samples)",
            field="--precision",
        )
    if rounds is not None and not adaptive:
        raise InputError("counts an adaptive run's re-plans: use it with --adaptive", field="--rounds")
    if register_first and dry_run:
        raise InputError(
            "a dry run moves nothing, so it cannot register: leave out one of them", field="--register"
        )
    rig = believed_rig(rig_path, sim, true_rig)
    session = out or plan_path.with_name(f"{plan_path.stem}-session")
    with contextlib.ExitStack() as stack:  # the simulated world, when there is one, outlives the run
        links = Links()
        if sim and not dry_run:  # the simulator is reached only from the command line (the composition root)
            from worlds.plan_world import ObjectOffset, sim_links

            offset = None if object_offset is None else ObjectOffset.from_option(object_offset)
            links = sim_links(
                stack, rig, read_plan(plan_path), plan_path, scene_path, true_rig, speed_factor, offset
            )
        if register_first:
            plan_path = _registered(plan_path, rig, session, links)
        plan = read_plan(plan_path)
        targets = motion_targets(plan, rig, plan_path)
        if not sim and plan.object.placement is None:  # the simulated world lies as planned unless told
            console.print(f"[bold yellow]placement {escape(placement_line(plan))}[/]", soft_wrap=True)
        console.print(motion_table(plan, targets))
        if dry_run:
            # the object the run would load: a mesh that changed is said now
            load_planned_mesh(plan, plan_path)
            frames = sum(len(p.exposures_s) for p in plan.poses)
            duration = estimate_duration_s(plan, targets, rig)
            console.print(
                f"{len(targets)} poses, {frames} frames: within limits; about {duration:.0f} s on this rig"
            )
            if adaptive:
                console.print(
                    f"adaptive: the pilot takes {', '.join(pilot_poses(plan))}; the rest is planned again"
                )
            return 0
        lamp, why = lamp_watch_for(rig, every=lamp_every, stable_per_min=warm_up_within / 100,
                                   warm_up_s=None if warm_up_min is None else 60 * warm_up_min)  # fmt: skip
        if why:
            console.print(escape(why), soft_wrap=True)
        options = _RunOptions(
            links=links,
            bracket=Bracketing(dark_frames=dark_frames),
            force=force,
            lamp=lamp,
            on_start=lambda resumed: console.print(
                f"{'resuming' if resumed else 'starting'} session {escape(str(session))}"
            ),
        )
        short = {}
        if adaptive:
            done = _adaptive(
                functools.partial(
                    acquire_adaptive,
                    plan_path,
                    rig,
                    session,
                    precision_pct=precision_pct,
                    rounds=rounds,
                    **options,
                ),
                plan,
            )
            outcome, short = done.run, done.replanned.short
        else:
            with pose_progress(console, len(targets)) as show:
                outcome = acquire_plan(plan_path, rig, session, progress=show, **options)
    console.print(run_table(outcome, session))
    # the last line: what the devices confirmed (a run that stops says it in its error)
    if outcome.safe is not None:
        console.print(f"the rig is safe: {escape(outcome.safe.sentence())}", soft_wrap=True)
    return EXIT_UNCOVERED if short else 0  # as plan's, for a re-plan that leaves regions short


class _RunOptions(TypedDict):
    """What a run is given besides its plan, rig and session, the same with or without --adaptive."""

    links: Links
    bracket: Bracketing
    force: bool
    lamp: LampWatch
    on_start: Callable[[bool], None]


def _adaptive(run: Callable[..., AdaptiveOutcome], plan: PlanFile) -> AdaptiveOutcome:
    """``--adaptive``: the run, a progress bar per stage, and what it measured and decided."""
    with contextlib.ExitStack() as bars:
        stages: list[Callable[[Step], None]] = []

        def stage(what: str) -> None:
            bars.close()
            console.print(escape(what), soft_wrap=True)
            stages.clear()

        def progress(step: Step) -> None:
            if not stages:
                stages.append(bars.enter_context(pose_progress(console, step.poses)))
            stages[0](step)

        done = run(progress=progress, on_stage=stage)
    console.print(cones_table(done, plan_cones(plan)))
    if (needs := needs_table(done)) is not None:
        console.print(needs)
    for line in adaptive_lines(done):
        console.print(line, soft_wrap=True)
    return done


def _registered(plan_path: Path, rig: Rig, session: Path, links: Links) -> Path:
    """``--register``: the placed plan for the session, measured now or the one it was started with."""
    with pose_progress(console, VIEWS * len(registration_lamps(rig))) as show:
        placed, done = register_for_session(plan_path, rig, session, links=links, on_step=show,
                                            progress=lambda what: console.print(escape(what)))  # fmt: skip
    if done is not None:
        show_registered(done)
        if done.uncovered:
            console.print(
                "[yellow]acquiring anyway: the regions above get fewer samples than the plan asked[/]"
            )
    return placed
