"""Each region's samples for the re-plan from the precision asked of it: the standard errors of the
photographs so far (the pilot's, then each round's), scaled to the samples that would bring them down to
it (docs/planning.md, "A precision asked").

A standard error falls as one over the square root of the pixels behind it, so a region whose fit
states Rs to ±s % needs (s / p)² times the highlight samples it has for ±p %; its Rd likewise from its
diffuse-only samples. The factors are applied by the planner to the photographs' own counts under the
re-plan's cones (``PlanSettings.highlight_factor``), so that they are counted as every plan counts; the
re-plan never asks a region for less than the plan did.

Where the law stops holding the next round sees it: a region whose pixels grew since the last round and
whose standard error did not follow is asked for nothing more (a small region's error counts its few
surface patches, which more photographs of the same surface do not add to).
"""

from __future__ import annotations

import math
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
# A region whose pixels grew by at least GREW× since the last round, and whose standard error fell by less
# than HELD of the square-root law's fall (on a log scale: 0.5 is a quarter-power law, where the law gives
# a half), is limited by something photographs do not add to: a small region's few surface patches, whose
# shared misses the standard error counts (docs/fitting.md, "Standard errors: pixels and patches")
GREW, HELD = 1.5, 0.5


@dataclass(frozen=True)
class RegionNeed:
    """A region's samples for the re-plan, as multiples of what the photographs so far gave it:
    ``highlight_factor`` (for Rs and n) and ``diffuse_factor`` (Rd), each (s / p)² for their fit's largest
    relative standard error s (``*_se_pct``, None where it was not measured: factor 0, the plan's own
    samples) and the precision p asked, at most MAX_FACTOR; ``*_pixels`` the fit's pixels behind each
    standard error; ``reason`` why a factor is 0 or held at MAX_FACTOR."""

    region: int
    highlight_factor: float
    diffuse_factor: float
    highlight_se_pct: float | None = None
    diffuse_se_pct: float | None = None
    reason: str | None = None
    highlight_pixels: int | None = None
    diffuse_pixels: int | None = None

    def as_line(self) -> RegionNeedLine:
        """The journal's record of it."""
        line = RegionNeedLine(
            highlight_factor=round(self.highlight_factor, 4), diffuse_factor=round(self.diffuse_factor, 4)
        )
        if self.highlight_se_pct is not None:
            line["highlight_se_pct"] = round(self.highlight_se_pct, 4)
        if self.diffuse_se_pct is not None:
            line["diffuse_se_pct"] = round(self.diffuse_se_pct, 4)
        if self.highlight_pixels is not None:
            line["highlight_pixels"] = self.highlight_pixels
        if self.diffuse_pixels is not None:
            line["diffuse_pixels"] = self.diffuse_pixels
        if self.reason is not None:
            line["reason"] = self.reason
        return line


def region_needs(
    plan: PlanFile,
    fitted: MaterialsFile,
    precision_pct: float,
    previous: dict[int, RegionNeed] | None = None,
) -> list[RegionNeed]:
    """Each of ``plan``'s regions' factors (in the plan's order of regions) for a standard error of at most
    ``precision_pct`` per cent of its Rd, Rs and n, from the ``fitted`` photographs so far; ``previous``
    (region id → need), the last round's, says where more pixels stopped helping (factor 0 then)."""
    entries = {e.id: e for e in fitted.regions}
    before = previous or {}
    needs = []
    for region in plan.object.regions:
        e = entries.get(region.id)
        if e is None:
            needs.append(RegionNeed(region.id, 0.0, 0.0, reason="not fitted: the plan's own samples"))
            continue
        last = before.get(region.id) or RegionNeed(region.id, 0.0, 0.0)  # no earlier round to compare with
        rd_se, px = _rd_se_pct(e), e.pixels
        diffuse, why_d = _asked(
            "Rd", rd_se, px.diffuse, last.diffuse_se_pct, last.diffuse_pixels, precision_pct
        )
        if e.specular != "measured" or e.rs is None or e.rs_se is None or e.n is None or e.n_se is None:
            why = _joined("its highlight was not measured: the plan's own highlight samples", why_d)
            needs.append(RegionNeed(region.id, 0.0, diffuse, diffuse_se_pct=rd_se, diffuse_pixels=px.diffuse,
                                    reason=why))  # fmt: skip
            continue
        rs, rs_se = np.asarray(e.rs), np.asarray(e.rs_se)
        lobe_se = max(float(np.max(100 * rs_se / np.maximum(rs, DARK_RD))), 100 * e.n_se / e.n)
        highlight, why_h = _asked("Rs, n", lobe_se, px.highlight, last.highlight_se_pct, last.highlight_pixels,
                                  precision_pct)  # fmt: skip
        needs.append(RegionNeed(region.id, highlight, diffuse, lobe_se, rd_se, _joined(why_h, why_d),
                                px.highlight, px.diffuse))  # fmt: skip
    return needs


def _asked(
    what: str,
    se_pct: float,
    pixels: int,
    se_before: float | None,
    pixels_before: int | None,
    precision_pct: float,
) -> tuple[float, str | None]:
    """``what``'s factor for ``precision_pct`` from its standard error ``se_pct`` (per cent, from ``pixels``),
    and why it is 0 — its error stopped following its pixels since the last round's ``se_before`` from
    ``pixels_before`` — or held at MAX_FACTOR; None for a factor as the square-root law gives it."""
    factor = _factor(se_pct, precision_pct)
    if factor > 1 and (held := _stopped_helping(what, se_before, pixels_before, se_pct, pixels)):
        return 0.0, held
    return factor, _capped(what, se_pct, precision_pct)


def _factor(se_pct: float, precision_pct: float) -> float:
    """The samples' multiple that brings ``se_pct`` down to ``precision_pct``, at most MAX_FACTOR."""
    return min((se_pct / precision_pct) ** 2, MAX_FACTOR)


def _capped(what: str, se_pct: float, precision_pct: float) -> str | None:
    """That the precision is out of reach this round when ``what``'s ``se_pct`` needs more than MAX_FACTOR,
    or None."""
    if (se_pct / precision_pct) ** 2 <= MAX_FACTOR:
        return None
    reach = se_pct / MAX_FACTOR**0.5
    return (
        f"{what} ±{se_pct:.2g} % so far: at most {MAX_FACTOR:g}× its samples asked, for about ±{reach:.2g} %"
    )


def _stopped_helping(
    what: str, se_before: float | None, pixels_before: int | None, se_pct: float, pixels: int
) -> str | None:
    """Why more samples would not bring ``what``'s standard error down (``se_pct`` from ``pixels``, against
    ``se_before`` from ``pixels_before`` a round earlier): its pixels grew GREW× or more and it fell by
    less than HELD of the square-root law's fall; or None."""
    if not se_before or not pixels_before or pixels < GREW * pixels_before:
        return None
    grew = pixels / pixels_before
    if math.log(se_before / se_pct) >= HELD * 0.5 * math.log(grew):
        return None
    return (
        f"its {what} standard error went ±{se_before:.2g} → ±{se_pct:.2g} % while its pixels grew {grew:.1f}×: "
        "more photographs of the same surface no longer shrink it (its few surface patches limit it), "
        "no more samples asked"
    )


def _joined(*whys: str | None) -> str | None:
    """The reasons given, in one sentence; None without any."""
    given = [w for w in whys if w]
    return "; ".join(dict.fromkeys(given)) or None


def _rd_se_pct(e: MaterialEntry) -> float:
    """The largest of Rd's channels' standard errors, per cent of the channel (of DARK_RD below it)."""
    rd, se = np.asarray(e.rd), np.asarray(e.rd_se)
    return float(np.max(100 * se / np.maximum(rd, DARK_RD)))
