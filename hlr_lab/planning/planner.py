"""Plan light positions (and turntable views) that give every region at least M highlight samples.

The paper's algorithm (§3.2) with the additions of DESIGN §1, each on by default and reported:
visibility, shadows and grazing angles decide whether a vertex counts; only reachable light positions
are candidates; a region counts only up to what it still needs (the plain count is reported too);
extra turntable views open when a region cannot be served from the first; M counts expected pixels.
All geometry runs in the turntable frame (the placed object at turntable angle 0).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from hlr_lab.mesh import ColouredMesh
from hlr_lab.planning.coverage import ViewSamples, count_estimates, exact_counts
from hlr_lab.planning.geometry import LightSphere, light_sphere, mirror_highlights
from hlr_lab.planning.greedy import Selection, select_lights
from hlr_lab.raycast import RayCaster, visible_vertices
from hlr_lab.rig import Rig
from hlr_lab.segment import Segmentation
from hlr_lab.sphere import azimuth_elevation, directions_with_spacing, rotation_z

CountUnit = Literal["pixels", "vertices"]


@dataclass(frozen=True)
class PlanSettings:
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
    paper_count: bool = True  # also run the paper's plain count, for the summary


@dataclass(frozen=True, eq=False)
class PlannedLight:
    step: int  # order in which the greedy chose it
    turntable_deg: float
    light_world: np.ndarray  # (3,)
    azimuth_deg: float  # about S's centre, as the gantry moves
    elevation_deg: float
    light_turntable: np.ndarray  # (3,) in the turntable frame (the placed object at angle 0)
    camera_turntable: np.ndarray  # (3,)
    expected: np.ndarray  # (R,) samples per region, in the count unit


@dataclass(frozen=True, eq=False)
class PlanResult:
    settings: PlanSettings
    sphere: LightSphere
    lights: list[PlannedLight]
    coverage: np.ndarray  # (R,) total expected samples
    satisfied: np.ndarray  # (R,) bool
    uncovered: dict[int, str]  # region → reason
    lights_paper_count: int | None
    views_considered: list[float]
    candidates: int
    reachable: int
    seconds: dict[str, float] = field(default_factory=dict)


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


def plan_lights(placed: ColouredMesh, segmentation: Segmentation, rig: Rig,
                settings: PlanSettings = PlanSettings(), *, caster: RayCaster | None = None) -> PlanResult:
    """Plan on ``placed``, the mesh already in the turntable frame (see ``geometry.placement``)."""
    clock = _Clock()
    theta_c = np.radians(settings.theta_c_deg)
    sphere = light_sphere(rig.gantry, placed.vertices, settings.sphere_scale)
    caster = caster or RayCaster(placed)
    clock.lap("ray engine")

    dirs_world = directions_with_spacing(settings.spacing_deg)
    reach = sphere.reachable(sphere.centre + sphere.radius * dirs_world, rig.camera)
    dirs_world = dirs_world[reach]
    tree = cKDTree(dirs_world)
    clock.lap("candidates")

    views = list(settings.views_deg) if settings.views_deg is not None else auto_views(
        rig.turntable_limits_deg, settings.view_step_deg)
    n_regions = segmentation.n_regions
    samples: dict[int, ViewSamples] = {}
    bounds_cache: dict[int, np.ndarray] = {}
    cell = max(np.radians(settings.spacing_deg), theta_c / 4)

    def view_samples(v: int) -> ViewSamples:
        if v not in samples:
            samples[v] = _view_samples(placed, segmentation, rig, sphere, caster, dirs_world, views[v], settings)
        return samples[v]

    def bounds_of(v: int) -> np.ndarray:
        if v not in bounds_cache:
            bounds_cache[v] = count_estimates(view_samples(v), caster, theta_c, cell, tree)
        return bounds_cache[v]

    exact_cache: dict[tuple[int, int], np.ndarray] = {}

    def evaluate(v: int, q: int) -> np.ndarray:
        if (v, q) not in exact_cache:
            vs = view_samples(v)
            exact_cache[v, q] = exact_counts(vs, caster, vs.candidates[q], vs.candidate_dirs[q], theta_c=theta_c,
                                             max_light_angle=np.radians(settings.max_view_angle_deg),
                                             shadows=settings.shadows)[0]
        return exact_cache[v, q]

    need = np.full(n_regions, float(settings.min_samples))
    bounds_of(0)
    clock.lap("cones")
    selection = select_lights(bounds_of, len(views), evaluate, need, capped=True, max_lights=settings.max_lights)
    clock.lap("greedy")
    paper = None
    if settings.paper_count:
        paper = len(select_lights(bounds_of, len(views), evaluate, need, capped=False,
                                  max_lights=settings.max_lights).choices)
        clock.lap("paper count")

    lights = _lights(selection, samples, views, sphere, rig)
    coverage = np.sum([light.expected for light in lights], axis=0) if lights else np.zeros(n_regions)
    satisfied = coverage >= settings.min_samples - 1e-9
    uncovered = _reasons(satisfied, coverage, selection, samples, bounds_cache, views, settings, view_samples,
                         bounds_of)
    clock.lap("report")
    return PlanResult(settings, sphere, lights, coverage, satisfied, uncovered, paper, views,
                      len(reach), int(reach.sum()), clock.laps)


def _view_samples(placed, segmentation, rig, sphere, caster, dirs_world, turntable_deg, settings) -> ViewSamples:
    """The samples one view can count: visible, not grazing vertices with their mirror points on S."""
    world_from_tt = rotation_z(np.radians(turntable_deg))
    tt_from_world = world_from_tt.T
    camera = rig.camera.in_frame(world_from_tt)
    visible = visible_vertices(caster, camera, max_view_angle_deg=settings.max_view_angle_deg)
    idx = np.flatnonzero(visible)
    points, normals = placed.vertices[idx], placed.vertex_normals[idx]
    centre_tt = tt_from_world[:3, :3] @ sphere.centre
    h = mirror_highlights(points, normals, camera.centre, centre_tt, sphere.radius)
    if settings.count == "pixels":
        weight = camera.projected_area_px(points, normals, placed.vertex_areas[idx])
    else:
        weight = np.ones(len(idx))
    candidates = centre_tt + sphere.radius * dirs_world @ tt_from_world[:3, :3].T
    return ViewSamples(h, segmentation.vertex_labels[idx], weight, candidates, dirs_world,
                       h.footprint @ world_from_tt[:3, :3].T, sphere.radius, segmentation.n_regions)


def _lights(selection: Selection, samples, views, sphere: LightSphere, rig: Rig) -> list[PlannedLight]:
    order = sorted(range(len(selection.choices)),
                   key=lambda i: (selection.views_used.index(selection.choices[i].view), i))
    lights = []
    for i in order:
        c = selection.choices[i]
        vs = samples[c.view]
        d = vs.candidate_dirs[c.candidate]
        az, el = azimuth_elevation(d)
        world_from_tt = rotation_z(np.radians(views[c.view]))
        lights.append(PlannedLight(
            step=i, turntable_deg=float(views[c.view]), light_world=sphere.centre + sphere.radius * d,
            azimuth_deg=float(np.degrees(az)), elevation_deg=float(np.degrees(el)),
            light_turntable=vs.candidates[c.candidate],
            camera_turntable=world_from_tt[:3, :3].T @ rig.camera.centre, expected=c.counts))
    return lights


def _reasons(satisfied, coverage, selection, samples, bounds_cache, views, settings, view_samples, bounds_of):
    """Why each unsatisfied region is short, in the operator's words."""
    reasons = {}
    short = np.flatnonzero(~satisfied)
    if len(short) == 0:
        return reasons
    for v in range(len(views)):  # the verdict needs every view's evidence
        bounds_of(v)
    seen = np.sum([view_samples(v).region_weight for v in range(len(views))], axis=0)
    reach = np.sum([bounds_cache[v].max(axis=0) for v in range(len(views))], axis=0)
    for r in short:
        if seen[r] <= 0:
            reasons[int(r)] = "not visible from any view (or only at grazing angles)"
        elif reach[r] <= 0:
            reasons[int(r)] = "highlight unreachable: no reachable light position puts a highlight on it"
        elif selection.hit_light_limit:
            reasons[int(r)] = (f"only {coverage[r]:.0f} of {settings.min_samples:g} samples within "
                               f"--max-lights {settings.max_lights}")
        else:
            reasons[int(r)] = (f"only {coverage[r]:.0f} of {settings.min_samples:g} samples: its remaining "
                               "highlights are shadowed or at grazing light")
    return reasons


class _Clock:
    def __init__(self):
        self.laps: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = now - self._t
        self._t = now
