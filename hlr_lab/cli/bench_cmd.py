"""``hlr-lab bench``: benchmarks that print figures."""

from __future__ import annotations

import contextlib
from pathlib import Path

import click
import numpy as np

from benchmarks.numerical import (
    FIT_PIXELS,
    PAPER_SETTINGS,
    fit_error_grid,
    mesh_label,
    nearest_neighbour_spacing_deg,
    run_plan_case,
    run_throughput_case,
)
from hlr_lab.cli.common import Finite, speed_factor_option
from hlr_lab.cli.console import console, out
from hlr_lab.fitting import ESTIMATORS
from hlr_lab.geometry.sphere import directions_with_spacing


@click.group()
def bench() -> None:
    """Benchmarks that print figures (targets in the README)."""


@bench.command("plan")
@click.option(
    "--mesh",
    "mesh_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Mesh to plan on (default: the built-in pebble). The paper's: the Stanford bunny.",
)
@click.option("--up", default="z", show_default=True, help="Mesh axis that points up (y for the bunny).")
@click.option(
    "--scale", type=Finite(min=0, min_open=True), default=1.0, show_default=True, help="Mesh units → metres."
)
@click.option(
    "--large",
    "min_vertices",
    type=click.IntRange(min=0),
    default=1_000_000,
    show_default=True,
    help="Also plan on the mesh subdivided to at least this many vertices (0: skip).",
)
def bench_plan(mesh_path, up, scale, min_vertices) -> None:
    """Planning time and peak memory: the paper's 4.1 set-up (8 regions in view, sphere 2× the bounding
    sphere, θc = 5°, one view, candidate spacing 0.5°) on the mesh and on a ≥ 1 M-vertex subdivision.

    \b
    Example:
      hlr-lab bench plan --mesh ../shared/assets/stanford-bunny.obj --up y
    """
    spacing = nearest_neighbour_spacing_deg(directions_with_spacing(PAPER_SETTINGS.spacing_deg))
    console.print(
        f"candidate spacing: requested {PAPER_SETTINGS.spacing_deg}°, measured max nearest-neighbour "
        f"{spacing:.3f}°"
    )
    name = mesh_label(str(mesh_path) if mesh_path else None)
    cases = [(name, None if mesh_path is None else str(mesh_path), up, scale, 0)]
    if min_vertices:
        cases.append(
            (f"{name} subdivided", None if mesh_path is None else str(mesh_path), up, scale, min_vertices)
        )
    out.print("plan benchmark: one fresh process per case; mesh loading and segmentation excluded")
    for case in cases:
        with console.status(f"planning {case[0]}…"):
            f = run_plan_case(*case)
        stages = ", ".join(f"{k} {v:.2f}" for k, v in f.stages.items())
        out.print(f"{f.case}: {f.vertices:,} vertices, {f.regions} regions", soft_wrap=True, markup=False)
        out.print(
            f"  lights {f.lights} (plain count {f.lights_plain}), uncovered regions {f.uncovered}",
            soft_wrap=True,
            markup=False,
        )
        out.print(f"  plan time {f.plan_s:.2f} s  [{stages}]", soft_wrap=True, markup=False)
        out.print(
            f"  memory: RSS {f.rss_before_mb:.0f} MB before planning, peak RSS {f.rss_peak_plan_mb:.0f} MB "
            "while planning",
            soft_wrap=True,
            markup=False,
        )


@bench.command("fit")
@click.option(
    "--sizes",
    default="1000000,3000000,10000000",
    show_default=True,
    help="Sample counts for the throughput and memory figures (comma-separated).",
)
@click.option("--no-grid", is_flag=True, help="Skip the error grid (only throughput and memory).")
def bench_fit(sizes, no_grid) -> None:
    """Estimator errors over noise levels and exponents, time per fit, throughput and memory.

    \b
    Example:
      hlr-lab bench fit
      hlr-lab bench fit --no-grid --sizes 10000000
    """
    if not no_grid:
        out.print(
            f"error grid: paper 4.2 set-up (cylinder, directional light, 8-bit, Rd, Rs of the paper), "
            f"{FIT_PIXELS:,} pixels, θc auto; max relative error over RGB",
            markup=False,
        )
        out.print(
            f"{'σ DN':>5} {'n':>5}  {'method':7} {'Rd err':>8} {'Rs err':>8} {'n err':>8} {'θc°':>6} {'time s':>7}",
            markup=False,
        )
        with console.status("fitting the grid…"):
            rows = fit_error_grid()
        for r in rows:
            if r.failure:
                out.print(f"{r.noise_dn:5.1f} {r.n:5.0f}  {r.method:7} failed: {r.failure}", markup=False)
                continue
            out.print(
                f"{r.noise_dn:5.1f} {r.n:5.0f}  {r.method:7} {100 * r.rd_err:7.2f}% {100 * r.rs_err:7.2f}% "
                f"{100 * r.n_err:7.2f}% {r.theta_c_deg:6.1f} {r.seconds:7.3f}",
                markup=False,
            )
        for method in ESTIMATORS:
            mine = [r for r in rows if r.method == method and not r.failure]
            if mine:
                out.print(
                    f"{method}: median errors Rd {100 * np.median([r.rd_err for r in mine]):.2f}%, "
                    f"Rs {100 * np.median([r.rs_err for r in mine]):.2f}%, "
                    f"n {100 * np.median([r.n_err for r in mine]):.2f}%; "
                    f"worst Rd {100 * max(r.rd_err for r in mine):.2f}%, Rs {100 * max(r.rs_err for r in mine):.2f}%, "
                    f"n {100 * max(r.n_err for r in mine):.2f}%; "
                    f"{sum(1 for r in rows if r.method == method and r.failure)} failed; "
                    f"median time per fit {np.median([r.seconds for r in mine]) * 1000:.0f} ms",
                    markup=False,
                )
    out.print(
        "throughput and memory (robust, θc 20°, one region, sphere, point light, photon + read noise; "
        "fresh process per size)",
        markup=False,
    )
    for n in (int(x) for x in sizes.split(",") if x.strip()):
        with console.status(f"fitting {n:,} samples…"):
            t = run_throughput_case(n)
        out.print(
            f"{n:>12,} samples: {t.seconds:6.2f} s, {t.per_second / 1e6:5.2f} M samples/s, inputs "
            f"{t.inputs_bytes / n:.0f} B/sample + working {t.peak_extra_bytes / n:.0f} B/sample = "
            f"{t.bytes_per_sample:.0f} B/sample",
            markup=False,
        )


@bench.command("sim")
@click.option("-n", "transactions", type=click.IntRange(10, 100_000), default=1000, show_default=True)
@click.option(
    "--frames",
    type=click.IntRange(0, 100_000),
    default=1000,
    show_default=True,
    help="Re-renders for the memory figure (0: skip the renderer).",
)
def bench_sim(transactions, frames) -> None:
    """The simulated rig: round trips to the Dynamixel bus (real dynamixel-sdk over its pseudo-terminal)
    and the Modbus stage (pymodbus over TCP and RTU); render time per frame and memory over re-renders.

    \b
    Example:
      hlr-lab bench sim -n 2000
    """
    from benchmarks.sim import (  # the simulator: CLI only
        modbus_round_trips,
        render_figures,
        servo_round_trips,
    )

    with console.status("timing servo transactions…"):
        servo = servo_round_trips(transactions)
    with console.status("timing Modbus transactions…"):
        modbus = modbus_round_trips(transactions)
    sections = (
        (f"servo transactions over a pty, dynamixel-sdk, {transactions} each (target ≤ 1 ms):", servo),
        (f"Modbus transactions, pymodbus, {transactions} each (target ≤ 3 ms):", modbus),
    )
    for title, figures in sections:
        out.print(title, markup=False)
        for name, f in figures.items():
            out.print(f"  {name:30s} median {f['median_ms']:.3f} ms, p95 {f['p95_ms']:.3f} ms", markup=False)
    if frames:
        with console.status(f"rendering (then {frames} re-renders)…"):
            render = render_figures(frames)
        out.print(
            "renderer (Mitsuba llvm_ad_rgb, direct integrator; target ≤ 0.3 s per 1280×960 frame, flat memory):",
            markup=False,
        )
        for name, value in render.items():
            out.print(f"  {name:40s} {value:8.3f}", markup=False)


@bench.command("acquire")
@click.option("--poses", type=click.IntRange(2, 10_000), default=20, show_default=True)
@speed_factor_option("Simulated", default=1000.0)  # fast: waiting for motion must hide nothing
def bench_acquire(poses, speed_factor) -> None:
    """Acquisition on the simulated rig with the real drivers: software overhead per pose (wall time not
    spent waiting for the axes or the camera) and servo / Modbus transactions per pose.

    The plan is builtin:pebble's, its poses cycled to the count asked for; frames are 1280×960, 16-bit,
    stored in a scratch directory that is removed afterwards.

    \b
    Example:
      hlr-lab bench acquire --poses 50
    """
    from benchmarks.acquire import acquire_figures  # builds the simulated rig: CLI only

    with console.status(f"acquiring {poses} poses on the simulated rig…"):
        f = acquire_figures(poses=poses, speed_factor=speed_factor)
    overhead = sorted(1e3 * p.overhead_s for p in f.poses)
    p90 = overhead[min(len(overhead) - 1, int(0.9 * len(overhead)))]
    lines = [
        f"{len(f.poses)} poses, {f.frames} frames (1280×960×3, 16-bit) in {f.total_s:.1f} s, motion ×{speed_factor:g}",
        f"software overhead per pose (target ≤ 20 ms median): median {f.median('overhead_s') * 1e3:.1f} ms, "
        f"p90 {p90:.1f} ms, max {overhead[-1]:.1f} ms",
        f"  per pose, median: wall {f.median('wall_s') * 1e3:.0f} ms = waiting for the axes "
        f"{f.median('moving_s') * 1e3:.0f} ms + camera {f.median('capture_s') * 1e3:.0f} ms + overhead",
        f"transactions per pose, median: servo {f.median('servo_transactions'):.0f}, "
        f"Modbus {f.median('modbus_transactions'):.0f}",
        f"storing the frames still queued after the last pose: {f.drain_s * 1e3:.0f} ms",
        f"peak RSS {f.peak_rss_mb:.0f} MB",
    ]
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)


@bench.command("session-fit")
@click.option("--poses", type=click.IntRange(2, 1000), default=20, show_default=True)
def bench_session_fit(poses) -> None:
    """End-to-end ``hlr-lab fit`` on a simulated session: total time, time per stage (HDR, G-buffer,
    selection, shadows, fitting) and peak memory, the fit in a fresh process.

    The session is builtin:pebble's plan, its poses cycled to the count asked for, acquired on the
    simulated rig at 1280×960 with 3-frame brackets into a scratch directory removed afterwards.
    Targets (2 cores, 20 poses): ≤ 30 s and ≤ 1.5 GB peak.

    \b
    Example:
      hlr-lab bench session-fit --poses 20
    """
    import tempfile

    from benchmarks.acquire import acquire_figures  # builds the simulated rig: CLI only
    from benchmarks.numerical import run_session_fit_case

    with tempfile.TemporaryDirectory(prefix="hlr-bench-fit-") as scratch:
        with console.status(f"acquiring {poses} poses on the simulated rig…"):
            acquired = acquire_figures(poses=poses, speed_factor=1000.0, keep=Path(scratch))
        with console.status("fitting (fresh process)…"):
            f = run_session_fit_case(Path(scratch) / "session")
    stages = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in f.stages.items())
    for line in (
        f"session: {f.views} poses, {acquired.frames} frames of {f.pixels_per_frame:,} pixels",
        f"fit (target ≤ 30 s, ≤ 1.5 GB): {f.seconds:.1f} s, peak RSS {f.peak_rss_mb:.0f} MB; "
        f"{f.regions_measured} regions measured",
        f"  per stage: {stages}",
    ):
        out.print(line, markup=False, soft_wrap=True)


@bench.command("soak")
@click.option("--poses", type=click.IntRange(20, 100_000), default=500, show_default=True)
@click.option(
    "--kills", type=click.IntRange(0, 1000), default=10, show_default=True, help="SIGKILLs at random moments."
)
@click.option(
    "--fault-every",
    "fault_interval_s",
    type=Finite(min=0.05),
    default=0.6,
    show_default=True,
    help="Mean seconds between injected faults.",
)
@click.option("--seed", type=int, default=0, show_default=True)
@speed_factor_option("Simulated", default=1000.0)
def bench_soak(poses, kills, fault_interval_s, seed, speed_factor) -> None:
    """A night under abuse: acquire POSES poses (builtin:pebble's plan cycled; hlr-lab acquire in a child
    process against the simulated rig) while faults of every kind are injected and the child is killed
    with SIGKILL at random moments, resuming after every end until the plan is complete; then check every
    planned frame once and intact, no goal outside the limits, flat memory and descriptors.

    \b
    Example:
      hlr-lab bench soak --poses 500 --kills 10
    """
    from benchmarks.soak import leak_window, soak  # builds the simulated rig: CLI only

    with console.status(f"soaking {poses} poses on the simulated rig…"):
        f = soak(
            poses=poses, kills=kills, fault_interval_s=fault_interval_s, speed_factor=speed_factor, seed=seed
        )
    child, world = f.longest_child, f.world
    warm, late = leak_window(child)
    lines = [
        f"{f.poses} poses, {f.frames_planned} planned frames, {f.seconds:.0f} s, motion ×{speed_factor:g}",
        f"faults injected: {sum(f.faults.values())} ({', '.join(f'{k} {v}' for k, v in f.faults.most_common())})",
        f"runs: {sum(f.ends.values())} ({', '.join(f'{k} {v}' for k, v in f.ends.most_common())}); "
        f"retries journaled {f.retries_journaled}",
        f"planned frames journaled {f.frames_journaled} of {f.frames_planned}, taken twice {f.duplicates}, "
        f"failing their checksums {f.damaged}; goals outside the limits that reached the devices {f.goals_outside}",
        f"longest run ({child[-1].t:.0f} s): RSS {warm.rss_mb:.0f} → {late.rss_mb:.0f} MB, "
        f"descriptors {warm.fds} → {late.fds} (at {warm.t:.0f} s and {late.t:.0f} s)",
        f"this process (the simulated rig): RSS {world[1].rss_mb:.0f} → {world[-1].rss_mb:.0f} MB, "
        f"descriptors {world[1].fds} → {world[-1].fds} (after the first run to the end)",
    ]
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)
    ok = f.frames_journaled == f.frames_planned and not (f.duplicates or f.damaged or f.goals_outside)
    out.print("soak: PASS" if ok else "soak: FAIL", markup=False)
    if not ok:
        raise SystemExit(1)


@bench.command("calibration")
@click.option(
    "--true-rig",
    "true_rig",
    default="builtin:bench-night",
    show_default=True,
    metavar="FILE|builtin:NAME",
    help="The simulated world's rig as it really is (hlr-lab starts from the drawing, the built-in rig).",
)
@click.option(
    "--views", type=click.IntRange(16, 200), default=24, show_default=True, help="Board photographs."
)
@click.option("--poses", type=click.IntRange(12, 200), default=30, show_default=True, help="Lamp poses.")
@click.option("--run-poses", type=click.IntRange(1, 1000), default=40, show_default=True,
              help="Poses of the end-to-end runs (builtin:pebble's plan cycled).")  # fmt: skip
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Keep the photographs, rig files and sessions here (a new folder; default: a scratch folder).",
)
@speed_factor_option("Simulated", default=40.0)
def bench_calibration(true_rig, views, poses, run_poses, out_dir, speed_factor) -> None:
    """What calibration is worth: calibrate the simulated bench built as --true-rig while hlr-lab believes
    the drawing (camera, gantry, radiometry with a warm-up), compare the calibrated rig file with the true
    one, and measure builtin:pebble end to end (plan → acquire → fit) with the drawing and with the
    calibrated file (its lamp warmed up and watched). Prints the simulated-rig time of each procedure
    (motion, exposures and warm-up at real speed; rendering is not rig time). Targets in the README.

    \b
    Examples:
      hlr-lab bench calibration
      hlr-lab bench calibration --true-rig builtin:bench-offsets --run-poses 2 --out bench-cal
    """
    import tempfile

    from benchmarks.calibration import calibration_figures  # builds the simulated rig: CLI only
    from hlr_lab.errors import InputError

    with contextlib.ExitStack() as stack:
        if out_dir is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="hlr-bench-calibration-")))
        elif out_dir.exists() and any(out_dir.iterdir()):
            raise InputError("the folder is not empty; give a new --out", path=out_dir, field="--out")
        else:
            folder = out_dir
        with console.status("calibrating…") as status:
            f = calibration_figures(folder, true_rig=true_rig, views=views, poses=poses, run_poses=run_poses,
                                    speed_factor=speed_factor, progress=status.update)  # fmt: skip
    r, q = f.recovery, f.radiometric
    assert r is not None  # calibration_figures measures both before it returns
    assert q is not None
    rig_times = ", ".join(f"{name} {seconds:.0f} s" for name, seconds in f.rig_s.items())
    walls = " + ".join(f"{seconds:.0f} s" for seconds in f.wall_s.values())
    lines = [
        f"world: {true_rig}; hlr-lab starts from the drawing (the built-in simulated rig)",
        f"simulated-rig time: {rig_times} (target ≤ 5 min for camera and gantry; {views} views, {poses} lamp "
        f"poses × 2 ball places, the radiometry's warm-up included); wall here at ×{speed_factor:g} "
        f"(photographing and solving): {walls}",
        "recovery against the true rig (target):",
        f"  focal length {r.focal_pct:.3f} % (0.2 %), principal point {r.principal_point_px:.2f} px (1 px), "
        f"reprojection RMS {r.rms_px:.3f} px (0.3 px)",
        f"  camera position {r.camera_position_mm:.2f} mm (1 mm), viewing direction {r.view_direction_deg:.3f}° "
        f"(0.05°), roll {r.roll_deg:.3f}° (0.05°), turntable zero {r.turntable_zero_steps:+d} steps",
        f"  gantry zero ticks {r.gantry_zero_ticks} (2), arm radius {r.arm_radius_mm:.2f} mm (1 mm), "
        f"azimuth axis {r.azimuth_axis_deg:.3f}° (0.1°), lamp worst {r.lamp_worst_mm:.2f} mm (2 mm)",
        f"  black level {q.black_level_dn:.2f} DN (0.5 DN), read noise {100 * q.read_noise:.2f} % (5 %), "
        f"conversion gain {100 * q.conversion_gain:.2f} % (3 %), sensitivity × power "
        f"{100 * q.sensitivity_times_power:.2f} % (1 %; the lamp then {100 * q.lamp_short_of_warm:.2f} % short "
        "of its warm power: what the warm-up leaves)",
        f"end to end, builtin:pebble, {run_poses} poses, error per region in % (targets with the calibrated "
        "file: Rd 1, Rs 3, n 3):",
    ]
    for name, regions in f.end_to_end.items():
        cells = "; ".join(
            f"{rid}: Rd {e.rd_pct:.2f} Rs {e.rs_pct:.2f} n {e.n_pct:.2f}" if np.isfinite(e.rd_pct)
            else f"{rid}: not fitted"
            for rid, e in sorted(regions.items())
        )  # fmt: skip
        worst = [  # nan: no region has that figure (no specular fitted anywhere)
            max((getattr(e, k) for e in regions.values() if np.isfinite(getattr(e, k))), default=float("nan"))
            for k in ("rd_pct", "rs_pct", "n_pct")
        ]
        lines.append(f"  {name:10}: worst Rd {worst[0]:.2f}, Rs {worst[1]:.2f}, n {worst[2]:.2f} ({cells})")
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)
