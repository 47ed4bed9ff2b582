"""Each region's θc from the pilot: the one the fit chose for the lobe it measured on the pilot's
photographs (``theta_c_deg="auto"``: where the fitted lobe falls to a few noise σ, docs/fitting.md), or
the plan's own where the pilot told nothing (and why); and the cone a re-plan counts each region's samples
in."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.formats.plan import PlanFile
from hlr_lab.session.events import RegionThetaC

# The planner's cones are exact up to 30° (its footprint bound, hlr_lab.planning.coverage); a wider lobe
# counts as 30° (fewer samples counted than are there: a plan that errs towards more photographs). Below
# 1° a cone is narrower than two candidate spacings and falls between the candidates.
PLANNING_THETA_C_DEG = (1.0, 30.0)
# Without a precision a re-plan counts a measured region's samples in its lobe's core (:func:`core_deg`),
# or in the plan's own cone where that is no wider than the core and the core within this factor of it: a
# light's samples grow as θc², so the plan then counted each of its lights within 2× of what the core gives
# it, every sample it counted inside the core. Where every lobe so confirms the plan the re-plan is the rest
# of the plan as made: a re-plan from the pilot for the same cones only reshuffles poses chosen together
# (docs/planning.md, "The closed loop")
CONFIRMS_PLAN = 2.0**0.5


@dataclass(frozen=True)
class RegionCone:
    """A region's θc from the pilot (degrees): ``measured`` (``n`` the fitted exponent) or the ``prior``
    (the plan's), with ``reason`` saying why (or, measured, that the fit's θc was held within
    PLANNING_THETA_C_DEG). A re-plan with a precision counts the region's samples in this cone, one without
    in its lobe's core or the plan's (:func:`replan_cones`)."""

    region: int
    theta_c_deg: float
    source: Literal["measured", "prior"]
    n: float | None = None
    reason: str | None = None

    def as_line(self) -> RegionThetaC:
        """The journal's record of it."""
        line = RegionThetaC(theta_c_deg=round(self.theta_c_deg, 3), source=self.source)
        if self.n is not None:
            line["n"] = round(self.n, 3)
        if self.reason is not None:
            line["reason"] = self.reason
        return line


def plan_cones(plan: PlanFile) -> dict[int, float]:
    """Each of ``plan``'s regions' θc (region id → degrees): its own where the plan has one, else the plan's."""
    own = plan.parameters.region_theta_c_deg or {}
    return {r.id: own.get(str(r.id), plan.parameters.theta_c_deg) for r in plan.object.regions}


def core_deg(n: float) -> float:
    """The cone about the mirror direction (degrees, held within PLANNING_THETA_C_DEG) that holds a lobe
    cosⁿβ's core: a light γ from a pixel's mirror direction puts the half vector γ/2 from the normal in the
    plane of incidence, so γ = 2·arccos(2^(−1/n)) reaches the lobe's half maximum. The pixels there tell Rs
    and n apart; the fit's θc (where the lobe meets the noise) reaches further on a bright lobe and less far
    on a dim one (n 1500, Rs 0.05: 2.6–5.0° for a core of 3.5°)."""
    low, high = PLANNING_THETA_C_DEG
    return min(max(2.0 * math.degrees(math.acos(0.5 ** (1.0 / max(n, 1e-6)))), low), high)


def _cores(cones: list[RegionCone]) -> dict[int, float]:
    """Each measured lobe's core (:func:`core_deg`), region id → degrees."""
    return {c.region: core_deg(c.n) for c in cones if c.source == "measured" and c.n is not None}


def _confirms(core: float, plan_deg: float) -> bool:
    """Whether a lobe's ``core`` (degrees) confirms the plan's ``plan_deg`` cone: no narrower than it, and
    within CONFIRMS_PLAN of it."""
    return plan_deg <= core <= CONFIRMS_PLAN * plan_deg


def replan_cones(plan: PlanFile, cones: list[RegionCone]) -> dict[int, float]:
    """θc per region (id → degrees) a re-plan without a precision counts its samples in: a measured lobe's
    core (:func:`core_deg`), or the plan's own where the core confirms it; the plan's where the pilot
    measured no lobe."""
    own, cores = plan_cones(plan), _cores(cones)
    counted = {r: core for r, core in cores.items() if not _confirms(core, own[r])}
    return {c.region: counted.get(c.region, own[c.region]) for c in cones}


def confirmed(plan: PlanFile, cones: list[RegionCone]) -> str | None:
    """Why the pilot confirms ``plan`` — every measured lobe's core no narrower than the plan's θc for its
    region and within CONFIRMS_PLAN of it, and at least one measured — or None."""
    own, cores = plan_cones(plan), _cores(cones)
    if not cores or not all(_confirms(core, own[r]) for r, core in cores.items()):
        return None
    ratios = [core / own[r] for r, core in cores.items()]
    return (
        f"every lobe measured is as the plan assumed (its core {min(ratios):.2f}–{max(ratios):.2f}× the plan's "
        f"θc, within 1–{CONFIRMS_PLAN:.2f}×): the plan's own poses, chosen together for those cones, are the rest"
    )


def region_cones(plan: PlanFile, pilot: MaterialsFile) -> list[RegionCone]:
    """Each of ``plan``'s regions' θc (in the plan's order of regions) from the ``pilot``'s fit."""
    entries = {e.id: e for e in pilot.regions}
    missing = {m.id: m.reason for m in pilot.not_measured}
    priors = plan_cones(plan)
    low, high = PLANNING_THETA_C_DEG
    cones = []
    for region in plan.object.regions:
        prior = priors[region.id]
        e = entries.get(region.id)
        if e is None or e.specular != "measured" or e.n is None:
            why = e.reason if e is not None else missing.get(region.id, "not seen in the pilot's photographs")
            cones.append(RegionCone(region.id, prior, "prior", reason=f"its lobe was not measured: {why}"))
            continue
        held = min(max(e.theta_c_deg, low), high)
        reason = None
        if held != e.theta_c_deg:
            reason = (
                f"the fit's {e.theta_c_deg:.1f}° held at {held:g}° (the planner's cones: {low:g}–{high:g}°)"
            )
        cones.append(RegionCone(region.id, held, "measured", n=e.n, reason=reason))
    return cones
