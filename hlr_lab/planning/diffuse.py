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


def _lit_outside_cone(
    view: ViewSamples, which: np.ndarray, lights: np.ndarray, theta_c: np.ndarray, max_light_angle: float
) -> np.ndarray:
    """(m, len(which)) bool: each of m lights (view frame, (m, 3)) lights the samples ``which`` within the
    grazing limit and lies outside their highlight cone (half-angle ``theta_c`` (R,) of their region,
    radians; no occlusion or shadow tested)."""
    h = view.highlights
    to_light = lights[:, None, :] - h.point[which][None]  # (m, n, 3)
    dist = np.linalg.norm(to_light, axis=2)
    cos_light = np.einsum("mnd,nd->mn", to_light, h.normal[which]) / dist
    cos_cone = np.einsum("mnd,nd->mn", to_light, h.mirror[which]) / dist
    return (cos_light >= np.cos(max_light_angle)) & (cos_cone < np.cos(theta_c)[view.region[which]])


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
    which = np.arange(len(view.region))
    if regions is not None:
        which = which[regions[view.region]]
    which = which[view.visible(which)]
    lit = which[_lit_outside_cone(view, which, light[None], theta_c, max_light_angle)[0]]
    if shadows and len(lit):
        h = view.highlights
        lit = lit[~caster.shadowed(h.point[lit], h.normal[lit], light)]
    return np.bincount(view.region[lit], weights=view.weight[lit], minlength=view.n_regions)


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
