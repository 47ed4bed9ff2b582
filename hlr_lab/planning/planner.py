"""Plan light positions (and turntable views) that give every region at least M highlight samples.

The paper's algorithm (§3.2) with these additions, each on by default and reported:
visibility, shadows and grazing angles decide whether a sample counts; only reachable light positions
are candidates; a region counts only up to what it still needs (the plain count is reported too);
extra turntable views open when a region cannot be served from the first; M counts expected pixels.

Candidates come at two densities: estimates for the greedy are computed on a coarse grid (θc/5), and
evaluating a coarse candidate exactly refines it over the dense grid (≤ ``spacing_deg``) points in its
Voronoi cell — the lights of a plan are always dense-grid points with exact counts.
All geometry runs in the turntable frame (the placed object at turntable angle 0).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import KDTree

from hlr_lab.errors import InputError
from hlr_lab.geometry.sphere import directions_with_spacing, rotation_z
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import RayCaster, facing
from hlr_lab.object.segment import Segmentation
from hlr_lab.planning.coverage import ViewSamples, best_light, count_estimates, exact_counts
from hlr_lab.planning.geometry import LightSphere, light_sphere, mirror_highlights
from hlr_lab.planning.greedy import Selection, score, select_lights
from hlr_lab.planning.samples import SurfaceSamples, surface_samples, vertex_samples
from hlr_lab.rig.file import Rig

CountUnit = Literal["pixels", "vertices"]
Criterion = Literal["capped", "plain"]
COARSE_FRACTION_OF_THETA_C = 0.2  # estimate grid spacing = θc/5: five points across a cone's radius
POOL_FRACTION = 4.0  # pool samples whose mirror points lie within θc/4 into one estimate cone


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
    compare_criteria: bool = True  # also plan with the other criterion, for the summary


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


@dataclass(frozen=True, eq=False)
class PlanResult:
    """A plan with its coverage per region, the reasons for regions left short, and its timings (s)."""

    settings: PlanSettings
    sphere: LightSphere
    lights: list[PlannedLight]
    coverage: np.ndarray  # (R,) total expected samples
    satisfied: np.ndarray  # (R,) bool
    uncovered: dict[int, str]  # region → reason
    lights_by_criterion: dict[str, int]  # light count of this plan's criterion and (if compared) the other
    views_considered: list[float]
    candidates: int  # dense-grid points on S
    reachable: int  # of which the gantry reaches
    samples: SurfaceSamples  # what the counts count (points in the turntable frame)
    seconds: dict[str, float] = field(default_factory=dict)


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
    which dense points refine each coarse one (its Voronoi cell)."""

    def __init__(self, sphere: LightSphere, rig: Rig, spacing_deg: float, coarse_deg: float):
        def reachable(spacing: float) -> tuple[np.ndarray, int]:
            d = directions_with_spacing(spacing)
            return d[sphere.reachable(sphere.centre + sphere.radius * d, rig.camera)], len(d)

        self.fine, self.total = reachable(spacing_deg)
        self.coarse = reachable(coarse_deg)[0] if coarse_deg > spacing_deg else self.fine
        self.coarse_tree = KDTree(self.coarse)
        owner = (
            np.asarray(self.coarse_tree.query(self.fine)[1]) if len(self.coarse) else np.zeros(0, np.int64)
        )
        self._order = np.argsort(owner, kind="stable")
        self._start = np.searchsorted(owner[self._order], np.arange(len(self.coarse) + 1))

    def cell(self, coarse_index: int) -> np.ndarray:
        """Indices of the dense candidates whose nearest coarse candidate is ``coarse_index``."""
        return self._order[self._start[coarse_index] : self._start[coarse_index + 1]]


def plan_lights(
    placed: ColouredMesh,
    segmentation: Segmentation,
    rig: Rig,
    settings: PlanSettings = PlanSettings(),
    *,
    caster: RayCaster | None = None,
) -> PlanResult:
    """Plan on ``placed``, the mesh already in the turntable frame (see ``geometry.placement``).

    A vertex (``count="vertices"``) or surface sample (``"pixels"``) counts for a light when it is visible
    from the camera at that view, not at a grazing angle to camera or light, the light lies in its cone,
    and nothing shadows it from the light.
    """
    clock = _Clock()
    planner = _Planner(placed, segmentation, rig, settings, caster, clock)
    need = np.full(segmentation.n_regions, float(settings.min_samples))
    planner.estimates_of(0)
    clock.lap("cones")
    capped = settings.criterion == "capped"
    lights_by_criterion = {}
    if settings.compare_criteria:
        other = "plain" if capped else "capped"
        lights_by_criterion[other] = len(planner.select(need, capped=not capped).choices)
        clock.lap("other criterion")
    selection = planner.select(need, capped=capped)
    lights_by_criterion[settings.criterion] = len(selection.choices)
    clock.lap("greedy")

    lights = planner.lights(selection)
    coverage = np.sum([light.expected for light in lights], axis=0) if lights else np.zeros(len(need))
    satisfied = coverage >= settings.min_samples - 1e-9
    uncovered = planner.reasons(satisfied, coverage, selection)
    clock.lap("report")
    return PlanResult(
        settings,
        planner.sphere,
        lights,
        coverage,
        satisfied,
        uncovered,
        lights_by_criterion,
        planner.views,
        planner.cands.total,
        len(planner.cands.fine),
        planner.surface,
        clock.laps,
    )


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
    ):
        self.rig, self.settings = rig, settings
        self.n_regions = segmentation.n_regions
        self.theta_c = np.radians(settings.theta_c_deg)
        self.max_light_angle = np.radians(settings.max_view_angle_deg)
        self.sphere = light_sphere(rig.gantry, placed.vertices, settings.sphere_scale)
        self.caster = caster or RayCaster(placed)
        clock.lap("ray engine")
        self.cands = _Candidates(
            self.sphere, rig, settings.spacing_deg, settings.theta_c_deg * COARSE_FRACTION_OF_THETA_C
        )
        # exact counts use samples as fine as the count unit needs; the greedy's estimates only steer, and
        # the vertices (weighted in the same unit) do that at a fraction of the cost on a coarse mesh
        self.surface = surface_samples(placed, segmentation, rig.camera, settings.count)
        self.coarse_surface = (
            vertex_samples(placed, segmentation) if len(self.surface) > len(placed.vertices) else self.surface
        )
        clock.lap("candidates")
        self.views = (
            given_views(settings.views_deg, rig.turntable_limits_deg)
            if settings.views_deg is not None
            else auto_views(rig.turntable_limits_deg, settings.view_step_deg)
        )
        self.pool_cell = np.radians(max(settings.spacing_deg, settings.theta_c_deg / POOL_FRACTION))
        self._samples: dict[int, ViewSamples] = {}
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

    def estimates_of(self, v: int) -> np.ndarray:
        """(Q, R) estimated counts of view v's coarse candidates."""
        if v not in self._estimates:
            vs = (
                self.view_samples(v)
                if self.coarse_surface is self.surface
                else self._samples_of(self.coarse_surface, v)
            )
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

    def select(self, need: np.ndarray, *, capped: bool) -> Selection:
        self._refined.clear()  # a refinement chosen under one criterion's needs is not the other's
        return select_lights(
            self.estimates_of,
            len(self.views),
            lambda v, q, n: self.evaluate(v, q, n, capped),
            need,
            capped=capped,
            max_lights=self.settings.max_lights,
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

    def lights(self, selection: Selection) -> list[PlannedLight]:
        """The chosen lights, grouped by turntable view (fewer table moves), in greedy order within a view."""
        order = sorted(
            range(len(selection.choices)),
            key=lambda i: (selection.views_used.index(selection.choices[i].view), i),
        )
        lights = []
        for i in order:
            c = selection.choices[i]
            d = self.cands.fine[self._refined[c.view, c.candidate][0]]
            az, el = self.rig.gantry.kinematics.direction_angles(d)
            world_from_tt = rotation_z(np.radians(self.views[c.view]))[:3, :3]
            lights.append(
                PlannedLight(
                    step=i,
                    turntable_deg=float(self.views[c.view]),
                    light_world=self.sphere.centre + self.sphere.radius * d,
                    azimuth_deg=float(np.degrees(az)),
                    elevation_deg=float(np.degrees(el)),
                    light_turntable=self.view_samples(c.view).light_position(d),
                    camera_turntable=world_from_tt.T @ self.rig.camera.centre,
                    expected=c.counts,
                    counted=self.counted(c.view, d),
                )
            )
        return lights

    def reasons(self, satisfied: np.ndarray, coverage: np.ndarray, selection: Selection) -> dict[int, str]:
        """Why each unsatisfied region is short, in the operator's words (this needs every view's evidence)."""
        short = np.flatnonzero(~satisfied)
        if len(short) == 0:
            return {}
        views = range(len(self.views))
        seen = np.sum([self.view_samples(v).region_weight() for v in views], axis=0)
        reach = np.sum([self.estimates_of(v).max(axis=0) for v in views], axis=0)
        m, reasons = self.settings.min_samples, {}
        for r in short:
            if seen[r] <= 0:
                reasons[int(r)] = "not visible from any view (or only at grazing angles)"
            elif reach[r] <= 0:
                reasons[int(r)] = "highlight unreachable: no reachable light position puts a highlight on it"
            elif selection.hit_light_limit:
                limit = self.settings.max_lights
                reasons[int(r)] = f"only {coverage[r]:.0f} of {m:g} samples within --max-lights {limit}"
            else:
                reasons[int(r)] = (
                    f"only {coverage[r]:.0f} of {m:g} samples: its remaining highlights are "
                    "shadowed or at grazing light"
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
