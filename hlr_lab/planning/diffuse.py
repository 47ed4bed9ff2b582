"""Diffuse-only samples: what each pose gives a region's Rd.

Rd is fitted from pixels outside every highlight (β > θc). A sample of a view counts as diffuse-only
for a light when the camera sees it (facing, not grazing, unoccluded), the light reaches it at less than
the grazing limit from its normal and unshadowed, and the light lies *outside* its highlight cone. Counted
in the plan's unit, as the highlight samples are (docs/planning.md).
"""

from __future__ import annotations

import numpy as np

from hlr_lab.object.raycast import RayCaster
from hlr_lab.planning.coverage import ViewSamples

_CANDIDATES_PER_BATCH = 8  # lights × samples × 3 floats at a time: ~20 MB on 100 000 samples
# A region given at least this many diffuse-only pixels by a light (and twice what --min-diffuse asks) is
# counted on the estimates' ~16 px samples: within 2 % of the ~2 px samples' count there (at most 1.7 % on
# bench plan's cases), at an eighth of the shadow rays. Fewer are counted on the fine samples: a small count
# moves by several per cent with the samples' size (37 px came out 34, 337 px 346), and decides a light.
COARSE_COUNT_FROM_PX = 500.0


def _lit_outside_cone(
    view: ViewSamples,
    which: np.ndarray | None,
    lights: np.ndarray,
    theta_c: np.ndarray,
    max_light_angle: float,
) -> np.ndarray:
    """(m, n) bool: each of m lights (view frame, (m, 3)) lights the samples ``which`` (n,) (None: all)
    within the grazing limit and lies outside their highlight cone (half-angle ``theta_c`` (R,) of their
    region, radians; no occlusion or shadow tested)."""
    cos_cone, cos_light = view.towards(lights, which)  # (n, m) each
    region = view.region if which is None else view.region[which]
    outside = cos_cone < np.cos(theta_c)[region, None]
    return ((cos_light >= np.cos(max_light_angle)) & outside).T


def diffuse_counts(
    view: ViewSamples,
    caster: RayCaster,
    light: np.ndarray,
    *,
    theta_c: np.ndarray,
    max_light_angle: float,
    shadows: bool,
    regions: np.ndarray | None = None,
) -> np.ndarray:
    """(R,) exact diffuse-only samples per region (the plan's unit) one light (3,) (view frame) gives;
    ``regions`` (R,) bool limits the work to those regions (the others count 0)."""
    which = None if regions is None else np.flatnonzero(regions[view.region])
    lit = np.flatnonzero(_lit_outside_cone(view, which, light[None], theta_c, max_light_angle)[0])
    lit = lit if which is None else which[lit]
    lit = lit[view.visible(lit)]  # rays last: the light reaches about half the samples the camera faces
    if shadows and len(lit):
        h = view.highlights
        lit = lit[~caster.shadowed(h.point[lit], h.normal[lit], light)]
    return np.bincount(view.region[lit], weights=view.weight[lit], minlength=view.n_regions)


def diffuse_counts_of_light(
    fine: ViewSamples,
    coarse: ViewSamples,
    caster: RayCaster,
    light: np.ndarray,
    *,
    theta_c: np.ndarray,
    max_light_angle: float,
    shadows: bool,
    min_diffuse: float | np.ndarray,
    regions: np.ndarray | None = None,
) -> np.ndarray:
    """(R,) diffuse-only samples per region one light (3,) (the view's frame) gives: :func:`diffuse_counts`
    on the ``coarse`` samples of the view, and again on its ``fine`` ones for each region that came out
    under ``max(COARSE_COUNT_FROM_PX, 2 min_diffuse)`` there (``min_diffuse`` a float or (R,) each
    region's); ``regions`` (R,) bool as in
    :func:`diffuse_counts`. Above that, the count cannot decide whether the region has ``min_diffuse``."""

    def count(view: ViewSamples, which: np.ndarray | None) -> np.ndarray:
        return diffuse_counts(
            view,
            caster,
            light,
            theta_c=theta_c,
            max_light_angle=max_light_angle,
            shadows=shadows,
            regions=which,
        )

    counts = count(coarse, regions)
    if coarse is fine:
        return counts
    recount = counts < np.maximum(COARSE_COUNT_FROM_PX, 2 * np.asarray(min_diffuse))
    if regions is not None:
        recount &= regions
    if recount.any():
        counts[recount] = count(fine, recount)[recount]
    return counts


def diffuse_estimates(
    view: ViewSamples, lights: np.ndarray, *, theta_c: np.ndarray, max_light_angle: float, regions: np.ndarray
) -> np.ndarray:
    """(m, R) diffuse-only samples per region each of m lights (m, 3) (view frame) would give, without
    shadows (an upper bound of :func:`diffuse_counts`), for the regions in ``regions`` (R,) bool only."""
    which = np.arange(len(view.region))
    which = which[regions[view.region]]
    which = which[view.visible(which)]
    out = np.zeros((len(lights), view.n_regions))
    onehot = np.zeros((len(which), view.n_regions))
    onehot[np.arange(len(which)), view.region[which]] = view.weight[which]
    for start in range(0, len(lights), _CANDIDATES_PER_BATCH):
        batch = lights[start : start + _CANDIDATES_PER_BATCH]
        out[start : start + len(batch)] = (
            _lit_outside_cone(view, which, batch, theta_c, max_light_angle) @ onehot
        )
    return out
