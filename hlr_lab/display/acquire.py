"""A run's motion sequence (``acquire`` before it moves), its progress, and its summary (after)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from hlr_lab.acquisition.poses import Outcome, Step
from hlr_lab.formats.plan import PlanFile
from hlr_lab.instrument.motion import PoseTarget


def motion_table(plan: PlanFile, targets: list[PoseTarget]) -> Table:
    """One row per pose: its angles (°), the stage steps and servo ticks sent, its exposures (s)."""
    t = Table(title="motion sequence", title_justify="left")
    for column in ("pose", "turntable", "azimuth", "elevation", "stage steps", "servo ticks", "exposures"):
        t.add_column(column, justify="right")
    for pose, target in zip(plan.poses, targets, strict=True):
        t.add_row(
            pose.id,
            f"{target.turntable_deg:g}°",
            f"{target.gantry_deg[0]:.2f}°",
            f"{target.gantry_deg[1]:.2f}°",
            str(target.turntable_steps),
            ", ".join(map(str, target.gantry_ticks)),
            ", ".join(f"{e:g}" for e in pose.exposures_s) + " s",
        )
    return t


def run_table(outcome: Outcome, session: Path) -> Table:
    """What the run did: frames taken, kept, retaken; poses; retries; its duration; the lamp's readings
    on a white reference beside the object; the camera's packets, where it counts them."""
    t = Table(title=f"session {escape(str(session))}", title_justify="left", show_header=False)
    t.add_column(justify="left")
    t.add_column(justify="right")
    for label, value in (
        ("frames taken", outcome.taken),
        ("frames already done", outcome.already_done),
        ("frames retaken (missing or changed)", len(outcome.retaken)),
        ("poses moved to", outcome.poses_moved),
        ("device retries", outcome.retries),
        ("duration", f"{outcome.duration_s:.1f} s"),
    ):
        t.add_row(label, str(value))
    if outcome.reference_poses is not None:  # the lamp watched on the white reference beside the object
        measured = f"{outcome.reference_measured} of {outcome.reference_poses} poses"
        t.add_row("lamp measured on the white reference", measured)
    if stream := outcome.camera_stream:  # a GigE Vision camera's link over the run
        t.add_row("camera packets (received / resent / missing)", stream_line(stream))
    return t


def stream_line(counters: dict[str, int]) -> str:
    """A camera stream's packets as "received / resent / missing" (Aravis's counters; 0 where absent)."""
    return " / ".join(
        f"{counters.get(k, 0):,}" for k in ("n_received_packets", "n_resent_packets", "n_missing_packets")
    )


@contextlib.contextmanager
def pose_progress(console: Console, poses: int) -> Iterator[Callable[[Step], None]]:
    """A bar on ``console`` over a run's ``poses``: the count, the time left and the current action; it
    gives the callable that :func:`hlr_lab.pipeline.acquire_plan` reports each step to."""
    columns = (
        TextColumn("pose {task.completed}/{task.total}"),
        BarColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.description}"),
    )
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task("starting", total=poses)

        def show(step: Step) -> None:
            done = step.index + (step.action == "done")
            bar.update(task, completed=done, description=escape(f"{step.pose}: {step.action}"))

        yield show
