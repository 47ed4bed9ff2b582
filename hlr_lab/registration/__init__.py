"""``hlr-lab register``: photograph the object where it lies, measure its placement, and plan again for it
(docs/placement.md).

:func:`register_plan` is the whole step, as the command, ``acquire --register`` and other programs call
it: the registration photographs (:mod:`~hlr_lab.registration.capture`; skipped when solving again from
an earlier folder), read back (:mod:`~hlr_lab.registration.views`), the placement measured
(:mod:`~hlr_lab.registration.measure`), the plan made again for it (:func:`hlr_lab.pipeline.replan_placed`),
the summary page (:mod:`~hlr_lab.registration.summary`), and the placed plan written — in one piece, and
only when all of that succeeded.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlr_lab.acquisition.poses import Outcome, Step
from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PLAN_FORMAT, PlacementRecord, PlanFile, read_plan, write_plan
from hlr_lab.instrument.control import NO_OVERRIDES
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.pipeline import replan_placed
from hlr_lab.planning.planner import PlanResult
from hlr_lab.registration.capture import capture_views
from hlr_lab.registration.measure import Measured, measure_placement, placement_record
from hlr_lab.registration.summary import write_summary
from hlr_lab.registration.views import read_photographs
from hlr_lab.rig.file import Rig
from hlr_lab.session.metadata import SESSION
from hlr_lab.session.outputs import check_outputs

CAMERA_AGREES_PX = 0.05  # the rig's camera and the photographs' may differ by this at the object (rounding)


@dataclass(frozen=True, eq=False)
class Registered:
    """A registration's outcome: the placement measured, its record, the placed plan (written at
    ``output``) and its planner result, the photographs' folder, the capture (None when solving again), the
    summary page (None and why when it could not be written), and the seconds each step took."""

    measured: Measured
    record: PlacementRecord
    plan: PlanFile
    result: PlanResult
    output: Path
    folder: Path
    captured: Outcome | None
    summary: Path | None
    summary_problem: str | None
    seconds: dict[str, float]

    @property
    def uncovered(self) -> list[int]:
        """The regions the placed plan cannot give their samples (the plan command's exit 3)."""
        return [int(r) for r in np.flatnonzero(~self.result.satisfied)]


def register_plan(
    plan_path: Path,
    rig: Rig,
    folder: Path,
    output: Path,
    *,
    links: Links = NO_OVERRIDES,
    solve_only: bool = False,
    progress: Callable[[str], None] = lambda _: None,
    on_step: Callable[[Step], None] = lambda _: None,
    on_start: Callable[[bool], None] = lambda _resumed: None,
) -> Registered:
    """Register ``plan_path``'s object on ``rig``: photograph it into ``folder`` (unless ``solve_only``:
    the photographs already there), measure where it lies, plan again for it and write the placed plan at
    ``output``. ``progress`` hears each step, ``on_step`` the photographs' poses."""
    plan = read_plan(plan_path)
    check_outputs([output], [plan_path], writes=[PLAN_FORMAT])
    motion_targets(plan, rig, plan_path)  # a plan for another rig is refused before anything moves
    seconds: dict[str, float] = {}
    lap = time.perf_counter()

    def took(step: str) -> None:  # the seconds since the last step ended
        nonlocal lap
        seconds[step], lap = time.perf_counter() - lap, time.perf_counter()

    captured = None
    if not solve_only:
        progress("photographing the object…")
        captured = capture_views(
            plan, plan_path, rig, folder, links=links, progress=on_step, on_start=on_start
        )
    took("photographs")
    photographs = read_photographs(folder)
    _same_camera(photographs.rig, rig, folder)
    measured = measure_placement(plan, plan_path, photographs, folder, progress=progress)
    record = placement_record(measured, plan)
    took("solve")
    progress("planning again for where it lies…")
    placed, result = replan_placed(plan, plan_path, measured.mesh, rig, record, measured.found.mesh_to_turntable,
                                   output)  # fmt: skip
    took("plan")
    summary, problem = None, None
    try:
        summary = write_summary(measured, photographs, plan, record, folder)
    except OSError as exc:  # the placed plan does not depend on the page
        problem = f"{folder}: the summary page could not be written ({exc.strerror or exc})"
    write_plan(output, placed)
    return Registered(measured, record, placed, result, output, folder, captured, summary, problem, seconds)


def session_placed_plan(session: Path) -> tuple[Path, Path]:
    """Where registering for ``session`` puts its placed plan and its photographs: beside the session,
    ``SESSION-placed.json`` and ``SESSION-registration/`` (``acquire --register``, a campaign's register)."""
    return session.with_name(f"{session.name}-placed.json"), session.with_name(f"{session.name}-registration")


def register_for_session(
    plan_path: Path,
    rig: Rig,
    session: Path,
    *,
    links: Links = NO_OVERRIDES,
    progress: Callable[[str], None] = lambda _: None,
    on_step: Callable[[Step], None] = lambda _: None,
) -> tuple[Path, Registered | None]:
    """The plan to run into ``session`` for ``plan_path``'s object where it lies: registered now (the placed
    plan's path and the registration), or — ``session`` started already — the placed plan it was started
    with, and None (the object has not been moved since, or the session's frames would not be one
    object's placement). Refuses a started session that was not registered."""
    placed, photographs = session_placed_plan(session)
    if (session / SESSION).exists():
        if not placed.is_file():
            raise InputError(
                f"this session was started without registering (there is no {placed.name} beside it): resume it "
                "without --register, or give a new --out",
                path=session,
            )
        progress(f"resuming with the placement measured before: {placed}")
        return placed, None
    return placed, register_plan(
        plan_path, rig, photographs, placed, links=links, progress=progress, on_step=on_step
    )


def _same_camera(taken_with: Rig, rig: Rig, folder: Path) -> None:
    """Refuse photographs taken with another camera (its calibration changed since): the outlines are
    measured with the camera that took them, the plan made for ``rig``'s."""
    probe = np.array([[0.0, 0.0, 0.05], [0.05, 0.0, 0.0], [0.0, 0.05, 0.1]])  # points near the object
    a, _ = taken_with.camera.project(probe)
    b, _ = rig.camera.project(probe)
    if not np.allclose(a, b, atol=CAMERA_AGREES_PX, equal_nan=True):
        raise InputError(
            f"its photographs were taken with another camera calibration than {rig.source}'s (points near the "
            f"object move by {float(np.nanmax(np.abs(a - b))):.2f} px): register again with this rig file, or "
            "solve with the one they were taken with",
            path=folder,
        )
