"""``hlr-lab bench acquire``: the acquisition loop's own cost on the simulated rig, with the real drivers.

Software overhead per pose is the pose's wall time minus the time spent waiting for the axes to arrive
and settle (``wait_settled``) and for the camera to expose and deliver its frame (``capture``); what is
left is hlr-lab's work on the critical path: commands, the pose journal line, temperatures, the lamp,
clipping checks, handing frames to the writer. Motion runs at a high speed factor so that the wait does
not hide anything. Transactions are counted where they arrive: instruction packets at the simulated
servo bus, requests at the Modbus server.

It builds the simulator: only the command line imports it (the composition root).
"""

from __future__ import annotations

import itertools
import resource
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.numerical import SessionFitFigures, run_session_fit_case
from drivers.protocols import Camera, Positioner, RawFrame, StreamCounters
from hlr_lab.acquisition.poses import Step, acquire
from hlr_lab.display.acquire import stream_line
from hlr_lab.formats.plan import PlanFile, write_plan
from hlr_lab.instrument.control import open_rig
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.mesh import file_sha256
from hlr_lab.object.procedural import builtin_object
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import plan_object
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.file import Rig, sim_rig
from hlr_lab.session.metadata import start_or_resume
from sim.rig import SimRig
from worlds.plan_world import sim_scene, world_geometry, world_links

BENCH_OBJECT = "builtin:pebble"


@dataclass
class Stopwatch:
    seconds: float = 0.0

    def timed(self, call, *args):
        t0 = time.perf_counter()
        try:
            return call(*args)
        finally:
            self.seconds += time.perf_counter() - t0


@dataclass
class TimedPositioner:
    """A Positioner whose waits for arrival are clocked."""

    inner: Positioner
    waiting: Stopwatch

    def move_to(self, goal: tuple[int, ...]) -> None:
        self.inner.move_to(goal)

    def wait_settled(self, timeout_s: float) -> tuple[int, ...]:
        return self.waiting.timed(self.inner.wait_settled, timeout_s)

    def position(self) -> tuple[int, ...]:
        return self.inner.position()

    def stop(self) -> None:
        self.inner.stop()


@dataclass
class TimedCamera:
    """A Camera whose captures (exposure, readout, transfer) are clocked, and their exposures summed."""

    inner: Camera
    capturing: Stopwatch
    exposed_s: float = 0.0

    def set_exposure(self, seconds: float) -> None:
        self.inner.set_exposure(seconds)

    def set_gain(self, gain_db: float) -> None:
        self.inner.set_gain(gain_db)

    def capture(self) -> RawFrame:
        frame = self.capturing.timed(self.inner.capture)
        self.exposed_s += frame.exposure_s
        return frame

    def close(self) -> None:
        self.inner.close()

    def statistics(self) -> dict[str, int]:
        return self.inner.statistics() if isinstance(self.inner, StreamCounters) else {}


@dataclass
class PoseFigures:
    wall_s: float
    moving_s: float  # waiting for arrival and settling
    capture_s: float
    servo_transactions: int
    modbus_transactions: int

    @property
    def overhead_s(self) -> float:
        return self.wall_s - self.moving_s - self.capture_s


@dataclass
class AcquireFigures:
    poses: list[PoseFigures] = field(default_factory=list)
    frames: int = 0
    total_s: float = 0.0
    drain_s: float = 0.0  # after the last pose: storing the frames still queued
    peak_rss_mb: float = 0.0
    packet_loss: float = 0.0  # the simulated camera's stream packets lost on their first sending
    camera_stream: dict[str, int] = field(default_factory=dict)  # its counters over the run (Aravis's)
    retries: int = 0  # device exchanges retried (a frame incomplete beyond its resends among them)

    def median(self, attribute: str) -> float:
        return statistics.median(getattr(p, attribute) for p in self.poses)


def builtin_plan(rig: Rig) -> PlanFile:
    """builtin:pebble planned on ``rig`` with the default settings, as ``hlr-lab plan`` would."""
    mesh = builtin_object(BENCH_OBJECT).mesh
    plan, _ = plan_object(
        mesh, segment(mesh), rig, PlanSettings(), mesh_spec=BENCH_OBJECT, plan_folder=Path.cwd()
    )
    return plan


def repeated_poses(plan: PlanFile, n: int) -> PlanFile:
    """``n`` poses cycling through the plan's own (so each one moves the rig), with unique ids."""
    poses = [plan.poses[i % len(plan.poses)].model_copy(update={"id": f"b{i:03d}"}) for i in range(n)]
    return plan.model_copy(update={"poses": poses})


def acquire_figures(
    *, poses: int, speed_factor: float, keep: Path | None = None, packet_loss: float = 0.0
) -> AcquireFigures:
    """Acquire ``poses`` poses of builtin:pebble's plan (cycled) on the simulated rig into a scratch
    session, or into ``keep``/session (a whole session: its plan.json beside it, for ``fit``), the
    simulated GigE Vision camera losing ``packet_loss`` of its stream packets on their first sending."""
    rig = sim_rig()
    plan = repeated_poses(builtin_plan(rig), poses)
    targets = motion_targets(plan, rig)
    waiting, capturing = Stopwatch(), Stopwatch()
    figures = AcquireFigures(packet_loss=packet_loss)
    scene = sim_scene(plan, Path.cwd(), None)  # a built-in object: no file is read
    with (
        SimRig(scene=scene, speed_factor=speed_factor, **world_geometry(rig)) as world,
        tempfile.TemporaryDirectory(prefix="hlr-bench-acquire-") as scratch,
    ):
        session = Path(scratch) if keep is None else keep / "session"
        if keep is not None:
            plan_path = keep / "plan.json"
            write_plan(plan_path, plan)
            start_or_resume(session, plan_path, file_sha256(plan_path), rig, force=False)
        assert world.gige is not None  # the simulated rig's camera is a GigE Vision device
        world.gige.faults.drop_ratio = packet_loss
        with open_rig(rig, world_links(world)) as opened:
            marks = [_mark(world, waiting, capturing)]

            def on_step(step: Step) -> None:
                if step.action == "done":
                    marks.append(_mark(world, waiting, capturing))

            i = opened.instruments
            started = time.perf_counter()
            outcome = acquire(
                plan,
                targets,
                Instruments(
                    TimedPositioner(i.turntable, waiting),
                    TimedPositioner(i.gantry, waiting),
                    TimedCamera(i.camera, capturing),
                    i.lamp,
                    i.thermometers,
                ),
                session,
                progress=on_step,
            )
            figures.total_s = time.perf_counter() - started
    figures.frames, figures.retries = outcome.taken, outcome.retries
    figures.camera_stream = outcome.camera_stream or {}
    figures.drain_s = figures.total_s - (marks[-1][0] - started)
    figures.poses = [
        PoseFigures(*(b - a for a, b in zip(m0, m1, strict=True))) for m0, m1 in itertools.pairwise(marks)
    ]
    figures.peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    return figures


def _mark(world: SimRig, waiting: Stopwatch, capturing: Stopwatch) -> tuple:
    """Cumulative clocks and counters at a pose boundary (consecutive differences make a PoseFigures)."""
    return (
        time.perf_counter(),
        waiting.seconds,
        capturing.seconds,
        world.bus.instructions,
        world.turntable.requests,
    )


def report(f: AcquireFigures, speed_factor: float) -> list[str]:
    """What ``hlr-lab bench acquire`` prints."""
    overhead = sorted(1e3 * p.overhead_s for p in f.poses)
    p90 = overhead[min(len(overhead) - 1, int(0.9 * len(overhead)))]
    return [
        f"{len(f.poses)} poses, {f.frames} frames (1280×960×3, 16-bit) in {f.total_s:.1f} s, motion ×{speed_factor:g}",
        f"software overhead per pose (target ≤ 20 ms median): median {f.median('overhead_s') * 1e3:.1f} ms, "
        f"p90 {p90:.1f} ms, max {overhead[-1]:.1f} ms",
        f"  per pose, median: wall {f.median('wall_s') * 1e3:.0f} ms = waiting for the axes "
        f"{f.median('moving_s') * 1e3:.0f} ms + camera {f.median('capture_s') * 1e3:.0f} ms + overhead",
        f"transactions per pose, median: servo {f.median('servo_transactions'):.0f}, "
        f"Modbus {f.median('modbus_transactions'):.0f}",
        f"storing the frames still queued after the last pose: {f.drain_s * 1e3:.0f} ms",
        f"camera packets over the run (GigE Vision, {f.packet_loss:.0%} lost on first sending): received / "
        f"resent / missing {stream_line(f.camera_stream)}; device retries {f.retries}",
        f"peak RSS {f.peak_rss_mb:.0f} MB",
    ]


def session_fit_figures(
    poses: int, progress: Callable[[str], None] = lambda _: None
) -> tuple[SessionFitFigures, int]:
    """``hlr-lab bench session-fit``: acquire ``poses`` poses (as :func:`acquire_figures`, at a speed
    factor of 1000) into a scratch session, fit it in a fresh process; the fit's figures and the frames."""
    with tempfile.TemporaryDirectory(prefix="hlr-bench-fit-") as scratch:
        progress(f"acquiring {poses} poses on the simulated rig…")
        acquired = acquire_figures(poses=poses, speed_factor=1000.0, keep=Path(scratch))
        progress("fitting (fresh process)…")
        return run_session_fit_case(Path(scratch) / "session"), acquired.frames
