"""Each region's θc for the re-plan: the one the fit chose for the lobe it measured on the pilot's
photographs (``theta_c_deg="auto"``: where the fitted lobe falls to a few noise σ, docs/fitting.md), or
the plan's own where the pilot told nothing (and why)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.formats.plan import PlanFile
from hlr_lab.session.events import RegionThetaC

# The planner's cones are exact up to 30° (its footprint bound, hlr_lab.planning.coverage); a wider lobe
# counts as 30° (fewer samples counted than are there: a plan that errs towards more photographs). Below
# 1° a cone is narrower than two candidate spacings and falls between the candidates.
PLANNING_THETA_C_DEG = (1.0, 30.0)
# A measured cone within this factor of the plan's confirms it for its region: a light's samples grow as
# θc², so the plan counted each of its lights within 2× of what the measured cone gives it. Without a
# precision the re-plan keeps such a region's cone (M samples in the cone the plan promised them in: on
# the bunny with n 8/40/400 in turn, the n 400 regions' stated σ Rs/n 0.46/0.64 % → 0.28/0.29 % for the
# same 3 photographs), and where every lobe confirms the plan it is the rest of the plan as made: a re-plan
# from the pilot for the same cones only reshuffles poses chosen together (docs/planning.md)
CONFIRMS_PLAN = 2.0**0.5


@dataclass(frozen=True)
class RegionCone:
    """A region's θc from the pilot (degrees): ``measured`` (``n`` the fitted exponent) or the ``prior``
    (the plan's), with ``reason`` saying why (or, measured, that the fit's θc was held within
    PLANNING_THETA_C_DEG). Without a precision a re-plan counts the region's samples in the plan's θc where
    this one confirms it (:func:`replan_cones`)."""

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


def prior_cones(plan: PlanFile) -> dict[int, float]:
    """Each of ``plan``'s regions' θc (region id → degrees): its own where the plan has one, else the plan's."""
    own = plan.parameters.region_theta_c_deg or {}
    return {r.id: own.get(str(r.id), plan.parameters.theta_c_deg) for r in plan.object.regions}


def _confirms(cone: RegionCone, prior_deg: float) -> bool:
    """Whether ``cone`` was measured within CONFIRMS_PLAN of ``prior_deg``, the plan's θc for its region."""
    return cone.source == "measured" and 1 / CONFIRMS_PLAN <= cone.theta_c_deg / prior_deg <= CONFIRMS_PLAN


def replan_cones(plan: PlanFile, cones: list[RegionCone]) -> dict[int, float]:
    """θc per region (id → degrees) a re-plan without a precision counts its samples in: the plan's own
    where the measured one confirms it (within CONFIRMS_PLAN), else the one in ``cones``."""
    prior = prior_cones(plan)
    return {c.region: prior[c.region] if _confirms(c, prior[c.region]) else c.theta_c_deg for c in cones}


def confirmed(plan: PlanFile, cones: list[RegionCone]) -> str | None:
    """Why the pilot confirms ``plan`` — every measured cone within CONFIRMS_PLAN of the plan's θc for its
    region, and at least one measured — or None where some lobe is wider or narrower than that."""
    prior = prior_cones(plan)
    measured = [c for c in cones if c.source == "measured"]
    ratios = [c.theta_c_deg / prior[c.region] for c in measured]
    if not measured or not all(_confirms(c, prior[c.region]) for c in measured):
        return None
    return (
        f"every lobe measured is as the plan assumed (θc {min(ratios):.2f}–{max(ratios):.2f}× the plan's, within "
        f"{CONFIRMS_PLAN:.2f}×): the plan's own poses, chosen together for those cones, are the rest"
    )


def region_cones(plan: PlanFile, pilot: MaterialsFile) -> list[RegionCone]:
    """Each of ``plan``'s regions' θc (in the plan's order of regions) from the ``pilot``'s fit."""
    entries = {e.id: e for e in pilot.regions}
    missing = {m.id: m.reason for m in pilot.not_measured}
    priors = prior_cones(plan)
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
