"""``hlr-lab bench``: benchmarks that print figures."""

from __future__ import annotations

from pathlib import Path

import click

from benchmarks.numerical import (
    fit_error_grid,
    grid_report,
    optimum_figures,
    optimum_objects,
    optimum_report,
    plan_cases,
    plan_report,
    run_plan_case,
    run_throughput_case,
    spacing_line,
    throughput_header,
    throughput_line,
)
from hlr_lab.cli.calibrate_cmd import count_option
from hlr_lab.cli.common import FILE, FOLDER, Finite, placement_options, speed_factor_option, true_rig_option
from hlr_lab.cli.console import console, out
from hlr_lab.errors import InputError
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.file import load_rig, sim_rig


def _print(lines: list[str]) -> None:
    for line in lines:
        out.print(line, markup=False, soft_wrap=True)


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
@placement_options
@click.option(
    "--large",
    "min_vertices",
    type=click.IntRange(min=0),
    default=1_000_000,
    help="Also plan on the mesh split at its edges' midpoints to this many vertices (0: skip; a scan: 10000000).",
)
@click.option(
    "--assets", "assets", type=FOLDER, help="Folder holding spot/ (the fewest-lights cases add Spot)."
)
@click.option("--fewest/--no-fewest", default=True, help="Also the fewest-lights cases (about a minute).")
def bench_plan(mesh_path, up, scale, min_vertices, assets, fewest) -> None:
    """Planning time and peak memory: the paper's 4.1 set-up (8 regions in view, sphere 2× the bounding
    sphere, θc = 5°, one view, candidate spacing 0.5°; counted in pixels, and on the mesh itself also in
    vertices as the paper counts) on the mesh and on it split to ``--large`` vertices (a scan's claims
    checked on the mesh itself). Then the fewest lights: each case's lights against the greedy's and the
    lower bound.

    \b
    Example:
      hlr-lab bench plan --mesh ../shared/assets/stanford-bunny.obj --up y --assets ../shared/assets
      hlr-lab bench plan --mesh ../shared/assets/stanford-bunny.obj --up y --large 10000000 --no-fewest
    """
    console.print(spacing_line())
    out.print(
        "plan benchmark: one fresh process per case; loading and segmenting the mesh not in the plan time"
    )
    for case in plan_cases(mesh_path, up, scale, min_vertices):
        with console.status(f"planning {case[0]}…"):
            _print(plan_report(run_plan_case(*case)))
    if not fewest:
        return
    out.print(
        "fewest lights (the integer programme within its work limits; the bound is on the planner's estimated counts):"
    )
    for name, placed, settings in optimum_objects(mesh_path, up, scale, assets):
        with console.status(f"planning {name}…"):
            _print([optimum_report(optimum_figures(name, placed, settings))])


@bench.command("fit")
@click.option(
    "--sizes",
    default="1000000,3000000,10000000",
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
        with console.status("fitting the grid…"):
            rows = fit_error_grid()
        _print(grid_report(rows))
    _print([throughput_header()])
    for n in (int(x) for x in sizes.split(",") if x.strip()):
        with console.status(f"fitting {n:,} samples…"):
            _print([throughput_line(run_throughput_case(n))])


@bench.command("sim")
@click.option("-n", "transactions", type=click.IntRange(10, 100_000), default=1000)
@click.option(
    "--frames",
    type=click.IntRange(0, 100_000),
    default=1000,
    help="Re-renders for the memory figure (0: skip the renderer).",
)
def bench_sim(transactions, frames) -> None:
    """The simulated rig: round trips to the Dynamixel bus (real dynamixel-sdk over its pseudo-terminal)
    and the Modbus stage (pymodbus over TCP and RTU); a frame's transport from the camera (GigE Vision
    through Aravis, and the older TCP endpoint); render time per frame and memory over re-renders.

    \b
    Example:
      hlr-lab bench sim -n 2000
    """
    from benchmarks.sim import (  # the simulator: CLI only
        camera_transport_figures,
        camera_transport_report,
        render_figures,
        render_report,
        transactions_report,
    )

    with console.status("") as status:
        _print(transactions_report(transactions, progress=status.update))
        status.update("timing the camera's frames…")
        _print(camera_transport_report(camera_transport_figures()))
    if frames:
        with console.status(f"rendering (then {frames} re-renders)…"):
            _print(render_report(render_figures(frames)))


@bench.command("acquire")
@click.option("--poses", type=click.IntRange(2, 10_000), default=20)
@speed_factor_option("Simulated", default=1000.0)  # fast: waiting for motion must hide nothing
@click.option("--packet-loss", type=click.FloatRange(0.0, 0.5), default=0.0, show_default=True,
              help="Fraction of the simulated camera's stream packets lost on their first sending.")  # fmt: skip
def bench_acquire(poses, speed_factor, packet_loss) -> None:
    """Acquisition on the simulated rig with the real drivers: software overhead per pose (wall time not
    spent waiting for the axes or the camera), servo / Modbus transactions per pose, and the camera's
    GigE Vision packets over the run (received, resent, missing).

    The plan is builtin:pebble's, its poses cycled to the count asked for; frames are 1280×960, 16-bit,
    stored in a scratch directory that is removed afterwards.

    \b
    Examples:
      hlr-lab bench acquire --poses 50
      hlr-lab bench acquire --poses 20 --packet-loss 0.05   # a lossy link: every packet resent
    """
    from benchmarks.acquire import acquire_figures, report  # builds the simulated rig: CLI only

    with console.status(f"acquiring {poses} poses on the simulated rig…"):
        f = acquire_figures(poses=poses, speed_factor=speed_factor, packet_loss=packet_loss)
    _print(report(f, speed_factor))


@bench.command("session-fit")
@click.option("--poses", type=click.IntRange(2, 1000), default=20)
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
    from benchmarks.acquire import session_fit_figures  # builds the simulated rig: CLI only
    from benchmarks.numerical import session_fit_report

    with console.status("") as status:
        f, frames = session_fit_figures(poses, progress=status.update)
    _print(session_fit_report(f, frames))


@bench.command("image-formation")
@click.argument("session", type=FOLDER)
@click.option("--sub", type=click.IntRange(1, 8), default=3, show_default=True,
              help="Rays per pixel side for the box prediction.")  # fmt: skip
def bench_image_formation(session: Path, sub: int) -> None:
    """Where the fit's one ray per pixel centre parts from how the simulated camera forms a pixel: the
    SESSION's pixels against the true model (the default simulated world: acquire --sim without --scene)
    predicted at the pixel centre and over the pixel's box (as the simulated camera forms it), by β; and
    the n and Rs each prediction gives the fit.

    \b
    Example:
      hlr-lab paint --mesh stanford-bunny.obj -o bunny8.ply
      hlr-lab plan --mesh bunny8.ply --sim -o plan.json
      hlr-lab acquire --plan plan.json --sim --out bunny-session
      hlr-lab bench image-formation bunny-session
    """
    from benchmarks.image_formation import image_formation, image_formation_lines  # the simulator: CLI only

    with console.status("comparing the pixels with the true model"):
        result = image_formation(session, sub)
    _print(image_formation_lines(result))


@bench.command("materials")
@click.option("--scenes", type=click.IntRange(1, 10_000), default=30, show_default=True,
              help="Scenes, each with its own random materials; the objects taken in turn.")  # fmt: skip
@click.option("--objects", default="pebble", show_default=True,
              help="Comma-separated, from pebble, bunny, spot (bunny and spot need --assets).")  # fmt: skip
@click.option("--assets", "assets", type=FOLDER,
              help="A folder with stanford-bunny.obj and spot/ (spot_triangulated.obj, spot_texture.png).")  # fmt: skip
@click.option("--rig", "rig_path", type=FILE,
              help="The rig file hlr-lab believes (default: the built-in simulated rig).")  # fmt: skip
@true_rig_option
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--precision", "precision_pct", type=click.FloatRange(0, 100, min_open=True), metavar="PCT",
              help="Acquire each scene adaptively for this standard error of every parameter, per cent "
              "(acquire --adaptive --precision); default: the plan as made.")  # fmt: skip
@click.option("--out", "out_dir", type=FOLDER,
              help="Keep every scene's plan, truth and session here, and the results as materials-bench.json "
              "(a new folder; default: a scratch folder).")  # fmt: skip
def bench_materials(scenes, objects, assets, rig_path, true_rig, seed, precision_pct, out_dir) -> None:
    """Do the fitted materials and their standard errors tell the truth? Each scene is an object with seeded
    random materials (n log-uniform 8–500, Rd per channel 0.02–0.9, a grey Rs with Rd + Rs ≤ 1), planned
    on the rig hlr-lab believes, acquired on the simulated rig (built as --true-rig when given) and fitted:
    every parameter against its truth, in per cent and in standard errors. Prints a line per scene, then
    per parameter the worst and median error and the coverage: the share within 1 and 2 stated σ (≈ 68 %
    and ≥ 90 % when the uncertainties are honest).

    \b
    Examples:
      hlr-lab bench materials --scenes 30 --objects pebble,bunny,spot --assets ../shared/assets
      hlr-lab bench materials --rig calibrated.toml --true-rig builtin:bench-offsets --scenes 6
      hlr-lab bench materials --scenes 8 --objects bunny,spot --assets ../shared/assets --precision 0.5
    """
    from benchmarks.calibration import bench_folder  # the simulator: CLI only
    from benchmarks.materials import coverage_lines, materials_bench, save_results, scene_line

    names = _bench_objects(objects)
    believed = load_rig(rig_path) if rig_path is not None else sim_rig()
    with bench_folder(out_dir) as folder, console.status("") as status:
        results = materials_bench(folder, believed, scenes=scenes, objects=names, assets=assets,
                                  true_rig=true_rig, seed=seed, precision_pct=precision_pct, progress=status.update,
                                  done=lambda r: _print([scene_line(r)]))  # fmt: skip
        if out_dir is not None:
            save_results(folder / "materials-bench.json", results)
    _print(coverage_lines(results))


@bench.command("adaptive")
@click.option("--cases", default="n 8,n 40,n 400,n 8/40/400,narrow", show_default=True,
              help="Comma-separated: the lobes the regions take in turn (benchmarks/adaptive.py CASES).")  # fmt: skip
@click.option("--objects", default="pebble", show_default=True,
              help="Comma-separated, from pebble, bunny, spot (bunny and spot need --assets).")  # fmt: skip
@click.option("--assets", "assets", type=FOLDER,
              help="A folder with stanford-bunny.obj and spot/ (spot_triangulated.obj, spot_texture.png).")  # fmt: skip
@click.option("--min-samples", type=Finite(1, 1e7), default=PlanSettings().min_samples, show_default=True,
              help="M of the plan each case starts from.")  # fmt: skip
@click.option("--precision", "precision_pct", type=click.FloatRange(0, 100, min_open=True), metavar="PCT",
              help="The adaptive runs' standard error asked of every parameter, per cent (acquire --adaptive "
              "--precision); default: none, the plan's M.")  # fmt: skip
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--out", "out_dir", type=FOLDER,
              help="Keep every case's plan, truth and both sessions here (a new folder).")  # fmt: skip
def bench_adaptive(cases, objects, assets, min_samples, precision_pct, seed, out_dir) -> None:
    """The closed loop against the plan as made: each case's object planned with the default θc, then
    photographed on the simulated rig twice in the same world — the plan as it is, and adaptively (a
    pilot, each region's θc measured, the rest planned again) — and both fitted. Prints per case the poses
    each photographed and the worst region's Rd, Rs and n errors against the truth.

    \b
    Examples:
      hlr-lab bench adaptive
      hlr-lab bench adaptive --min-samples 400 --objects pebble,bunny --assets ../shared/assets
      hlr-lab bench adaptive --min-samples 400 --precision 0.25
    """
    from benchmarks.adaptive import CASES, adaptive_bench, case_line, header
    from benchmarks.calibration import bench_folder  # the simulator: CLI only

    chosen = tuple(c.strip() for c in cases.split(",") if c.strip())
    unknown = sorted(set(chosen) - set(CASES))
    if unknown or not chosen:
        raise InputError(
            f"unknown case(s) {', '.join(unknown) or '(none)'}; use {', '.join(CASES)}", field="--cases"
        )
    settings = PlanSettings(min_samples=min_samples)
    with bench_folder(out_dir) as folder, console.status("") as status:
        _print(header())
        adaptive_bench(folder, sim_rig(), cases=chosen, objects=_bench_objects(objects), assets=assets,
                       settings=settings, seed=seed, precision_pct=precision_pct, progress=status.update,
                       done=lambda f: _print([case_line(f)]))  # fmt: skip


@bench.command("register")
@click.option("--objects", default="pebble", show_default=True,
              help="Comma-separated, from pebble, bunny, spot (bunny and spot need --assets).")  # fmt: skip
@click.option("--assets", "assets", type=FOLDER,
              help="A folder with stanford-bunny.obj and spot/ (spot_triangulated.obj, spot_texture.png).")  # fmt: skip
@click.option("--spp", type=click.IntRange(1, 1024), default=16, show_default=True,
              help="Samples per pixel of the rendered views.")  # fmt: skip
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option("--out", "out_dir", type=FOLDER,
              help="Keep the objects' plans here (a new folder; default: a scratch folder).")  # fmt: skip
@click.option("--end-to-end/--no-end-to-end", default=True, show_default=True,
              help="Also register each object (hlr-lab register on the simulated rig), acquire and fit.")  # fmt: skip
@click.option("--random", "random_count", type=click.IntRange(1, 1000),
              help="Instead of the four fixed placements, this many seeded random ones per object (turned "
                   "anywhere, up to 15 mm off, tilted up to 3°), and the standard errors' coverage table.")  # fmt: skip
def bench_register(objects, assets, spp, seed, out_dir, end_to_end, random_count) -> None:
    """How well the object's placement is measured from its outlines: each object put where the plan does
    not expect it (turned about the axis, up to 2 cm off it, tilted 3°) on the simulated rig, its
    registration views rendered and exposed, the placement measured from them alone. Prints per case every
    mesh vertex's distance from where it really lies (RMS, worst), the rotation's error, the outline
    residual and the times; then each object resting on another of its faces (its likeliest stable pose
    other than the plan's), which the measurement must find; then a cylinder painted in four sectors, whose
    turn only its colours fix; then
    end to end, each object 12, −8 mm off and turned 200°: registered with hlr-lab register (through the
    drivers), the placed plan acquired and fitted, beside the plan acquired as it was: the worst region's
    Rd, Rs and n errors against the truth, the poses fit flagged, the registration's rig and wall time.
    With --random N: N seeded placements per object instead of the four, the share of each of the six
    numbers' errors within 1 and 2 stated standard errors, and nothing after that.

    \b
    Examples:
      hlr-lab bench register
      hlr-lab bench register --objects pebble,bunny,spot --assets ../shared/assets
      hlr-lab bench register --objects pebble,bunny,spot --assets ../shared/assets --random 8
    """
    from benchmarks.calibration import bench_folder  # the simulator: CLI only
    from benchmarks.register import (
        PLACEMENTS,
        case_line,
        coverage_lines,
        cylinder_bench,
        cylinder_line,
        end_to_end_bench,
        end_to_end_line,
        face_bench,
        face_line,
        random_placements,
        register_bench,
        summary_lines,
    )

    names = _bench_objects(objects)
    with bench_folder(out_dir) as folder, console.status("") as status:
        placements = PLACEMENTS if random_count is None else random_placements(random_count, seed)
        results = register_bench(folder, sim_rig(), objects=names, assets=assets, spp=spp, seed=seed,
                                 placements=placements, progress=status.update,
                                 done=lambda r: _print([case_line(r)]))  # fmt: skip
        if random_count is not None:
            _print(summary_lines(results) + coverage_lines(results))
            return
        status.update("each object on another face…")
        face_bench(
            folder, sim_rig(), objects=names, spp=spp, seed=seed, done=lambda r: _print([face_line(r)])
        )
        status.update("the painted cylinder…")
        cylinder_bench(sim_rig(), spp=spp, seed=seed, done=lambda r: _print([cylinder_line(r)]))
        _print(summary_lines(results))
        if end_to_end:
            status.update("end to end: register, acquire, fit…")
            end_to_end_bench(folder, sim_rig(), objects=names, done=lambda r: _print([end_to_end_line(r)]))


def _bench_objects(objects: str) -> tuple[str, ...]:
    """``--objects``' names, each one of the bench's objects."""
    from benchmarks.materials import OBJECTS

    names = tuple(n.strip() for n in objects.split(",") if n.strip())
    unknown = sorted(set(names) - set(OBJECTS))
    if unknown or not names:
        raise InputError(f"unknown object(s) {', '.join(unknown) or '(none)'}; use {', '.join(OBJECTS)}",
                         field="--objects")  # fmt: skip
    return names


@bench.command("soak")
@click.option("--poses", type=click.IntRange(20, 100_000), default=500)
@click.option("--kills", type=click.IntRange(0, 1000), default=10, help="SIGKILLs at random moments.")
@click.option(
    "--fault-every",
    "fault_interval_s",
    type=Finite(min=0.05),
    default=0.6,
    help="Mean seconds between injected faults.",
)
@click.option("--seed", type=int, default=0)
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
    from benchmarks.soak import passed, report, soak  # builds the simulated rig: CLI only

    with console.status(f"soaking {poses} poses on the simulated rig…"):
        f = soak(
            poses=poses, kills=kills, fault_interval_s=fault_interval_s, speed_factor=speed_factor, seed=seed
        )
    _print(report(f, speed_factor))
    if not passed(f):
        raise SystemExit(1)


@bench.command("calibration")
@click.option(
    "--true-rig",
    "true_rig",
    default="builtin:bench-night",
    metavar="FILE|builtin:NAME",
    help="The simulated world's rig as it really is (hlr-lab starts from the drawing, the built-in rig).",
)
@count_option("views", "Board photographs.")
@count_option("poses", "Lamp poses.")
@click.option("--run-poses", type=click.IntRange(1, 1000), default=40,
              help="Poses of the end-to-end runs (builtin:pebble's plan cycled).")  # fmt: skip
@click.option(
    "--out",
    "out_dir",
    type=FOLDER,
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
    from benchmarks.calibration import bench_folder, calibration_figures, report  # the simulator: CLI only

    with bench_folder(out_dir) as folder, console.status("calibrating…") as status:
        f = calibration_figures(folder, true_rig=true_rig, views=views, poses=poses, run_poses=run_poses,
                                speed_factor=speed_factor, progress=status.update)  # fmt: skip
    _print(
        report(f, true_rig=true_rig, views=views, poses=poses, run_poses=run_poses, speed_factor=speed_factor)
    )
