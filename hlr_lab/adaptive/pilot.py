"""The pilot of an adaptive run: the fewest of the plan's own poses that put a highlight on every region
once, and the plan cut to them."""

from __future__ import annotations

import numpy as np

from hlr_lab.formats.plan import PlanFile, RegionCoverage

# a pose shows a region's highlight when it gives it this many samples (the paper's M; M itself when the
# plan asks for fewer), or the most any pose gives it: enough highlight pixels for the fit to tell the
# lobe's width, whatever M the whole plan was made for
PILOT_SAMPLES = 50.0


def pilot_poses(plan: PlanFile) -> list[str]:
    """The ids of the plan's poses the pilot takes, in the plan's order: a set cover of the regions whose
    highlight the plan reaches (greedy: the pose showing most regions not yet shown first, ties to the
    plan's order), a pose showing a region when its expected highlight samples reach
    min(``PILOT_SAMPLES``, M) or the most any pose gives that region. Regions no pose reaches are left to the
    prior θc."""
    if not plan.poses:
        return []
    ids = [str(r.id) for r in plan.object.regions]
    counts = np.array([[p.expected.get(r, 0.0) for r in ids] for p in plan.poses])  # (P, R)
    most = counts.max(axis=0)
    shows = (counts >= np.minimum(min(PILOT_SAMPLES, plan.parameters.min_samples), most)) & (counts > 0)
    todo = most > 0
    chosen: list[int] = []
    while todo.any():
        gain = (shows & todo).sum(axis=1)
        gain[chosen] = -1
        best = int(np.argmax(gain))  # the first of equals: the plan's order
        if gain[best] <= 0:
            break
        chosen.append(best)
        todo &= ~shows[best]
    return [plan.poses[i].id for i in sorted(chosen)]


def cut_to(plan: PlanFile, poses: list[str]) -> PlanFile:
    """``plan`` with only the poses ``poses`` (ids, in the plan's order), its coverage what they give."""
    kept = [p for p in plan.poses if p.id in set(poses)]
    coverage = {}
    for rid, old in plan.coverage.items():
        samples = sum(p.expected.get(rid, 0.0) for p in kept)
        diffuse = sum((p.expected_diffuse or {}).get(rid, 0.0) for p in kept)
        needed = old.needed if old.needed is not None else plan.parameters.min_samples
        diffuse_needed = old.diffuse_needed or 0.0
        coverage[rid] = RegionCoverage(
            samples=round(samples, 1),
            satisfied=samples >= needed and diffuse >= diffuse_needed,  # both, as a plan's coverage says
            needed=old.needed,
            diffuse_samples=round(diffuse, 1),
            diffuse_needed=old.diffuse_needed,
        )
    return plan.model_copy(update={"poses": kept, "coverage": coverage})
