"""Benchmarks that print figures (not timed unit tests): ``hlr-lab bench plan`` and ``hlr-lab bench fit``.

Cases that measure memory run in a fresh process so that their peak is their own.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import KDTree

from hlr_lab.errors import HlrLabError
from hlr_lab.fitting import DEFAULT_ESTIMATOR, ESTIMATORS, EstimatorName, fit_region
from hlr_lab.fitting.synthetic import PAPER_42, Truth, synthetic_region
from hlr_lab.geometry.sphere import directions_with_spacing
from hlr_lab.object.mesh import ColouredMesh, load_mesh
from hlr_lab.object.procedural import paint_patches, pebble
from hlr_lab.object.raycast import RayCaster, visible_vertices
from hlr_lab.object.segment import Segmentation, segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlannedLight, PlanSettings, TakenLight, plan_lights
from hlr_lab.rig.file import Rig, sim_rig

PAPER_REGIONS = 8
WARM_RUNS = 5  # the paper's set-up planned again in its process, for the compute's own time
PAPER_SETTINGS = PlanSettings(
    theta_c_deg=5.0, min_samples=50, sphere_scale=2.0, views_deg=[0.0], spacing_deg=0.5
)


def paper_41_object(
    mesh: ColouredMesh, rig: Rig, *, up: str = "z", scale: float = 1.0, k: int = PAPER_REGIONS
) -> ColouredMesh:
    """The paper's 4.1 set-up: the placed mesh painted in ``k`` patches that all face the camera at
    turntable 0° (clustered among the visible vertices), like the paper's 8 regions in view."""
    placed = mesh.transformed(placement(mesh, up=up, scale=scale))
    bare = ColouredMesh(placed.vertices, placed.faces)
    seen = visible_vertices(RayCaster(bare), rig.camera, max_view_angle_deg=PAPER_SETTINGS.max_view_angle_deg)
    return paint_patches(bare, k, among=seen).mesh


def subdivided(mesh: ColouredMesh, min_vertices: int) -> ColouredMesh:
    """``mesh`` split at its edges' midpoints (the same surface) to ``min_vertices`` vertices (or more, if
    ``mesh`` has more): whole rounds while a round (~4× the vertices) stays within the count, then the
    vertices still missing as single edges split at their midpoints, spread over the mesh, each splitting
    its two faces in two. Watertight as a scan is: no T-junction, whose edges would be rims."""
    v, f = mesh.vertices, mesh.faces
    while 4 * len(v) <= min_vertices:
        v, f = trimesh.remesh.subdivide(v, f)[:2]
    while len(v) < min_vertices:
        v, f = _bisected(v, f, min_vertices - len(v))
    return ColouredMesh(v, f)


def _bisected(v: np.ndarray, f: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``v`` (V, 3), ``f`` (F, 3) with up to ``count`` inner edges split at their midpoints, no two edges of
    one face (an edge is taken where its seeded rank is the lowest of its two faces' edges)."""
    shared, faces, _, _ = ColouredMesh(v, f).edge_faces()  # (E, 2) vertices, (E, 2) faces
    rank = np.random.default_rng(0).permutation(len(shared))
    lowest = np.full(len(f), len(shared))
    for side in range(2):
        np.minimum.at(lowest, faces[:, side], rank)
    taken = np.flatnonzero((lowest[faces[:, 0]] == rank) & (lowest[faces[:, 1]] == rank))
    taken = taken[np.argsort(rank[taken])][:count]
    middle = len(v) + np.arange(len(taken))  # (T,) the new vertices
    v = np.concatenate([v, v[shared[taken]].mean(axis=1)])
    halves = []
    for side in range(2):
        face = faces[taken, side]
        corner = f[face]  # (T, 3)
        lo, hi = shared[taken, 0], shared[taken, 1]
        # the split edge is corner c → c+1 of the face; keep the winding: (c, mid, c+2), (mid, c+1, c+2)
        c = np.zeros(len(face), np.int64)
        for k in range(3):
            a, b = corner[:, k], corner[:, (k + 1) % 3]
            c[(np.minimum(a, b) == lo) & (np.maximum(a, b) == hi)] = k
        row = np.arange(len(face))
        p0, p1, p2 = corner[row, c], corner[row, (c + 1) % 3], corner[row, (c + 2) % 3]
        f = f.copy() if side == 0 else f
        f[face] = np.stack([p0, middle, p2], axis=1)
        halves.append(np.stack([middle, p1, p2], axis=1))
    return v, np.concatenate([f, *halves])


@dataclass
class PlanFigures:
    case: str
    vertices: int
    regions: int
    lights: int
    lights_plain: int
    lower_bound: int
    uncovered: int
    plan_s: float
    stages: dict[str, float]
    rss_before_mb: float
    rss_peak_plan_mb: float
    segment_s: float
    rss_peak_segment_mb: float
    proxy_vertices: int = 0  # the ray proxy's vertices (0: planned on the mesh itself)
    gbuffer_s: float = 0.0  # the ray engine built on the mesh itself and one G-buffer cast, as a fit does
    rss_peak_gbuffer_mb: float = 0.0
    register: ScanRegistration | None = None  # the placement measured with the mesh itself (a scan only)
    # the plan's claims against its lights counted exactly on the mesh itself (planned on a proxy), and on
    # the mesh it was subdivided from (a decimated copy), as ratios claim / count: per region, in total
    claims_on_mesh: np.ndarray | None = None
    claims_on_copy: np.ndarray | None = None
    # the same plan made again in the same process (imports, caches and the allocator warm), s each: the
    # paper's set-up's compute (a mesh as it was loaded only)
    warm_s: tuple[float, ...] = ()
    # the paper's set-up counted in vertices, as the paper counts (a mesh as it was loaded only)
    vertex_count: VertexCountFigures | None = None


@dataclass(frozen=True)
class VertexCountFigures:
    """The paper's set-up planned with vertex counts in a warm process: its lights and bound, and the
    compute's time (s) with the search for the fewest (``plan``'s default; ``optimum_s`` the search's own, in
    the last run) and without it (the greedy's lights, pruned, and the LP bound: ``--optimum-budget 0``),
    each the median of WARM_RUNS."""

    lights: int
    lower_bound: int
    proven: bool
    greedy_lights: int
    plan_s: float
    optimum_s: float
    greedy_and_bound_s: float


@dataclass(frozen=True)
class ScanRegistration:
    """``register``'s solve with a scan: its time (s) and peak RSS (MB), the error of the placement it found
    (every vertex's distance from where it lies, RMS, mm; the rotation's, degrees), and the time the mesh it
    was subdivided from takes for the same views."""

    seconds: float
    rss_peak_mb: float
    rms_mm: float
    rotation_deg: float
    coarse_seconds: float


class _PeakRss:
    """Samples this process's resident memory every few ms while active (the kernel's high-water mark
    cannot be reset, and the set-up before planning may be larger than planning itself)."""

    def __init__(self, period_s: float = 0.005):
        self.period, self.peak, self._stop = period_s, 0, threading.Event()
        self._page = os.sysconf("SC_PAGE_SIZE")

    def _rss(self) -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * self._page

    def __enter__(self):
        self.peak = self._rss()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.wait(self.period):
            self.peak = max(self.peak, self._rss())

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._rss())


def _plan_case(case: str, mesh_path: str | None, up: str, scale: float, min_vertices: int) -> PlanFigures:
    rig = sim_rig()
    base = load_mesh(mesh_path) if mesh_path else pebble().mesh
    coarse = paper_41_object(base, rig, up=up, scale=scale)
    painted = (
        paper_41_object(subdivided(base, min_vertices), rig, up=up, scale=scale) if min_vertices else coarse
    )
    del base  # a plan process holds one copy of the mesh
    gc.collect()
    with _PeakRss() as segmenting:
        t = time.perf_counter()
        seg = segment(painted)
        segment_s = time.perf_counter() - t
    gc.collect()
    rss = _PeakRss()
    before = rss._rss()
    with rss:
        t = time.perf_counter()
        result = plan_lights(painted, seg, rig, PAPER_SETTINGS)
        elapsed = time.perf_counter() - t
    figures = PlanFigures(
        case,
        len(painted.vertices),
        seg.n_regions,
        len(result.lights),
        result.lights_by_criterion.get("plain", -1),
        result.optimum.lower_bound,
        len(result.uncovered),
        elapsed,
        result.seconds,
        before / 2**20,
        rss.peak / 2**20,
        segment_s,
        segmenting.peak / 2**20,
    )
    if not min_vertices:
        for _ in range(WARM_RUNS):
            t = time.perf_counter()
            plan_lights(painted, seg, rig, PAPER_SETTINGS)
            figures.warm_s += (time.perf_counter() - t,)
        figures.vertex_count = _vertex_count_figures(painted, seg, rig)
    if result.proxy is None:
        return figures
    # the claims checked, after the figures: the full mesh's ray engine is what the proxy spares
    claims = np.sum([light.expected for light in result.lights], axis=0)  # (R,)
    figures.proxy_vertices = len(result.proxy.mesh.vertices)
    figures.register = registered_scan(painted, coarse, rig)
    # what fitting the scan asks of its geometry: the ray engine on the mesh itself, and a G-buffer
    gc.collect()
    with _PeakRss() as geometry:
        t = time.perf_counter()
        caster = RayCaster(painted)
        caster.gbuffer(rig.camera)
        figures.gbuffer_s = time.perf_counter() - t
    figures.rss_peak_gbuffer_mb = geometry.peak / 2**20
    figures.claims_on_mesh = claims / counted_on(painted, seg, rig, result.lights, caster)
    if coarse is not painted:
        # the decimated copy painted as the scan is (each vertex the label of the scan's nearest)
        label = seg.vertex_labels[KDTree(painted.vertices).query(coarse.vertices)[1]]
        copy_seg = replace(seg, vertex_labels=label, face_labels=label[coarse.faces[:, 0]])
        with np.errstate(divide="ignore"):  # a region the copy does not count at all: inf, printed "none"
            figures.claims_on_copy = claims / counted_on(coarse, copy_seg, rig, result.lights)
    return figures


def _vertex_count_figures(painted: ColouredMesh, seg: Segmentation, rig: Rig) -> VertexCountFigures:
    """The paper's set-up counted in vertices, planned WARM_RUNS times with the search for the fewest and
    as many without it (the process already warm)."""
    searched = replace(PAPER_SETTINGS, count="vertices")
    runs = [(searched, []), (replace(searched, optimum_budget_s=0), [])]
    results = []
    for _ in range(WARM_RUNS):
        for settings, times in runs:
            t = time.perf_counter()
            results.append(plan_lights(painted, seg, rig, settings))
            times.append(time.perf_counter() - t)
    best, greedy = results[-2:]
    return VertexCountFigures(
        len(best.lights),
        best.optimum.lower_bound,
        best.optimum.proven,
        len(greedy.lights),
        float(np.median(runs[0][1])),
        best.seconds["optimum"],
        float(np.median(runs[1][1])),
    )


def registered_scan(scan: ColouredMesh, surface: ColouredMesh, rig: Rig) -> ScanRegistration:
    """The placement solved with ``scan`` (in the turntable frame, as planned) from six views' masks
    ray-cast from ``surface`` (the mesh it was subdivided from: the same surface, so the masks are the scan's
    without an Embree scene of its faces) lying 12, −8 mm off, turned 200° and tilted 2°: what ``hlr-lab
    register`` solves, without the rig."""
    from benchmarks.register import VIEWS_DEG, Placed
    from hlr_lab.placement.photographs import ObservedView
    from hlr_lab.placement.pose import PlacementFrame, rotation_error_deg, vertex_errors_mm
    from hlr_lab.placement.solve import Outlines, register, view_camera

    frame = PlacementFrame.about(surface.vertices, np.eye(4))
    true = frame.matrix(Placed(12, -8, 200, tilt_deg=2).params())
    caster = RayCaster(surface.transformed(true))
    views = [ObservedView(a, caster.gbuffer(view_camera(rig.camera, a)).hit) for a in VIEWS_DEG]
    t = time.perf_counter()
    register(Outlines(surface, rig.camera, frame, views))
    coarse_s = time.perf_counter() - t
    gc.collect()
    with _PeakRss() as rss:
        t = time.perf_counter()
        found = register(Outlines(scan, rig.camera, PlacementFrame.about(scan.vertices, np.eye(4)), views))
        elapsed = time.perf_counter() - t
    errors = vertex_errors_mm(surface.vertices, found.mesh_to_turntable, true)
    return ScanRegistration(
        elapsed,
        rss.peak / 2**20,
        float(np.sqrt(np.mean(errors**2))),
        rotation_error_deg(found.mesh_to_turntable, true),
        coarse_s,
    )


def counted_on(
    mesh: ColouredMesh,
    seg: Segmentation,
    rig: Rig,
    lights: list[PlannedLight],
    caster: RayCaster | None = None,
) -> np.ndarray:
    """(R,) the highlight samples ``lights`` give each region, counted exactly on ``mesh`` itself (no proxy;
    ``caster`` its own, if already built) with the paper set-up's settings."""
    taken = [TakenLight(light.turntable_deg, light.light_world) for light in lights]
    settings = replace(PAPER_SETTINGS, max_lights=len(taken), compare_criteria=False, optimum_budget_s=0)
    counted = plan_lights(mesh, seg, rig, settings, caster=caster or RayCaster(mesh), taken=taken)
    return np.sum([light.expected for light in counted.lights[: len(taken)]], axis=0)


@dataclass
class OptimumFigures:
    case: str
    regions: int
    satisfied: int
    lights: int
    greedy: dict[str, int]
    lower_bound: int
    lp_value: float
    proven: bool
    chosen_by: str
    status: str
    optimum_s: float
    plan_s: float


MIXED_THETA_C_DEG = (30.0, 12.0, 2.6, 4.0)  # builtin:pebble's regions, as a re-plan measures them


def optimum_objects(mesh_path: Path | None, up: str, scale: float, assets: Path | None) -> list[tuple]:
    """``bench plan``'s cases for the fewest lights: (name, placed mesh, settings). The paper's set-up
    on ``mesh_path`` (8 regions; counted in pixels, then in vertices as the paper counts) and the same mesh
    in 12 patches, builtin:pebble and the pebble in 14 patches on the simulated rig, and Spot when
    ``assets`` holds it; the pebble also with each region's own cone, as an adaptive re-plan plans it."""
    rig = sim_rig()
    base = load_mesh(mesh_path) if mesh_path else pebble().mesh
    name = Path(mesh_path).stem if mesh_path else "builtin:pebble"
    paper = paper_41_object(base, rig, up=up, scale=scale)
    cases: list[tuple] = [
        (f"{name}, paper 4.1 (8 regions)", paper, PAPER_SETTINGS),
        (f"{name}, paper 4.1 counted in vertices", paper, replace(PAPER_SETTINGS, count="vertices")),
        (
            f"{name}, paper 4.1 in 12 patches",
            paper_41_object(base, rig, up=up, scale=scale, k=12),
            PAPER_SETTINGS,
        ),
    ]
    stone = pebble().mesh
    placed = stone.transformed(placement(stone))
    cases.append(("builtin:pebble, sim rig", placed, PlanSettings()))
    # an adaptive re-plan's cones: each region's measured θc, a wide lobe beside a narrow one
    mixed = PlanSettings(region_theta_c_deg=MIXED_THETA_C_DEG)
    cases.append(("builtin:pebble, sim rig, θc 30/12/2.6/4°", placed, mixed))
    cases.append(("pebble in 14 patches, sim rig", paint_patches(placed, 14).mesh, PlanSettings()))
    spot = None if assets is None else assets / "spot" / "spot_triangulated.obj"
    if spot is not None and spot.exists():
        mesh = load_mesh(spot, spot.with_name("spot_texture.png"))
        cases.append(("Spot, sim rig", mesh.transformed(placement(mesh, up="y", scale=0.08)), PlanSettings()))
    return cases


def optimum_figures(name: str, placed: ColouredMesh, settings: PlanSettings) -> OptimumFigures:
    """Plan ``placed`` (already on the plate) on the simulated rig: lights, the greedy's, the bound."""
    seg = segment(placed)
    t = time.perf_counter()
    result = plan_lights(placed, seg, sim_rig(), settings)
    o = result.optimum
    return OptimumFigures(
        name,
        seg.n_regions,
        int(result.satisfied.sum()),
        len(result.lights),
        result.lights_by_criterion,
        o.lower_bound,
        o.lp_value,
        o.proven,
        o.chosen_by,
        o.status,
        o.seconds,
        time.perf_counter() - t,
    )


def optimum_report(f: OptimumFigures) -> str:
    """One line of ``bench plan``'s fewest-lights table."""
    greedy = "/".join(str(f.greedy[k]) for k in ("capped", "plain") if k in f.greedy)
    proof = "proven" if f.proven else "not proven"
    return (
        f"  {f.case}: {f.regions} regions ({f.satisfied} satisfied), {f.lights} lights by {f.chosen_by}; "
        f"greedy capped/plain {greedy}; lower bound {f.lower_bound} (LP {f.lp_value:.2f}), gap "
        f"{f.lights - f.lower_bound}, {proof} ({f.status}); optimum {f.optimum_s:.2f} s of {f.plan_s:.2f} s"
    )


def in_fresh_process(fn, *args):
    """Run ``fn(*args)`` in a fresh process (spawned: no memory inherited from this one)."""
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        return pool.apply(fn, args)


def run_plan_case(*args) -> PlanFigures:
    return in_fresh_process(_plan_case, *args)


FIT_NOISE_DN = (0.5, 1.0, 2.0, 4.0)
FIT_EXPONENTS = (5.0, 20.0, 59.0, 200.0, 500.0)
FIT_PIXELS = 40_000


@dataclass
class FitErrors:
    noise_dn: float
    n: float
    method: str
    rd_err: float  # max relative error over the channels
    rs_err: float
    n_err: float
    theta_c_deg: float
    seconds: float
    failure: str = ""


def fit_error_grid(
    noise_levels=FIT_NOISE_DN, exponents=FIT_EXPONENTS, pixels: int = FIT_PIXELS
) -> list[FitErrors]:
    """Both estimators, θc chosen automatically, on the paper's 4.2 set-up (cylinder, directional light,
    8-bit) with the paper's Rd and Rs and each exponent n, at each read-noise level."""
    rows = []
    for noise in noise_levels:
        for n in exponents:
            truth = Truth(PAPER_42.rd, PAPER_42.rs, n)
            region = synthetic_region(
                truth, pixels=pixels, bits=8, read_noise_dn=noise, seed=int(n * 10 + noise * 100)
            )
            for method in ESTIMATORS:
                t = time.perf_counter()
                try:
                    f = fit_region(
                        region.intensity,
                        region.irradiance,
                        region.cos_alpha,
                        region.cos_beta,
                        theta_c_deg="auto",
                        method=method,
                    )
                except HlrLabError as exc:
                    rows.append(FitErrors(noise, n, method, np.nan, np.nan, np.nan, np.nan, 0.0, str(exc)))
                    continue
                rows.append(
                    FitErrors(
                        noise,
                        n,
                        method,
                        _rel(f.rd, truth.rd),
                        _rel(f.rs, truth.rs),
                        _rel(f.n, n),
                        f.theta_c_deg,
                        time.perf_counter() - t,
                    )
                )
    return rows


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) / np.asarray(b) - 1)))


@dataclass
class Throughput:
    samples: int
    seconds: float
    inputs_bytes: int
    peak_extra_bytes: int  # resident memory the fit added on top of its inputs, at its peak

    @property
    def per_second(self) -> float:
        return self.samples / self.seconds

    @property
    def bytes_per_sample(self) -> float:
        return (self.inputs_bytes + self.peak_extra_bytes) / self.samples


def _throughput_case(samples: int, method: EstimatorName) -> Throughput:
    truth = Truth(np.array([0.6, 0.3, 0.2]), np.array([0.3, 0.3, 0.35]), 80.0)
    r = synthetic_region(
        truth,
        shape="sphere",
        light="point",
        pixels=samples,
        bits=12,
        read_noise_dn=2.0,
        electrons_per_dn=4.0,
        full_scale=1.6,
        seed=3,
    )
    inputs = sum(a.nbytes for a in (r.intensity, r.irradiance, r.cos_alpha, r.cos_beta))
    gc.collect()
    rss = _PeakRss()
    before = rss._rss()
    with rss:
        t = time.perf_counter()
        fit_region(r.intensity, r.irradiance, r.cos_alpha, r.cos_beta, theta_c_deg=20.0, method=method)
        elapsed = time.perf_counter() - t
    return Throughput(samples, elapsed, inputs, rss.peak - before)


def run_throughput_case(samples: int, method: EstimatorName = DEFAULT_ESTIMATOR) -> Throughput:
    return in_fresh_process(_throughput_case, samples, method)


def spacing_line() -> str:
    """The line ``hlr-lab bench plan`` prints first: the candidate grid's real spacing."""
    spacing = nearest_neighbour_spacing_deg(directions_with_spacing(PAPER_SETTINGS.spacing_deg))
    return f"candidate spacing: requested {PAPER_SETTINGS.spacing_deg}°, measured max nearest-neighbour {spacing:.3f}°"


def throughput_header() -> str:
    """The line ``hlr-lab bench fit`` prints before its throughput figures."""
    return (
        "throughput and memory (robust, θc 20°, one region, sphere, point light, photon + read noise; "
        "fresh process per size)"
    )


def plan_cases(mesh_path: Path | None, up: str, scale: float, min_vertices: int) -> list[tuple]:
    """``hlr-lab bench plan``'s cases (:func:`run_plan_case`'s arguments): the mesh (None: builtin:pebble),
    and unless ``min_vertices`` is 0 the mesh subdivided to at least that many vertices."""
    name = Path(mesh_path).stem if mesh_path else "builtin:pebble"
    path = None if mesh_path is None else str(mesh_path)
    cases = [(name, path, up, scale, 0)]
    return [*cases, (f"{name} subdivided", path, up, scale, min_vertices)] if min_vertices else cases


def nearest_neighbour_spacing_deg(directions: np.ndarray) -> float:
    from scipy.spatial import KDTree

    d, _ = KDTree(directions).query(directions, k=2)
    return float(np.degrees(2 * np.arcsin(d[:, 1].max() / 2)))


@dataclass
class SessionFitFigures:
    views: int
    pixels_per_frame: int
    regions_measured: int
    seconds: float
    stages: dict[str, float]
    peak_rss_mb: float


def _session_fit_case(session: str) -> SessionFitFigures:
    from hlr_lab.reflectance.session_fit import fit_session, open_session

    s = open_session(Path(session))
    rss = _PeakRss()
    with rss:
        t = time.perf_counter()
        result = fit_session(s)
        elapsed = time.perf_counter() - t
    return SessionFitFigures(
        len(s.views),
        s.rig.camera.width * s.rig.camera.height,
        len(result.fits),
        elapsed,
        result.seconds,
        rss.peak / 2**20,
    )


def run_session_fit_case(session: Path) -> SessionFitFigures:
    """``hlr-lab fit``'s work on ``session`` in a fresh process: time, per-stage time, peak memory."""
    return in_fresh_process(_session_fit_case, str(session))


def plan_report(f: PlanFigures) -> list[str]:
    """What ``hlr-lab bench plan`` prints for one case."""
    stages = ", ".join(f"{k} {v:.2f}" for k, v in f.stages.items())
    lines = [
        f"{f.case}: {f.vertices:,} vertices, {f.regions} regions",
        f"  lights {f.lights} (lower bound {f.lower_bound}; the plain count's greedy {f.lights_plain}), "
        f"uncovered regions {f.uncovered}",
        f"  plan time {f.plan_s:.2f} s  [{stages}]",
        *(
            [
                f"  planned again in the same process: median {np.median(f.warm_s):.2f} s, "
                f"least {min(f.warm_s):.2f} s of {len(f.warm_s)}"
            ]
            if f.warm_s
            else []
        ),
        *(_vertex_count_report(f.vertex_count) if f.vertex_count else []),
        f"  memory: RSS {f.rss_before_mb:.0f} MB before planning, peak RSS {f.rss_peak_plan_mb:.0f} MB while planning",
        f"  segmenting it (not in the plan time): {f.segment_s:.2f} s, peak RSS {f.rss_peak_segment_mb:.0f} MB",
    ]
    if f.gbuffer_s:
        lines.append(
            f"  the fit's geometry on it (its own ray engine, one G-buffer of the simulated rig's camera): "
            f"{f.gbuffer_s:.2f} s, peak RSS {f.rss_peak_gbuffer_mb:.0f} MB"
        )
    if f.register is not None:
        r = f.register
        lines.append(
            f"  register with it (six views' masks, placed 12, -8 mm off, turned 200°, tilted 2°): {r.seconds:.1f} s, "
            f"peak RSS {r.rss_peak_mb:.0f} MB; vertices {r.rms_mm:.3f} mm RMS off, rotation {r.rotation_deg:.3f}° "
            f"(the mesh it was subdivided from: {r.coarse_seconds:.1f} s)"
        )
    if f.proxy_vertices:
        lines.append(
            f"  planned on a ray proxy of {f.proxy_vertices:,} vertices; claims / the lights counted exactly:"
        )
    for where, ratio in (
        ("on the mesh itself", f.claims_on_mesh),
        ("on the mesh it was subdivided from", f.claims_on_copy),
    ):
        if ratio is not None:
            spread = ", ".join(f"{r:.2f}" if np.isfinite(r) else "none counted" for r in ratio)
            finite = ratio[np.isfinite(ratio)]
            worst = f"{_worst(finite):+.0%}" if len(finite) else "—"
            lines.append(f"    {where}: per region {spread}; worst {worst} where counted")
    return lines


def _vertex_count_report(v: VertexCountFigures) -> list[str]:
    proof = "proven" if v.proven else "not proven"
    return [
        f"  counted in vertices, as the paper counts: lights {v.lights} (lower bound {v.lower_bound}, {proof}; "
        f"the greedy's {v.greedy_lights}); planned again: median {v.plan_s:.2f} s, of which the search for the "
        f"fewest {v.optimum_s:.2f} s; greedy and bound alone (--optimum-budget 0) {v.greedy_and_bound_s:.2f} s"
    ]


def _worst(ratio: np.ndarray) -> float:
    """The ratio furthest from 1, as a relative error."""
    return float(ratio[np.argmax(np.abs(ratio - 1))] - 1)


def grid_report(rows: list[FitErrors]) -> list[str]:
    """The error grid as ``hlr-lab bench fit`` prints it: a table, then each estimator's summary."""
    lines = [
        f"error grid: paper 4.2 set-up (cylinder, directional light, 8-bit, Rd, Rs of the paper), "
        f"{FIT_PIXELS:,} pixels, θc auto; max relative error over RGB",
        f"{'σ DN':>5} {'n':>5}  {'method':7} {'Rd err':>8} {'Rs err':>8} {'n err':>8} {'θc°':>6} {'time s':>7}",
    ]
    for r in rows:
        if r.failure:
            lines.append(f"{r.noise_dn:5.1f} {r.n:5.0f}  {r.method:7} failed: {r.failure}")
            continue
        lines.append(
            f"{r.noise_dn:5.1f} {r.n:5.0f}  {r.method:7} {100 * r.rd_err:7.2f}% {100 * r.rs_err:7.2f}% "
            f"{100 * r.n_err:7.2f}% {r.theta_c_deg:6.1f} {r.seconds:7.3f}"
        )
    for method in ESTIMATORS:
        mine = [r for r in rows if r.method == method and not r.failure]
        if mine:
            lines.append(
                f"{method}: median errors Rd {100 * np.median([r.rd_err for r in mine]):.2f}%, "
                f"Rs {100 * np.median([r.rs_err for r in mine]):.2f}%, "
                f"n {100 * np.median([r.n_err for r in mine]):.2f}%; "
                f"worst Rd {100 * max(r.rd_err for r in mine):.2f}%, Rs {100 * max(r.rs_err for r in mine):.2f}%, "
                f"n {100 * max(r.n_err for r in mine):.2f}%; "
                f"{sum(1 for r in rows if r.method == method and r.failure)} failed; "
                f"median time per fit {np.median([r.seconds for r in mine]) * 1000:.0f} ms"
            )
    return lines


def throughput_line(t: Throughput) -> str:
    n = t.samples
    return (
        f"{n:>12,} samples: {t.seconds:6.2f} s, {t.per_second / 1e6:5.2f} M samples/s, inputs "
        f"{t.inputs_bytes / n:.0f} B/sample + working {t.peak_extra_bytes / n:.0f} B/sample = "
        f"{t.bytes_per_sample:.0f} B/sample"
    )


def session_fit_report(f: SessionFitFigures, frames: int) -> list[str]:
    stages = ", ".join(f"{name} {seconds:.1f} s" for name, seconds in f.stages.items())
    return [
        f"session: {f.views} poses, {frames} frames of {f.pixels_per_frame:,} pixels",
        f"fit (target ≤ 30 s, ≤ 1.5 GB): {f.seconds:.1f} s, peak RSS {f.peak_rss_mb:.0f} MB; "
        f"{f.regions_measured} regions measured",
        f"  per stage: {stages}",
    ]
