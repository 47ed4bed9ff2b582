"""How many highlight samples each candidate light gives each region, in one view.

Two levels, so that planning stays fast on million-vertex meshes yet every count it reports is exact:

* :func:`count_estimates` — for all candidates at once. Samples whose cone axis (the mirror ray) is
  shadowed are dropped (one ray each); the rest are pooled by nearby mirror point, region and
  footprint size, and each pool is tested as one cone (its weighted mean point and axis) against the
  candidates a KD-tree finds near its footprint. Close to the exact count, but only an estimate.
* :func:`exact_counts` — for one light: the exact cone test per sample, grazing light, and a shadow
  ray per sample (Embree). The planner only ever reports exact counts.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from hlr_lab.planning.geometry import Highlights, in_cone
from hlr_lab.raycast import RayCaster

# First-order footprint radius (distance·tanθc/cos incidence) times this covers the exact footprint's
# second-order growth for θc up to 30° (tests compare the exact counts against brute force).
_FOOTPRINT_MARGIN = 1.25
_MIN_COS_INCIDENCE = 0.25
_RADIUS_CLASS = 1.25  # pooled samples' footprint radii differ by at most this factor
_PAIRS_PER_BATCH = 4_000_000  # bounds memory: ~40 bytes a pair while a batch is filtered


@dataclass(frozen=True, eq=False)
class ViewSamples:
    """The countable samples of one view (visible, not grazing vertices), in the turntable frame.

    index (K,) of each sample in the plan's SurfaceSamples; highlights (K samples); region (K,) int;
    weight (K,) in the plan's count unit; candidate_dirs (Q, 3)
    and footprint_dirs (K, 3): unit directions from S's centre of the candidate lights and of the samples'
    mirror points, in the world frame so that one KD-tree of candidates serves every view; S's centre (3,)
    in the view's frame and its radius; view_from_world (3, 3) rotation.
    """

    index: np.ndarray
    highlights: Highlights
    region: np.ndarray
    weight: np.ndarray
    candidate_dirs: np.ndarray
    footprint_dirs: np.ndarray
    sphere_centre: np.ndarray
    sphere_radius: float
    view_from_world: np.ndarray
    n_regions: int

    def light_position(self, dirs_world: np.ndarray) -> np.ndarray:
        """(…, 3) world directions from S's centre → light positions on S in the view's frame."""
        return self.sphere_centre + self.sphere_radius * dirs_world @ self.view_from_world.T

    @cached_property
    def candidates(self) -> np.ndarray:
        """(Q, 3) the candidate light positions in the view's frame."""
        return self.light_position(self.candidate_dirs)

    @property
    def region_weight(self) -> np.ndarray:
        return np.bincount(self.region, weights=self.weight, minlength=self.n_regions)

    def footprint_radius(self, theta_c: float) -> np.ndarray:
        """(K,) chord radius on the unit sphere that contains each sample's cone footprint on S."""
        return self._footprint_scale * np.tan(theta_c)

    @cached_property
    def _footprint_scale(self) -> np.ndarray:
        h = self.highlights
        return _FOOTPRINT_MARGIN * h.distance / np.maximum(h.cos_incidence, _MIN_COS_INCIDENCE) / self.sphere_radius

    @cached_property
    def footprint_tree(self) -> cKDTree:
        return cKDTree(self.footprint_dirs)


def count_estimates(view: ViewSamples, caster: RayCaster, theta_c: float, cell: float,
                    tree: cKDTree | None = None) -> np.ndarray:
    """(Q, R) estimated highlight count of each candidate per region.

    ``cell`` (chord on the unit sphere) is the pooling grid; ``tree`` a KD-tree of candidate_dirs.
    """
    h, q = view.highlights, len(view.candidates)
    estimates = np.zeros(q * view.n_regions)
    if len(view.region) == 0 or q == 0:
        return estimates.reshape(q, view.n_regions)
    tree = tree or cKDTree(view.candidate_dirs)
    lit = ~caster.shadowed(h.point, h.normal, h.point + h.mirror * h.distance[:, None])
    pools = _pool(view, lit, view.footprint_radius(theta_c), cell)
    order = np.argsort(pools.radius)
    density = q / (4 * np.pi)  # candidates per steradian
    cos_c = np.cos(theta_c)
    start = 0
    while start < len(order):
        r_max = pools.radius[order[start]] * _RADIUS_CLASS
        stop = int(np.searchsorted(pools.radius[order], r_max, side="right"))
        per_pool = max(1.0, np.pi * r_max**2 * density)
        stop = max(start + 1, min(stop, start + int(_PAIRS_PER_BATCH / per_pool)))
        batch = order[start:stop]
        pairs = cKDTree(pools.footprint[batch]).sparse_distance_matrix(tree, pools.radius[batch].max(),
                                                                       output_type="ndarray")
        g, cand = batch[pairs["i"]], pairs["j"]
        to_light = view.candidates[cand] - pools.point[g]
        inside = np.einsum("ij,ij->i", to_light, pools.mirror[g]) >= cos_c * np.linalg.norm(to_light, axis=1)
        estimates += np.bincount(cand[inside] * view.n_regions + pools.region[g[inside]],
                                 weights=pools.weight[g[inside]], minlength=len(estimates))
        start = stop
    return estimates.reshape(q, view.n_regions)


@dataclass(frozen=True, eq=False)
class _Pools:
    """Samples pooled into representative cones: point, mirror axis, footprint (P, 3); radius, weight,
    region (P,)."""

    point: np.ndarray
    mirror: np.ndarray
    footprint: np.ndarray
    radius: np.ndarray
    weight: np.ndarray
    region: np.ndarray


def _pool(view: ViewSamples, keep: np.ndarray, radius: np.ndarray, cell: float) -> _Pools:
    h = view.highlights
    idx = np.flatnonzero(keep & (view.weight > 0))
    fp, rad, reg, w = view.footprint_dirs[idx], radius[idx], view.region[idx], view.weight[idx]
    cls = np.floor(np.log(np.maximum(rad, 1e-12)) / np.log(_RADIUS_CLASS)).astype(np.int64)
    keys = np.column_stack([np.floor(fp / cell).astype(np.int64), reg, cls])
    _, group, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    group, n = group.ravel(), len(counts)

    def mean(a: np.ndarray) -> np.ndarray:
        out = np.zeros((n, a.shape[1]))
        np.add.at(out, group, a * w[:, None])
        return out / np.bincount(group, weights=w, minlength=n)[:, None]

    mirror, footprint = mean(h.mirror[idx]), mean(fp)
    mirror /= np.linalg.norm(mirror, axis=1, keepdims=True)
    footprint /= np.linalg.norm(footprint, axis=1, keepdims=True)
    reach = np.linalg.norm(fp - footprint[group], axis=1) + rad  # the pool's disc holds every footprint
    disc = np.zeros(n)
    np.maximum.at(disc, group, reach)
    region = np.zeros(n, np.int64)
    region[group] = reg
    return _Pools(mean(h.point[idx]), mirror, footprint, disc, np.bincount(group, weights=w, minlength=n), region)


def exact_counts(view: ViewSamples, caster: RayCaster, light: np.ndarray, light_dir: np.ndarray, *,
                 theta_c: float, max_light_angle: float, shadows: bool) -> tuple[np.ndarray, np.ndarray]:
    """Exact highlight counts per region (R,) for one light position (3,) (view frame; ``light_dir`` its
    world direction from S's centre), and the indices of the counted samples.

    A sample counts when the light is inside its cone, lights it at less than ``max_light_angle`` from
    the normal, and (with ``shadows``) reaches it unobstructed.
    """
    h = view.highlights
    radius = view.footprint_radius(theta_c)
    near = np.asarray(view.footprint_tree.query_ball_point(light_dir, radius.max() if len(radius) else 0.0),
                      dtype=np.int64)
    near = near[np.linalg.norm(view.footprint_dirs[near] - light_dir, axis=1) <= radius[near]]
    sub = Highlights(h.point[near], h.normal[near], h.mirror[near], h.distance[near], h.footprint[near],
                     h.cos_incidence[near])
    inside = in_cone(sub, light, theta_c)
    to_light = light - sub.point
    cos_light = np.einsum("ij,ij->i", sub.normal, to_light) / np.linalg.norm(to_light, axis=1)
    counted = near[inside & (cos_light >= np.cos(max_light_angle))]
    if shadows and len(counted):
        counted = counted[~caster.shadowed(h.point[counted], h.normal[counted], light)]
    counts = np.bincount(view.region[counted], weights=view.weight[counted], minlength=view.n_regions)
    return counts, np.sort(counted)
