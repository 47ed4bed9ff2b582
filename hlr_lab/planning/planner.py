"""Plan light positions (and turntable views) that give every region at least M highlight samples.

The paper's algorithm (§3.2) with these additions, each on by default and reported:
visibility, shadows and grazing angles decide whether a sample counts; only reachable light positions
are candidates; a region counts only up to what it still needs (the plain count is reported too);
extra turntable views open when a region cannot be served from the first; M counts expected pixels.

Candidates come at two densities: estimates for the greedy are computed on a coarse grid (θc/3), and
evaluating a coarse candidate exactly refines it over the dense grid (≤ ``spacing_deg``) points in its
Voronoi cell — the lights of a plan are always dense-grid points with exact counts.
All geometry runs in the turntable frame (the placed object at turntable angle 0).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from scipy.spatial import KDTree

from hlr_lab.errors import InputError
from hlr_lab.geometry.sphere import directions_with_spacing, fibonacci_band, rotation_z
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import RayCaster, facing
from hlr_lab.object.segment import Segmentation
from hlr_lab.planning.coverage import ViewSamples, best_light, count_estimates, exact_counts
from hlr_lab.planning.diffuse import diffuse_counts_of_light, diffuse_estimates
from hlr_lab.planning.geometry import LightSphere, light_sphere, mirror_highlights
from hlr_lab.planning.greedy import MIN_GAIN, Choice, Selection, prune, score, select_lights
from hlr_lab.planning.optimum import TIME_GUARD, CoverOptimum, minimum_cover
from hlr_lab.planning.proxy import RayProxy, ray_proxy
from hlr_lab.planning.samples import (
    ESTIMATE_PX,
    SurfaceSamples,
    faces_towards,
    splits_faces,
    surface_samples,
)
from hlr_lab.rig.file import Rig

CountUnit = Literal["pixels", "vertices"]
Criterion = Literal["capped", "plain"]
Purpose = Literal["highlights", "diffuse", "taken"]
# estimate grid spacing θc/3: three points across a cone's radius. θc/5 counted 2.8× the candidate pairs
# for no better plan: on θc/3 the bound was proven on every bench case (bunny 8/12/16 patches, Spot,
# pebble), with the same or fewer lights (docs/planning.md)
COARSE_FRACTION_OF_THETA_C = 1 / 3
# pool samples of a region whose mirror points lie within its θc/2 into one estimate cone: on ~16 px
# samples, θc/4 made 6× the pools (pebble) for no better plan; θc/2 gave the same or fewer lights on bunny8,
# Spot and pebble
POOL_FRACTION = 2.0
INTEGER_PROGRAMME = "integer programme"
# Diffuse-only samples are wide (the whole lit side of a region outside a 5° cone): candidates every 10°
# find them, and the few best estimates are counted exactly.
DIFFUSE_SPACING_DEG = 10.0
EXACT_PER_ROUND = 24  # candidates counted exactly after a cover the estimates promised falls short
MAX_COVER_ROUNDS = 8  # covers checked against exact counts (bench plan's cases: every one held by its fifth)
DIFFUSE_EXACT_TRIES = 4
MAX_OPTIMUM_BUDGET_S = 600.0


@dataclass(frozen=True)
class PlanSettings:
    """What ``plan`` is asked for (its options; these defaults are the command's)."""

    theta_c_deg: float = 5.0
    min_samples: float = 50.0
    count: CountUnit = "pixels"
    sphere_scale: float | None = None  # None: S is the gantry's reachable sphere
    views_deg: Sequence[float] | None = None  # None: automatic
    view_step_deg: float = 45.0
    spacing_deg: float = 0.5
    max_view_angle_deg: float = 80.0  # grazing limit for the camera and the light
    max_lights: int = 64
    shadows: bool = True
    criterion: Criterion = "capped"  # "plain": the paper's count, every sample of a short region counts
    min_diffuse: float = 100.0  # diffuse-only samples each region needs for Rd (0: not planned)
    compare_criteria: bool = True  # also plan with the other criterion, and keep the one with fewer lights
    optimum_budget_s: float = 30.0  # guard on the integer programme's wall-clock time (0: the LP bound only)
    # each region's θc (degrees, in the segmentation's order) where it is known (an adaptive run measures
    # it: docs/planning.md); None: theta_c_deg for every region
    region_theta_c_deg: tuple[float, ...] | None = None
    # each region's own M and diffuse-only need (count unit, the segmentation's order) where the precision
    # asked of it sets them (an adaptive run's re-plan: docs/planning.md); None: min_samples, min_diffuse
    region_min_samples: tuple[float, ...] | None = None
    region_min_diffuse: tuple[float, ...] | None = None
    # each region needs at least this many times the highlight (diffuse-only) samples the taken lights give
    # it, if more than its M (diffuse need): the precision asked of an adaptive run (docs/planning.md); the
    # plan's result holds the needs so resolved in region_min_samples, region_min_diffuse
    highlight_factor: tuple[float, ...] | None = None
    diffuse_factor: tuple[float, ...] | None = None

    def __post_init__(self):
        if not (math.isfinite(self.min_diffuse) and self.min_diffuse >= 0):
            raise InputError(
                f"the diffuse-only samples a region needs must be 0 or more, got {self.min_diffuse}",
                field="--min-diffuse",
            )
        if not (math.isfinite(self.optimum_budget_s) and 0 <= self.optimum_budget_s <= MAX_OPTIMUM_BUDGET_S):
            raise InputError(
                f"the integer programme's budget must be 0 … {MAX_OPTIMUM_BUDGET_S:g} s, got {self.optimum_budget_s}",
                field="--optimum-budget",
            )
        for theta in (self.theta_c_deg, *(self.region_theta_c_deg or ())):
            if not (math.isfinite(theta) and 0 < theta < 90):
                raise InputError(f"θc must lie in (0, 90) degrees, got {theta}", field="--theta-c")
        for m in self.region_min_samples or ():
            if not (math.isfinite(m) and m > 0):
                raise InputError(f"a region's M must be above 0, got {m}", field="region_min_samples")
        for name in ("region_min_diffuse", "highlight_factor", "diffuse_factor"):
            for m in getattr(self, name) or ():
                if not (math.isfinite(m) and m >= 0):
                    raise InputError(f"each region's {name} must be 0 or more, got {m}", field=name)

    def theta_c_rad(self, n_regions: int) -> np.ndarray:
        """(R,) each region's θc in radians."""
        return np.radians(
            _per_region(self.region_theta_c_deg, self.theta_c_deg, n_regions, "region_theta_c_deg", "θc")
        )

    def needed(self, n_regions: int) -> np.ndarray:
        """(R,) the highlight samples each region needs (count unit): its own M, or min_samples."""
        return _per_region(self.region_min_samples, self.min_samples, n_regions, "region_min_samples", "M")

    def diffuse_needed(self, n_regions: int) -> np.ndarray:
        """(R,) the diffuse-only samples each region needs (count unit): its own, or min_diffuse."""
        return _per_region(
            self.region_min_diffuse, self.min_diffuse, n_regions, "region_min_diffuse", "diffuse-only needs"
        )


def _resolved(settings: PlanSettings, given: list[PlannedLight], n_regions: int) -> PlanSettings:
    """``settings`` with each region's needs raised to its factors times what the taken lights ``given``
    give it (:attr:`PlanSettings.highlight_factor`), the factors then dropped: the plan's own needs."""
    if settings.highlight_factor is None and settings.diffuse_factor is None:
        return settings
    had = np.sum([light.expected for light in given], axis=0) + np.zeros(n_regions)
    had_diffuse = np.sum([light.diffuse for light in given], axis=0) + np.zeros(n_regions)
    highlight = _per_region(settings.highlight_factor, 0.0, n_regions, "highlight_factor", "factors")
    diffuse = _per_region(settings.diffuse_factor, 0.0, n_regions, "diffuse_factor", "factors")
    return replace(
        settings,
        region_min_samples=tuple(float(x) for x in np.maximum(settings.needed(n_regions), highlight * had)),
        region_min_diffuse=tuple(
            float(x) for x in np.maximum(settings.diffuse_needed(n_regions), diffuse * had_diffuse)
        ),
        highlight_factor=None,
        diffuse_factor=None,
    )


def _per_region(
    own: tuple[float, ...] | None, default: float, n_regions: int, field: str, what: str
) -> np.ndarray:
    """(R,) float64: ``own`` (one per region) or ``default`` for every region."""
    values = own if own is not None else (default,) * n_regions
    if len(values) != n_regions:
        raise InputError(
            f"{len(values)} regions' {what} given for {n_regions} regions: give one per region", field=field
        )
    return np.asarray(values, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class PlannedLight:
    """One planned light: where it is (world, turntable frame, gantry angles in degrees) and what it gives."""

    step: int  # order in which the greedy chose it
    turntable_deg: float
    light_world: np.ndarray  # (3,)
    azimuth_deg: float  # about S's centre, as the gantry moves
    elevation_deg: float
    light_turntable: np.ndarray  # (3,) in the turntable frame (the placed object at angle 0)
    camera_turntable: np.ndarray  # (3,)
    expected: np.ndarray  # (R,) samples per region, in the count unit
    counted: np.ndarray  # indices into PlanResult.samples of the samples this light counts
    diffuse: np.ndarray  # (R,) diffuse-only samples per region, in the count unit
    # "diffuse": added for regions short of diffuse-only samples; "taken": photographed before the plan was
    # made (given to plan_lights), counted, not chosen
    purpose: Purpose = "highlights"


@dataclass(frozen=True)
class TakenLight:
    """A light already photographed (an adaptive run's pilot): the turntable angle (degrees) and where the
    light stood (3,) (world frame, metres). A plan counts what it gives and plans only what is still needed."""

    turntable_deg: float
    light_world: np.ndarray


@dataclass(frozen=True)
class PlanOptimum:
    """How far the plan can be from the fewest lights for the regions it satisfies.

    ``lower_bound``: no set of the candidates satisfies them with fewer lights (the LP relaxation of the
    set multicover, or the integer programme's proof), on the planner's estimated counts; ``lp_value`` the
    relaxation's optimum (fractional lights); ``proven``: the plan has the fewest lights (on those counts);
    ``chosen_by``: which way of choosing gave the plan ("greedy (capped)", "greedy (plain)", "integer
    programme"); ``status``: how the integer programme ended; ``seconds`` it took with the bound.
    """

    lower_bound: int
    lp_value: float
    proven: bool
    chosen_by: str
    status: str
    seconds: float


@dataclass(frozen=True, eq=False)
class PlanResult:
    """A plan with its coverage per region, the reasons for regions left short, and its timings (s)."""

    settings: PlanSettings
    sphere: LightSphere
    lights: list[PlannedLight]
    coverage: np.ndarray  # (R,) total expected highlight samples
    satisfied: np.ndarray  # (R,) bool: M highlight and min_diffuse diffuse-only samples
    uncovered: dict[int, str]  # region → reason
    lights_by_criterion: dict[str, int]  # light count of this plan's criterion and (if compared) the other
    views_considered: list[float]
    candidates: int  # dense-grid points on S
    reachable: int  # of which the gantry reaches
    samples: SurfaceSamples  # what the counts count (points in the turntable frame)
    optimum: PlanOptimum
    seconds: dict[str, float] = field(default_factory=dict)
    proxy: RayProxy | None = None  # the coarser copy of a scan the plan was made on (planning/proxy.py)

    @property
    def diffuse(self) -> np.ndarray:
        """(R,) total expected diffuse-only samples."""
        return np.sum([light.diffuse for light in self.lights], axis=0) + np.zeros(len(self.coverage))


def given_views(views_deg: Sequence[float], limits_deg: tuple[float, float]) -> list[float]:
    """The turntable angles given (``--views``), each once in the order given (an angle twice would be
    photographed twice for nothing), refused (:class:`InputError`, field ``--views``) when one lies outside
    the rig's turntable ``limits_deg``: a plan the rig cannot run is not written."""
    low, high = limits_deg
    outside = [v for v in views_deg if not low <= v <= high]
    if outside:
        raise InputError(
            f"{outside[0]:g}° is outside the rig's turntable limits [{low:g}, {high:g}]: give angles within them",
            field="--views",
        )
    return list(dict.fromkeys(float(v) for v in views_deg))


def auto_views(limits_deg: tuple[float, float], step_deg: float) -> list[float]:
    """Turntable angles for ``--views auto``: 0 first, then alternating outward by ``step_deg``."""
    lo, hi = limits_deg
    angles = [0.0] if lo <= 0 <= hi else [lo]
    k = 1
    while k * step_deg < 360 - 1e-9:
        for a in (k * step_deg, -k * step_deg):
            wrapped = (a + 180) % 360 - 180
            if lo <= wrapped <= hi and all(abs((wrapped - b + 180) % 360 - 180) > 1e-6 for b in angles):
                angles.append(float(wrapped))
        k += 1
    return angles


class _Candidates:
    """Reachable light directions (world, unit, from S's centre) at the dense and the coarse spacing, and
    which dense points refine each coarse one (its Voronoi cell among the reachable coarse points)."""

    def __init__(self, sphere: LightSphere, rig: Rig, spacing_deg: float, coarse_deg: float):
        self._dense = directions_with_spacing(spacing_deg)  # (total, 3), in order of descending z
        self.total = len(self._dense)
        self._reachable = sphere.reachable(sphere.centre + sphere.radius * self._dense, rig.camera)
        self.fine = self._dense[self._reachable]
        self._fine_index = np.cumsum(self._reachable) - 1  # a dense point's index into fine, if reachable
        self._refines = coarse_deg > spacing_deg
        if self._refines:
            coarse = directions_with_spacing(coarse_deg)
            self.coarse = coarse[sphere.reachable(sphere.centre + sphere.radius * coarse, rig.camera)]
        else:
            self.coarse = self.fine
        self.coarse_tree = KDTree(self.coarse)
        # a cell is looked for within this chord of its coarse point: its farthest member lies ~0.6–0.9
        # coarse spacings away on the lattices planned with (measured)
        self._gather = 2.0 * np.radians(coarse_deg)
        self._cells: np.ndarray | None = None  # every dense point's cell, if a cell ever reached far
        # each cell found, by coarse index: the greedy's runs (capped, plain, the integer programme's cover)
        # and the exact checks ask for the same few dozen cells again (~0.2 ms each)
        self._found: dict[int, np.ndarray] = {}

    def cell(self, coarse_index: int) -> np.ndarray:
        """Indices (ascending) of the dense candidates whose nearest coarse candidate is ``coarse_index``.

        Found among the dense points within two coarse spacings of it (a few hundred, of ~10⁵): a plan
        asks for a few dozen cells. A cell that reaches past 3/4 of that (only where the reachable region
        is thinner than a few coarse spacings) is taken from every dense point's nearest coarse point."""
        if not self._refines:
            return np.array([coarse_index])
        if coarse_index not in self._found:
            self._found[coarse_index] = self._cell(coarse_index)
        return self._found[coarse_index]

    def _cell(self, coarse_index: int) -> np.ndarray:
        """:meth:`cell`, found."""
        if self._cells is not None:
            return np.flatnonzero(self._cells == coarse_index)
        centre, r = self.coarse[coarse_index], self._gather
        band = fibonacci_band(self.total, centre[2] - r, centre[2] + r)  # a run: slices, not copies
        start, stop = band[0], band[-1] + 1
        # unit vectors a, b: |a − b| ≤ r ⟺ a·b ≥ 1 − r²/2
        near = start + np.flatnonzero(
            (self._dense[start:stop] @ centre >= 1 - r * r / 2) & self._reachable[start:stop]
        )
        near = self._fine_index[near]
        # a point within r of the centre has its nearest coarse point within 2r of the centre
        rivals = np.asarray(self.coarse_tree.query_ball_point(centre, 2 * r), dtype=np.int64)
        nearest = rivals[np.argmax(self.fine[near] @ self.coarse[rivals].T, axis=1)]
        members = near[nearest == coarse_index]
        if np.any(self.fine[members] @ centre < 1 - (0.75 * r) ** 2 / 2):
            self._cells = np.asarray(self.coarse_tree.query(self.fine, workers=-1)[1])
            self._found.clear()  # from now on every cell is the whole grid's, as the first asked again
            return np.flatnonzero(self._cells == coarse_index)
        return members


def plan_lights(
    placed: ColouredMesh,
    segmentation: Segmentation,
    rig: Rig,
    settings: PlanSettings = PlanSettings(),
    *,
    caster: RayCaster | None = None,
    taken: Sequence[TakenLight] = (),
) -> PlanResult:
    """Plan on ``placed``, the mesh already in the turntable frame (see ``geometry.placement``).

    A vertex (``count="vertices"``) or surface sample (``"pixels"``) counts for a light when it is visible
    from the camera at that view, not at a grazing angle to camera or light, the light lies in its cone,
    and nothing shadows it from the light.

    The plan is the one with the fewest lights among the greedy's with ``settings.criterion``, the greedy's
    with the other criterion (``compare_criteria``) and the cover the integer programme finds within
    ``optimum_budget_s`` — each without the lights it can do without — that satisfies every region the
    first satisfies. ``PlanResult.optimum`` says how far it can be from the fewest (docs/planning.md).

    ``taken``: lights already photographed; the plan starts with them (purpose "taken", their exact counts)
    and adds lights only for what they leave short (the optimum's figures are of the added lights).

    A mesh far finer than the image (a scan) is planned on its ray proxy (``PlanResult.proxy``,
    :mod:`hlr_lab.planning.proxy`) unless ``caster`` is given, which is then the mesh's own.
    """
    clock = _Clock()
    proxy = None
    if caster is None and settings.count == "pixels":
        proxy = ray_proxy(placed, segmentation, rig.camera)
        if proxy is not None:
            placed, segmentation = proxy.mesh, proxy.segmentation
    clock.lap("proxy")
    planner = _Planner(placed, segmentation, rig, settings, caster, clock, taken)
    given = [planner.taken_light(i, t) for i, t in enumerate(taken)]
    planner.photographed = np.array([light.expected for light in given]).reshape(-1, segmentation.n_regions)
    had = planner.photographed.sum(axis=0)  # (R,)
    # a precision's needs are multiples of what the taken lights give, which only the planner can count
    settings = planner.settings = _resolved(settings, given, segmentation.n_regions)
    needed, diffuse_needed = (
        settings.needed(segmentation.n_regions),
        settings.diffuse_needed(segmentation.n_regions),
    )
    need = np.maximum(needed - had, 0.0)
    planner.estimates_of(0)
    clock.lap("cones")
    capped = settings.criterion == "capped"
    runs = [planner.run(settings.criterion, need, capped=capped)]
    if settings.compare_criteria:
        other: Criterion = "plain" if capped else "capped"
        runs.append(planner.run(other, need, capped=not capped))
    lights_by_criterion = {run.name: len(run.selection.choices) for run in runs}
    clock.lap("greedy")
    best, optimum = planner.fewest_lights(runs, need)
    clock.lap("optimum")

    lights = given + planner.lights(best, first_step=len(given))
    clock.lap("lights")
    lights += planner.add_diffuse(lights)
    clock.lap("diffuse")
    coverage = np.sum([light.expected for light in lights], axis=0) + np.zeros(len(need))
    diffuse = np.sum([light.diffuse for light in lights], axis=0) + np.zeros(len(need))
    highlights_met = coverage >= needed - 1e-9
    diffuse_met = diffuse >= diffuse_needed - 1e-9
    uncovered = planner.reasons(highlights_met, coverage, best.selection, had)
    for r in np.flatnonzero(highlights_met & ~diffuse_met):
        uncovered[int(r)] = (
            f"only {diffuse[r]:.0f} of {diffuse_needed[r]:g} diffuse-only samples (Rd): its lit side "
            "lies within the highlight cones or is shadowed from every reachable light"
        )
    clock.lap("report")
    return PlanResult(
        settings,
        planner.sphere,
        lights,
        coverage,
        highlights_met & diffuse_met,
        uncovered,
        lights_by_criterion,
        planner.views,
        planner.cands.total,
        len(planner.cands.fine),
        planner.surface,
        optimum,
        clock.laps,
        proxy,
    )


@dataclass(frozen=True, eq=False)
class _Run:
    """One way of choosing lights: its name, the choices, and the dense point each chosen coarse candidate
    was refined to ((view, coarse) → dense index)."""

    name: str
    selection: Selection
    refined: dict[tuple[int, int], int]

    @property
    def n_lights(self) -> int:
        return len(self.selection.choices)

    def coverage(self, n_regions: int) -> np.ndarray:
        return np.sum([c.counts for c in self.selection.choices], axis=0) + np.zeros(n_regions)


class _Planner:
    """One planning run's state: the sphere, candidates, samples and the per-view caches."""

    def __init__(
        self,
        placed: ColouredMesh,
        segmentation: Segmentation,
        rig: Rig,
        settings: PlanSettings,
        caster: RayCaster | None,
        clock: _Clock,
        taken: Sequence[TakenLight] = (),
    ):
        self.rig, self.settings = rig, settings
        self.n_regions = segmentation.n_regions
        self.n_taken = len(taken)
        self.photographed = np.zeros((0, self.n_regions))  # (K, R) the taken lights' exact counts
        self.theta_c = settings.theta_c_rad(self.n_regions)  # (R,)
        # the grid and the pools follow the narrowest cone: coarser ones would step over its highlights
        narrowest_deg = float(np.degrees(self.theta_c.min(initial=np.radians(settings.theta_c_deg))))
        self.max_light_angle = np.radians(settings.max_view_angle_deg)
        self.sphere = light_sphere(rig.gantry, placed.vertices, settings.sphere_scale)
        self.caster = caster or RayCaster(placed)
        clock.lap("ray engine")
        self.cands = _Candidates(
            self.sphere, rig, settings.spacing_deg, narrowest_deg * COARSE_FRACTION_OF_THETA_C
        )
        self.views = (
            given_views(settings.views_deg, rig.turntable_limits_deg)
            if settings.views_deg is not None
            else auto_views(rig.turntable_limits_deg, settings.view_step_deg)
        )
        for t in taken:  # a light already photographed counts from the view it was taken in
            if not any(abs(t.turntable_deg - v) < 1e-6 for v in self.views):
                self.views.append(float(t.turntable_deg))
        # exact counts use samples as fine as the count unit needs; the estimates only steer the greedy and
        # bound the plan, and samples of ~ESTIMATE_PX pixels do that at a fraction of the cost (a coarse
        # mesh's vertices would not: one stands for hundreds of pixels, all or none in a cone). Faces no
        # view sees the front of give no samples (one view: half the surface)
        eyes = np.array([rotation_z(np.radians(v))[:3, :3].T @ rig.camera.centre for v in self.views])
        # one side-of-eye test for both samplings (the coarser splits faces only if the finer does)
        split = settings.count == "pixels" and splits_faces(placed, rig.camera)
        towards = faces_towards(placed, eyes) if split else None
        self.surface = surface_samples(placed, segmentation, rig.camera, settings.count, towards=towards)
        self.coarse_surface = (
            surface_samples(
                placed, segmentation, rig.camera, settings.count, target_px=ESTIMATE_PX, towards=towards
            )
            if settings.count == "pixels"
            else self.surface
        )
        if len(self.coarse_surface) >= len(self.surface):
            self.coarse_surface = self.surface
        clock.lap("candidates")
        # (R,) each region's pooling grid follows its own cone: a wide lobe's samples pooled on the
        # narrowest region's grid made many pools, each paired with every candidate in its wide disc (the
        # pebble planned with an adaptive re-plan's cones, 30/12/2.6/4°: 38.5 s, 3.0 s on their own grids)
        self.pool_cell = np.radians(
            np.maximum(settings.spacing_deg, np.degrees(self.theta_c) / POOL_FRACTION)
        )
        self._samples: dict[int, ViewSamples] = {}
        self._coarse_samples: dict[int, ViewSamples] = {}
        self._estimates: dict[int, np.ndarray] = {}
        self._refined: dict[tuple[int, int], tuple[int, np.ndarray]] = {}  # (view, coarse) → (dense, counts)

    def view_samples(self, v: int) -> ViewSamples:
        """The fine samples of view v (exact counts)."""
        if v not in self._samples:
            self._samples[v] = self._samples_of(self.surface, v)
        return self._samples[v]

    def _samples_of(self, surface: SurfaceSamples, v: int) -> ViewSamples:
        return _view_samples(
            surface,
            self.n_regions,
            self.rig,
            self.sphere,
            self.caster,
            self.cands.coarse,
            self.views[v],
            self.settings,
        )

    def coarse_view_samples(self, v: int) -> ViewSamples:
        """The estimates' samples of view v."""
        if self.coarse_surface is self.surface:
            return self.view_samples(v)
        if v not in self._coarse_samples:
            self._coarse_samples[v] = self._samples_of(self.coarse_surface, v)
        return self._coarse_samples[v]

    def estimates_of(self, v: int) -> np.ndarray:
        """(Q, R) estimated counts of view v's coarse candidates."""
        if v not in self._estimates:
            vs = self.coarse_view_samples(v)
            self._estimates[v] = count_estimates(
                vs, self.caster, self.theta_c, self.pool_cell, self.cands.coarse_tree
            )
        return self._estimates[v]

    def evaluate(self, v: int, q: int, need: np.ndarray, capped: bool) -> np.ndarray:
        """Exact counts of coarse candidate q of view v, refined to the best dense point of its cell."""
        if (v, q) not in self._refined:
            vs, cell = self.view_samples(v), self.cands.cell(q)
            if len(cell) == 0:
                return np.zeros(self.n_regions)
            j, counts = best_light(
                vs,
                self.caster,
                vs.light_position(self.cands.fine[cell]),
                self.cands.fine[cell],
                lambda c: score(c, need, capped),
                theta_c=self.theta_c,
                max_light_angle=self.max_light_angle,
                shadows=self.settings.shadows,
            )
            self._refined[v, q] = (int(cell[j]), counts)
        return self._refined[v, q][1]

    def run(
        self,
        name: str,
        need: np.ndarray,
        *,
        capped: bool,
        taken: Sequence[Choice] = (),
    ) -> _Run:
        """The greedy's lights for ``need``, going on from the lights ``taken`` (exact counts)."""
        if not taken:
            self._refined.clear()  # a refinement chosen for one run's needs is not another's
        selection = select_lights(
            self.estimates_of,
            len(self.views),
            lambda v, q, n: self.evaluate(v, q, n, capped),
            need,
            capped=capped,
            max_lights=self.settings.max_lights - self.n_taken,  # the plan's lights, taken ones included
            taken=taken,
            photographed=self.photographed,
        )
        refined = {key: self._refined[key][0] for key in ((c.view, c.candidate) for c in selection.choices)}
        return _Run(name, selection, refined)

    def fewest_lights(self, runs: list[_Run], need: np.ndarray) -> tuple[_Run, PlanOptimum]:
        """The run with the fewest lights (pruned) that satisfies what ``runs[0]`` does, adding the integer
        programme's cover, and what the set multicover says of it."""
        m = need  # (R,) each region's M, less what the lights already taken give it
        runs = [replace(r, selection=prune(r.selection, m)) for r in runs]
        if not (need > 0).any():  # the lights already taken give every region what it needs
            return runs[0], PlanOptimum(0, 0.0, True, f"greedy ({runs[0].name})", "nothing to add", 0.0)
        reference = runs[0].coverage(self.n_regions) >= m - 1e-9

        def rank(r: _Run) -> tuple[int, float]:
            return r.n_lights, -float(np.minimum(r.coverage(self.n_regions), m).sum())

        def acceptable(r: _Run) -> bool:
            return bool(np.all(r.coverage(self.n_regions)[reference] >= m[reference] - 1e-9))

        best = min((r for r in runs if acceptable(r)), key=rank)
        counts = np.concatenate([self.estimates_of(v) for v in range(len(self.views))])  # (V·Q, R)
        found = self._cover(counts, reference, best.n_lights, need)
        if found.cover is not None:
            # the cover's lights as counted exactly (each refined in its cell), completed by the greedy where
            # they fall short (a last round's cover). The greedy choosing again among the cover's candidates,
            # each refined for what was still needed at its step, made 12 lights of the bunny's proven 11
            # counted in vertices (docs/planning.md)
            q = len(self.cands.coarse)
            cover = [divmod(int(j), q) for j in found.cover]
            as_counted = [Choice(v, c, self.evaluate(v, c, need, True)) for v, c in cover]
            finished = self.run(INTEGER_PROGRAMME, need, capped=True, taken=as_counted)
            finished = replace(finished, selection=prune(finished.selection, m))
            if acceptable(finished) and rank(finished) < rank(best):
                best = finished
        proven_fewest = len(found.cover) if found.cover is not None else best.n_lights
        proven = best.n_lights <= found.lower_bound or (found.proven and best.n_lights <= proven_fewest)
        chosen_by = best.name if best.name == INTEGER_PROGRAMME else f"greedy ({best.name})"
        return best, PlanOptimum(
            found.lower_bound, found.lp_value, proven, chosen_by, found.status, found.seconds
        )

    def counted(self, v: int, light_dir: np.ndarray) -> np.ndarray:
        """Indices (into ``surface``) of the samples a light counts."""
        vs = self.view_samples(v)
        local = exact_counts(
            vs,
            self.caster,
            vs.light_position(light_dir),
            light_dir,
            theta_c=self.theta_c,
            max_light_angle=self.max_light_angle,
            shadows=self.settings.shadows,
        )[1]
        return vs.index[local]

    def _cover(
        self, counts: np.ndarray, reference: np.ndarray, incumbent: int, need: np.ndarray
    ) -> CoverOptimum:
        """The set multicover of the regions in ``reference`` over ``counts`` (V·Q, R), the stacked estimates
        of every view's candidates. A cover the estimates promise is checked with exact counts; where they
        fall short its lights' estimates are replaced by their exact counts and the programme solved again
        (as the greedy does light by light), for at most MAX_COVER_ROUNDS rounds — a limit of work, so that
        the plan does not depend on the machine's speed; the time budget only guards the whole. Where no
        round's cover held, the fewest lights among those counted exactly that cover are returned if no more
        than the last round's (:meth:`_exact_cover`), else that last cover, unproven: the greedy completes it
        from there. A covering pair is sought before the programme (``pairs_among``) in the first round
        among all candidates, then among those counted exactly first: the pair search favours the largest
        totals, and once a cover has fallen short those are the suspect estimates (a pair of exact counts
        that covers holds outright)."""
        m, budget = need, self.settings.optimum_budget_s  # m (R,): each region's target
        counts, q, start = counts.copy(), len(self.cands.coarse), time.perf_counter()
        exact = np.zeros(len(counts), bool)
        full = need
        found, holds, seed, target = None, False, None, np.zeros(len(m))
        for round_ in range(MAX_COVER_ROUNDS):
            target = np.where(reference, np.minimum(m, np.minimum(counts, m).sum(axis=0)), 0.0)
            left = max(budget - (time.perf_counter() - start), 0.0)
            found = minimum_cover(counts, target, incumbent, left, pairs_among=None if round_ == 0 else exact)
            if found.cover is None:
                break
            seed = found.cover
            for j in found.cover[~exact[found.cover]]:
                counts[j] = self.evaluate(int(j) // q, int(j) % q, full, True)
                exact[j] = True
            gave = counts[found.cover].sum(axis=0)
            holds = bool(np.all(gave[reference] >= target[reference] - 1e-6))
            if holds or time.perf_counter() - start > budget:
                break
            # the estimates of the regions it fell short on were high: count their best candidates exactly
            # too, or each round would correct a cover's few lights only
            short = reference & (gave < target - 1e-6)
            promise = np.where(exact, -np.inf, np.minimum(counts[:, short], m[short]).sum(axis=1))
            for j in np.argsort(-promise, kind="stable")[:EXACT_PER_ROUND]:
                if np.isfinite(promise[j]):
                    counts[j] = self.evaluate(int(j) // q, int(j) % q, full, True)
                    exact[j] = True
        assert found is not None
        if seed is not None and not holds:  # the rounds ran out checking covers
            guarded = time.perf_counter() - start > budget
            among_exact = (
                None if guarded else self._exact_cover(counts, exact, target, incumbent, budget, start)
            )
            if among_exact is not None and len(among_exact) <= len(seed):
                proven = len(among_exact) <= found.lower_bound
                status = (
                    "optimal" if proven else "a cover among the lights counted exactly; not proven the fewest"
                )
                found = replace(found, cover=among_exact, proven=proven, status=status)
            else:  # the last one still seeds
                status = TIME_GUARD if guarded else "covers of the estimates fell short when counted exactly"
                found = replace(found, cover=seed, proven=False, status=status)
        return replace(found, seconds=time.perf_counter() - start)

    @staticmethod
    def _exact_cover(
        counts: np.ndarray, exact: np.ndarray, target: np.ndarray, incumbent: int, budget: float, start: float
    ) -> np.ndarray | None:
        """Indices (into ``counts`` (V·Q, R)) of the fewest lights among those counted ``exact`` (V·Q,) that
        reach ``target`` (R,) — a cover that holds as found — if fewer than ``incumbent``; else None. The
        rounds' exact checks count a few hundred candidates; where every cover the estimates promised fell
        short, one of these often exists (the pebble with M 250: 4 lights, where the last round's cover
        completed by the greedy took 5)."""
        idx = np.flatnonzero(exact)
        if np.any(np.minimum(counts[idx], target).sum(axis=0) < target - 1e-6):
            return None  # the lights counted exactly do not reach the target together
        left = max(budget - (time.perf_counter() - start), 0.0)
        found = minimum_cover(counts[idx], target, incumbent, left)
        return None if found.cover is None else idx[found.cover]

    def lights(self, run: _Run, first_step: int = 0) -> list[PlannedLight]:
        """The chosen lights, grouped by turntable view (fewer table moves), in greedy order within a view
        (their steps numbered from ``first_step``)."""
        selection = run.selection
        order = sorted(
            range(len(selection.choices)),
            key=lambda i: (selection.views_used.index(selection.choices[i].view), i),
        )
        lights = []
        for i in order:
            c = selection.choices[i]
            lights.append(
                self._planned(
                    first_step + i, c.view, self.cands.fine[run.refined[c.view, c.candidate]], c.counts
                )
            )
        return lights

    def _planned(
        self, step: int, v: int, d: np.ndarray, counts: np.ndarray, purpose: Purpose = "highlights"
    ) -> PlannedLight:
        """The light in world direction ``d`` (3,) from S's centre at view v, with its exact highlight
        ``counts`` (R,) and its diffuse-only samples."""
        az, el = self.rig.gantry.kinematics.direction_angles(d)
        world_from_tt = rotation_z(np.radians(self.views[v]))[:3, :3]
        light = self.view_samples(v).light_position(d)
        return PlannedLight(
            step=step,
            turntable_deg=float(self.views[v]),
            light_world=self.sphere.centre + self.sphere.radius * d,
            azimuth_deg=float(np.degrees(az)),
            elevation_deg=float(np.degrees(el)),
            light_turntable=light,
            camera_turntable=world_from_tt.T @ self.rig.camera.centre,
            expected=counts,
            counted=self.counted(v, d),
            diffuse=self.diffuse(v, light),
            purpose=purpose,
        )

    def diffuse(self, v: int, light: np.ndarray, regions: np.ndarray | None = None) -> np.ndarray:
        """(R,) the diffuse-only samples a light at ``light`` (3,) (view v's frame) gives each region (of
        ``regions`` (R,) bool only, if given): :func:`diffuse_counts_of_light`."""
        return diffuse_counts_of_light(
            self.view_samples(v),
            self.coarse_view_samples(v),
            self.caster,
            light,
            theta_c=self.theta_c,
            max_light_angle=self.max_light_angle,
            shadows=self.settings.shadows,
            min_diffuse=self.settings.diffuse_needed(self.n_regions),
            regions=regions,
        )

    def taken_light(self, step: int, taken: TakenLight) -> PlannedLight:
        """A light already photographed, with its exact counts (its position put on S, as a plan's are)."""
        v = next(i for i, a in enumerate(self.views) if abs(a - taken.turntable_deg) < 1e-6)
        d = np.asarray(taken.light_world, dtype=np.float64) - self.sphere.centre
        d /= np.linalg.norm(d)
        vs = self.view_samples(v)
        counts = exact_counts(
            vs,
            self.caster,
            vs.light_position(d),
            d,
            theta_c=self.theta_c,
            max_light_angle=self.max_light_angle,
            shadows=self.settings.shadows,
        )[0]
        return self._planned(step, v, d, counts, "taken")

    def add_diffuse(self, lights: list[PlannedLight]) -> list[PlannedLight]:
        """Lights added for the regions the highlight lights leave short of ``min_diffuse`` diffuse-only
        samples: each the candidate (every DIFFUSE_SPACING_DEG, every view, the views already used first
        on ties) whose exact diffuse samples serve the short regions best, until none is short or none
        helps; a candidate's estimate (no shadows, the estimates' samples) picks the few counted exactly."""
        need = self.settings.diffuse_needed(self.n_regions) - np.sum([lt.diffuse for lt in lights], axis=0)
        if not (need > 0).any():
            return []
        seen = np.sum([self.view_samples(v).region_weight() for v in range(len(self.views))], axis=0) > 0
        dirs = directions_with_spacing(DIFFUSE_SPACING_DEG)
        dirs = dirs[self.sphere.reachable(self.sphere.centre + self.sphere.radius * dirs, self.rig.camera)]
        used = {lt.turntable_deg for lt in lights}
        added: list[PlannedLight] = []
        while len(lights) + len(added) < self.settings.max_lights and len(dirs):
            short = (need > 0) & seen
            if not short.any():
                break
            options = []  # (estimated gain, view already used, view, candidate)
            for v in range(len(self.views)):
                vs = self.coarse_view_samples(v)
                est = diffuse_estimates(
                    vs,
                    vs.light_position(dirs),
                    theta_c=self.theta_c,
                    max_light_angle=self.max_light_angle,
                    regions=short,
                )
                gain = np.minimum(est, np.maximum(need, 0))[:, short].sum(axis=1)
                for q in np.argsort(-gain, kind="stable")[:DIFFUSE_EXACT_TRIES]:
                    options.append((float(gain[q]), self.views[v] in used, v, int(q)))
            options.sort(key=lambda o: (-o[0], not o[1]))
            best, best_gain = None, MIN_GAIN - 1e-9
            for _, _, v, q in options[:DIFFUSE_EXACT_TRIES]:
                counted = self.diffuse(v, self.view_samples(v).light_position(dirs[q]), regions=short)
                gain = float(np.minimum(counted, np.maximum(need, 0))[short].sum())
                if gain > best_gain:
                    best, best_gain = (v, q), gain
            if best is None:
                break
            v, q = best
            vs = self.view_samples(v)
            counts = exact_counts(
                vs,
                self.caster,
                vs.light_position(dirs[q]),
                dirs[q],
                theta_c=self.theta_c,
                max_light_angle=self.max_light_angle,
                shadows=self.settings.shadows,
            )[0]
            light = self._planned(len(lights) + len(added), v, dirs[q], counts, "diffuse")
            added.append(light)
            used.add(light.turntable_deg)
            need -= light.diffuse
        return added

    def reasons(
        self, satisfied: np.ndarray, coverage: np.ndarray, selection: Selection, had: np.ndarray
    ) -> dict[int, str]:
        """Why each unsatisfied region is short, in the operator's words (this needs every view's evidence;
        ``had`` (R,): what the lights already taken give)."""
        short = np.flatnonzero(~satisfied)
        if len(short) == 0:
            return {}
        views = range(len(self.views))
        seen = np.sum([self.view_samples(v).region_weight() for v in views], axis=0)
        reach = np.sum([self.estimates_of(v).max(axis=0) for v in views], axis=0) + had
        m, reasons = self.settings.needed(self.n_regions), {}
        for r in short:
            if seen[r] <= 0:
                reasons[int(r)] = "not visible from any view (or only at grazing angles)"
            elif reach[r] <= 0:
                reasons[int(r)] = "highlight unreachable: no reachable light position puts a highlight on it"
            elif selection.hit_light_limit:
                limit = self.settings.max_lights
                reasons[int(r)] = f"only {coverage[r]:.0f} of {m[r]:g} samples within --max-lights {limit}"
            else:
                reasons[int(r)] = (
                    f"only {coverage[r]:.0f} of {m[r]:g} samples: no light left gives it enough to be worth a "
                    "photograph (its remaining highlights are shadowed, at grazing light, or a few pixels along "
                    "its border)"
                )
        return reasons


def _view_samples(
    surface: SurfaceSamples,
    n_regions: int,
    rig: Rig,
    sphere: LightSphere,
    caster: RayCaster,
    dirs_world: np.ndarray,
    turntable_deg: float,
    settings: PlanSettings,
) -> ViewSamples:
    """The samples one view may count (facing the camera, not grazing) with their mirror points on S."""
    world_from_tt = rotation_z(np.radians(turntable_deg))[:3, :3]
    camera = rig.camera.in_frame(rotation_z(np.radians(turntable_deg)))
    idx = np.flatnonzero(
        facing(camera, surface.point, surface.normal, max_view_angle_deg=settings.max_view_angle_deg)
    )
    points, normals = surface.point[idx], surface.normal[idx]
    centre_tt = world_from_tt.T @ sphere.centre
    h = mirror_highlights(points, normals, camera.centre, centre_tt, sphere.radius)
    if settings.count == "pixels":
        weight = camera.projected_area_px(points, normals, surface.area[idx])
    else:
        weight = np.ones(len(idx))
    return ViewSamples(
        idx,
        h,
        surface.region[idx],
        weight,
        dirs_world,
        h.footprint @ world_from_tt.T,
        centre_tt,
        sphere.radius,
        world_from_tt.T,
        n_regions,
        camera.centre,
        caster,
    )


class _Clock:
    def __init__(self):
        self.laps: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = now - self._t
        self._t = now
