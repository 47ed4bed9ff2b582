"""``hlr-lab bench soak``: a long acquisition under abuse, as a night on a bad bench would be.

The simulated rig runs in this process; ``hlr-lab acquire --rig`` runs as a child process against its
endpoints, exactly as against a real rig. While it runs, a fault thread injects faults of every kind
the simulator has: dropped and corrupted servo replies, unanswered and disconnected Modbus exchanges,
frames cut short, an axis knocked off during an exposure (each of these is retried or retaken and the
run goes on), Modbus device failures and servo overloads (these stop the run; the overload is cleared
as an operator would, by rebooting the servo). At random moments the child is killed with SIGKILL. After
every end the same command is run again, until the plan is complete.

Then the session is checked: every planned frame journaled exactly once and intact, no goal outside
the rig's limits ever reached the simulated devices, and the memory and descriptors of the longest
child and of this process did not grow.

Composition root code (it builds the simulator), hence under ``hlr_lab.cli``.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.acquire import builtin_plan, repeated_poses
from hlr_lab.errors import HlrLabError
from hlr_lab.formats.plan import write_plan
from hlr_lab.rig.file import Rig, sim_rig
from hlr_lab.session.frames import frame_problem
from hlr_lab.session.journal import JOURNAL, read_journal
from sim.dynamixel.servo import OVERLOAD
from sim.rig import SimRig
from worlds.plan_world import rig_file_text, sim_scene, world_geometry

# fault → relative frequency; the last two stop the run
FAULTS = {
    "servo reply dropped": 5,
    "servo reply corrupted": 5,
    "Modbus reply dropped": 5,
    "Modbus link dropped": 3,
    "camera frame lost beyond its resends": 3,
    "axis knocked off during an exposure": 2,
    "Modbus device failure": 0.2,  # rarer: each ends a run, and long runs are what show a leak
    "servo overload": 0.1,
}


@dataclass
class Sample:
    """One reading of a process: seconds since it started, resident memory (MB), open descriptors."""

    t: float
    rss_mb: float
    fds: int


@dataclass
class SoakFigures:
    poses: int
    frames_planned: int
    frames_journaled: int
    duplicates: int
    damaged: int
    goals_outside: int
    faults: Counter = field(default_factory=Counter)
    ends: Counter = field(default_factory=Counter)  # how each child ended: complete, killed, stopped
    retries_journaled: int = 0
    seconds: float = 0.0
    longest_child: list[Sample] = field(default_factory=list)
    world: list[Sample] = field(default_factory=list)


def soak(*, poses: int, kills: int, fault_interval_s: float, speed_factor: float, seed: int) -> SoakFigures:
    """Run the soak (see the module's docstring) in a scratch directory; returns its figures."""
    rng = random.Random(seed)
    rig = sim_rig()
    with tempfile.TemporaryDirectory(prefix="hlr-soak-") as scratch:
        plan = repeated_poses(builtin_plan(rig), poses)
        plan_path = Path(scratch) / "plan.json"
        write_plan(plan_path, plan)
        scene = sim_scene(plan, plan_path, None)
        started = time.monotonic()
        with SimRig(scene=scene, speed_factor=speed_factor, spp=1, **world_geometry(rig)) as world:
            e = world.endpoints
            rig_path = Path(scratch) / "rig.toml"
            rig_path.write_text(rig_file_text(e.dynamixel, e.modbus, e.camera))
            session = Path(scratch) / "session"
            command = [sys.executable, "-m", "hlr_lab.cli.main", "acquire", "--plan", str(plan_path),
                       "--rig", str(rig_path), "--out", str(session)]  # fmt: skip
            frames_planned = sum(len(p.exposures_s) for p in plan.poses)
            kill_at = sorted(rng.sample(range(3, frames_planned - 3), kills))
            figures = SoakFigures(poses, frames_planned, 0, 0, 0, 0)
            figures.world.append(_sample(os.getpid(), started))
            while True:
                world.bus.servo(1).reboot() if world.bus.servo(1).get("hardware_error_status") else None
                world.bus.servo(2).reboot() if world.bus.servo(2).get("hardware_error_status") else None
                end, samples = _run_child(command, session, world, rng, kill_at, fault_interval_s, figures)
                figures.ends[end] += 1
                if len(samples) > len(figures.longest_child):
                    figures.longest_child = samples
                figures.world.append(_sample(os.getpid(), started))
                if end == "complete":
                    break
                if sum(figures.ends.values()) > kills + 20 * poses:
                    raise HlrLabError(f"soak: the runs do not complete the plan: {dict(figures.ends)}")
            figures.seconds = time.monotonic() - started
            _check(figures, session, plan, rig, world)
    return figures


# glibc serves a frame-sized block (7.4 MB) from its heaps once one has been freed (its mmap threshold
# rises to the largest block freed), and each thread's heap then keeps what it once held: the child's
# memory climbs in steps to a plateau (158 → 235 MB over a 20-pose run, reached anywhere from 30 to 70 %
# of it), which a leak check between two moments of the run reads as a leak or not by chance. With a
# fixed threshold every frame-sized block is mapped and returned on its own, so the child's memory is
# what it holds.
CHILD_ENV = os.environ | {"MALLOC_MMAP_THRESHOLD_": str(1 << 20)}


def _run_child(command, session, world, rng, kill_at, interval_s, figures) -> tuple[str, list[Sample]]:
    """One ``hlr-lab acquire`` until it ends (complete, stopped by a fault) or is killed; faults are
    injected meanwhile. Returns how it ended and the samples of its memory and descriptors."""
    # stderr to a file: a pipe read only at the end fills up (the motion table alone is large) and blocks
    with tempfile.TemporaryFile("w+") as err_file:
        child = subprocess.Popen(
            command, stdout=subprocess.DEVNULL, stderr=err_file, text=True, env=CHILD_ENV
        )
        started, samples, stop = time.monotonic(), [], threading.Event()
        injector = threading.Thread(
            target=_inject, args=(world, rng, interval_s, figures.faults, stop), daemon=True
        )
        injector.start()
        killed = False
        try:
            while child.poll() is None:
                with contextlib.suppress(OSError):  # it may end between the poll and the reading
                    samples.append(_sample(child.pid, started))
                frames = sum(e["event"] == "frame" for e in read_journal(session / JOURNAL))
                if kill_at and frames >= kill_at[0]:
                    kill_at.pop(0)
                    child.send_signal(signal.SIGKILL)
                    killed = True
                    break
                time.sleep(0.25)
            status = child.wait(timeout=300)
        finally:
            stop.set()
            injector.join()
            if child.poll() is None:
                child.kill()
                child.wait()
        err_file.seek(0)
        err = err_file.read()
    if killed:
        return "killed", samples
    last = err.strip().splitlines()[-1] if err.strip() else "(nothing on stderr)"
    unsafe = _unsafe(world)
    if unsafe:  # what the devices themselves say, whatever the run said
        raise HlrLabError(f"soak: after acquire ended ({status}: {last}) the rig is not safe: {unsafe}")
    if status == 0:
        return "complete", samples
    if status != 1 or "the rig is safe" not in last:
        raise HlrLabError(f"soak: acquire ended with status {status} and the rig not confirmed safe: {last}")
    return "stopped by a fault", samples


def _unsafe(world: SimRig) -> str:
    """What of the simulated rig is not in the safe state (lamp off, torque off, turntable still)."""
    found = ["the lamp is on"] if world.turntable.stage.lamp else []
    found += [f"servo {s.id} has torque on" for s in world.bus.servos if s.get("torque_enable")]
    found += ["the turntable moves"] if world.turntable.stage.moving() else []
    return ", ".join(found)


def _inject(world: SimRig, rng: random.Random, interval_s: float, counts: Counter, stop: threading.Event):
    """Inject a fault every ``interval_s`` (± 50 %) until ``stop``. A one-shot fault (the next reply
    dropped, corrupted, refused) is armed only when none of its kind is pending: a queue of them would
    grow while that link is idle (a long exposure) and then fall on one exchange as a burst longer than
    any bounded retry, which is a test of the queue, not of the driver."""
    names, weights = list(FAULTS), list(FAULTS.values())
    assert world.gige is not None  # the soak's world photographs: it has a camera
    while not stop.wait(rng.uniform(0.5, 1.5) * interval_s):
        fault = rng.choices(names, weights)[0]
        servo = rng.choice(world.endpoints.servo_ids)
        one_shot = {
            "servo reply dropped": (world.bus.fault(servo), "drop_replies"),
            "servo reply corrupted": (world.bus.fault(servo), "corrupt_replies"),
            "Modbus reply dropped": (world.turntable.faults, "no_reply"),
            "Modbus device failure": (world.turntable.faults, "exception"),
            "camera frame lost beyond its resends": (world.gige.faults, "drop_for_good"),
        }
        if fault in one_shot:
            faults, name = one_shot[fault]
            if getattr(faults, name):
                continue  # one of its kind is still pending
            setattr(faults, name, 1)
        elif fault == "Modbus link dropped":
            world.turntable.disconnect_clients()
        elif fault == "axis knocked off during an exposure":
            world.bus.servo(servo).slip(rng.choice((-40, 40)), hold_s=0.1 * world.bus.speed_factor)
        elif fault == "servo overload":
            world.bus.servo(servo).hardware_fault(OVERLOAD)
        counts[fault] += 1


def _check(figures: SoakFigures, session: Path, plan, rig: Rig, world: SimRig) -> None:
    events = read_journal(session / JOURNAL)
    frames = [e for e in events if e["event"] == "frame" and not e["dark"]]
    keys = Counter((e["pose"], e["exposure_index"]) for e in frames)
    planned = {(p.id, k) for p in plan.poses for k in range(len(p.exposures_s))}
    figures.frames_journaled = sum(keys[k] > 0 for k in planned)
    figures.duplicates = sum(n - 1 for n in keys.values() if n > 1)
    figures.damaged = sum(frame_problem(session, e) is not None for e in frames)
    figures.retries_journaled = sum(e["event"] == "retry" for e in events)
    limits = dict(zip(rig.gantry.servo_ids, rig.gantry.servo_limits, strict=True))
    steps = sorted(rig.turntable_kinematics.steps_for(d) for d in rig.turntable_limits_deg)
    figures.goals_outside = sum(
        not limits[g.servo_id][0] <= g.goal <= limits[g.servo_id][1] for g in world.bus.goals
    )
    figures.goals_outside += sum(not steps[0] <= m <= steps[1] for m in world.turntable.stage.moves)


def leak_window(samples: list[Sample]) -> tuple[Sample, Sample]:
    """Two readings of a run to compare for a leak: its floor (the fewest descriptors, the least memory)
    over the tenth of its life from 40 % (well past start-up: imports, connecting, the first frames, which
    took a fifth of a run on a loaded machine) and over the tenth from 80 % (before it closes its files on
    the way out). A floor, not one reading: at any instant a run may hold a frame's temporary file or a
    reconnecting link open (one reading 3 descriptors above another without a leak, on a loaded machine),
    while a leak raises the floor itself: one descriptor or one frame (7.4 MB) a pose shows as 8 over a
    20-pose run's 40 %."""

    def floor(start: float) -> Sample:
        n = len(samples)
        window = samples[int(start * n) : max(int((start + 0.1) * n), int(start * n) + 1)]
        return Sample(window[0].t, min(s.rss_mb for s in window), min(s.fds for s in window))

    return floor(0.4), floor(0.8)


def _sample(pid: int, since: float) -> Sample:
    """Raises OSError when the process has gone (a zombie has no memory left to report)."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss_kb = [int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")]
    if not rss_kb:
        raise ProcessLookupError(pid)
    return Sample(time.monotonic() - since, rss_kb[0] / 1024, len(os.listdir(f"/proc/{pid}/fd")))


def passed(f: SoakFigures) -> bool:
    """Every planned frame journaled once and intact, and no goal outside the limits reached a device."""
    return f.frames_journaled == f.frames_planned and not (f.duplicates or f.damaged or f.goals_outside)


def report(f: SoakFigures, speed_factor: float) -> list[str]:
    """What ``hlr-lab bench soak`` prints, its verdict last."""
    child, world = f.longest_child, f.world
    warm, late = leak_window(child)
    return [
        f"{f.poses} poses, {f.frames_planned} planned frames, {f.seconds:.0f} s, motion ×{speed_factor:g}",
        f"faults injected: {sum(f.faults.values())} ({', '.join(f'{k} {v}' for k, v in f.faults.most_common())})",
        f"runs: {sum(f.ends.values())} ({', '.join(f'{k} {v}' for k, v in f.ends.most_common())}); "
        f"retries journaled {f.retries_journaled}",
        f"planned frames journaled {f.frames_journaled} of {f.frames_planned}, taken twice {f.duplicates}, "
        f"failing their checksums {f.damaged}; goals outside the limits that reached the devices {f.goals_outside}",
        f"longest run ({child[-1].t:.0f} s): RSS {warm.rss_mb:.0f} → {late.rss_mb:.0f} MB, "
        f"descriptors {warm.fds} → {late.fds} (floors over a tenth of the run from {warm.t:.0f} s and {late.t:.0f} s)",
        f"this process (the simulated rig): RSS {world[1].rss_mb:.0f} → {world[-1].rss_mb:.0f} MB, "
        f"descriptors {world[1].fds} → {world[-1].fds} (after the first run to the end)",
        "soak: PASS" if passed(f) else "soak: FAIL",
    ]
