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


@dataclass(frozen=True)
class RegionCone:
    """A region's θc for the re-plan (degrees): ``measured`` on the pilot (``n`` the fitted exponent) or the
    ``prior`` (the plan's), with ``reason`` saying why (or, measured, that the fit's θc was held within
    PLANNING_THETA_C_DEG)."""

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


def region_cones(plan: PlanFile, pilot: MaterialsFile) -> list[RegionCone]:
    """Each of ``plan``'s regions' θc (in the plan's order of regions) from the ``pilot``'s fit."""
    entries = {e.id: e for e in pilot.regions}
    missing = {m.id: m.reason for m in pilot.not_measured}
    own = plan.parameters.region_theta_c_deg or {}
    low, high = PLANNING_THETA_C_DEG
    cones = []
    for region in plan.object.regions:
        prior = own.get(str(region.id), plan.parameters.theta_c_deg)
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
