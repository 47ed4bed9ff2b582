"""Benchmarks that print figures (not timed unit tests): ``hlr-lab bench plan``.

Each case runs in a fresh process so that its peak memory is its own.
"""

from __future__ import annotations

import multiprocessing
import os
import resource
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from hlr_lab.mesh import ColouredMesh, load_mesh
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, plan_lights
from hlr_lab.procedural import paint_patches, pebble
from hlr_lab.raycast import RayCaster, visible_vertices
from hlr_lab.rig import Rig, sim_rig
from hlr_lab.segment import segment

PAPER_REGIONS = 8
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
    v, f = mesh.vertices, mesh.faces
    while len(v) < min_vertices:
        v, f = trimesh.remesh.subdivide(v, f)
    return ColouredMesh(v, f)


@dataclass
class PlanFigures:
    case: str
    vertices: int
    regions: int
    lights: int
    lights_plain: int
    uncovered: int
    plan_s: float
    stages: dict[str, float]
    rss_before_mb: float
    rss_peak_plan_mb: float


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
    if min_vertices:
        base = subdivided(base, min_vertices)
    painted = paper_41_object(base, rig, up=up, scale=scale)
    seg = segment(painted)
    rss = _PeakRss()
    before = rss._rss()
    with rss:
        t = time.perf_counter()
        result = plan_lights(painted, seg, rig, PAPER_SETTINGS)
        elapsed = time.perf_counter() - t
    return PlanFigures(
        case,
        len(painted.vertices),
        seg.n_regions,
        len(result.lights),
        result.lights_by_criterion.get("plain", -1),
        len(result.uncovered),
        elapsed,
        result.seconds,
        before / 2**20,
        rss.peak / 2**20,
    )


def run_plan_case(*args) -> PlanFigures:
    """Run one case in a fresh process (spawned: no memory inherited from this one)."""
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        return pool.apply(_plan_case, args)


def max_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def mesh_label(mesh_path: str | None) -> str:
    return Path(mesh_path).stem if mesh_path else "builtin:pebble"


def nearest_neighbour_spacing_deg(directions: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(directions).query(directions, k=2)
    return float(np.degrees(2 * np.arcsin(d[:, 1].max() / 2)))
