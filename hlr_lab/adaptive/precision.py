"""Each region's samples for the re-plan from the precision asked of it: the pilot's standard errors,
scaled to the samples that would bring them down to it (docs/planning.md, "A precision asked").

A standard error falls as one over the square root of the pixels behind it, so a region whose pilot
states Rs to ±s % needs (s / p)² times the highlight samples the pilot gave it for ±p %; its Rd likewise
from its diffuse-only samples. The factors are applied by the planner to the pilot's own counts under the
re-plan's cones (``PlanSettings.highlight_factor``), so that they are counted as every plan counts; the
re-plan never asks a region for less than the plan did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.formats.materials import MaterialEntry, MaterialsFile
from hlr_lab.formats.plan import PlanFile
from hlr_lab.session.events import RegionNeedLine

# No region is asked for more than this many times its pilot's samples (its standard error a quarter of the
# pilot's). Further the square-root law is extrapolated too far to trust (a small region's error counts its
# few surface patches, and a dim lobe's θc comes from the pilot's few pixels), and a region asked for
# hundreds of times its samples takes every light the greedy has for itself: on the built-in pebble with
# four dim n = 1500 lobes, uncapped factors of 57–950 gave 61 added lights to one region and none to the
# other three (docs/planning.md, "A precision asked").
MAX_FACTOR = 16.0
# Rd (or Rs) below this is held to an absolute precision (p % of it) rather than a relative one: a
# near-black channel's relative error grows without bound as it darkens, and no number of photographs
# would meet it
DARK_RD = 0.02


@dataclass(frozen=True)
class RegionNeed:
    """A region's samples for the re-plan, as multiples of what the pilot gave it: ``highlight_factor`` (for
    Rs and n) and ``diffuse_factor`` (Rd), each (s / p)² for the pilot's largest relative standard error s
    (``*_se_pct``, None where the pilot did not measure it: factor 0, the plan's own samples) and the
    precision p asked, at most MAX_FACTOR; ``reason`` why a factor is 0 or held at MAX_FACTOR."""

    region: int
    highlight_factor: float
    diffuse_factor: float
    highlight_se_pct: float | None = None
    diffuse_se_pct: float | None = None
    reason: str | None = None

    def as_line(self) -> RegionNeedLine:
        """The journal's record of it."""
        line = RegionNeedLine(
            highlight_factor=round(self.highlight_factor, 4), diffuse_factor=round(self.diffuse_factor, 4)
        )
        if self.highlight_se_pct is not None:
            line["highlight_se_pct"] = round(self.highlight_se_pct, 4)
        if self.diffuse_se_pct is not None:
            line["diffuse_se_pct"] = round(self.diffuse_se_pct, 4)
        if self.reason is not None:
            line["reason"] = self.reason
        return line


def region_needs(plan: PlanFile, pilot: MaterialsFile, precision_pct: float) -> list[RegionNeed]:
    """Each of ``plan``'s regions' factors (in the plan's order of regions) for a standard error of at most
    ``precision_pct`` per cent of its Rd, Rs and n, from the ``pilot``'s fit of the same regions."""
    entries = {e.id: e for e in pilot.regions}
    needs = []
    for region in plan.object.regions:
        e = entries.get(region.id)
        if e is None:
            needs.append(
                RegionNeed(region.id, 0.0, 0.0, reason="not fitted on the pilot: the plan's own samples")
            )
            continue
        rd_se = _rd_se_pct(e)
        diffuse = _factor(rd_se, precision_pct)
        if e.specular != "measured" or e.rs is None or e.rs_se is None or e.n is None or e.n_se is None:
            why = "its highlight was not measured on the pilot: the plan's own highlight samples"
            needs.append(
                RegionNeed(
                    region.id, 0.0, diffuse, diffuse_se_pct=rd_se, reason=_capped(why, rd_se, precision_pct)
                )
            )
            continue
        rs, rs_se = np.asarray(e.rs), np.asarray(e.rs_se)
        lobe_se = max(float(np.max(100 * rs_se / np.maximum(rs, DARK_RD))), 100 * e.n_se / e.n)
        why = _capped(None, max(lobe_se, rd_se), precision_pct)
        needs.append(RegionNeed(region.id, _factor(lobe_se, precision_pct), diffuse, lobe_se, rd_se, why))
    return needs


def _factor(se_pct: float, precision_pct: float) -> float:
    """The samples' multiple that brings ``se_pct`` down to ``precision_pct``, at most MAX_FACTOR."""
    return min((se_pct / precision_pct) ** 2, MAX_FACTOR)


def _capped(why: str | None, se_pct: float, precision_pct: float) -> str | None:
    """``why``, and that the precision is out of reach when ``se_pct`` needs more than MAX_FACTOR."""
    if (se_pct / precision_pct) ** 2 <= MAX_FACTOR:
        return why
    reach = se_pct / MAX_FACTOR**0.5
    cap = f"±{se_pct:.2g} % on the pilot: at most {MAX_FACTOR:g}× its samples asked, for about ±{reach:.2g} %"
    return cap if why is None else f"{why}; {cap}"


def _rd_se_pct(e: MaterialEntry) -> float:
    """The largest of Rd's channels' standard errors, per cent of the channel (of DARK_RD below it)."""
    rd, se = np.asarray(e.rd), np.asarray(e.rd_se)
    return float(np.max(100 * se / np.maximum(rd, DARK_RD)))
