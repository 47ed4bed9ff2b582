"""Is the object where the fit believes it? A per-pose check of the photograph against the placed mesh
(docs/placement.md, "Checked in every fit").

A misplaced object leaves its mark where the mesh's geometry changes fastest: along its silhouette (the
photographed object runs past the predicted outline on one side and stops short of it on the other) and
along its colour regions' borders (a band of one region's colour inside the neighbour's predicted pixels).
Both are measured on each pose's own photograph:

* **Outline** (px): the photographed object's |signed distance| at the predicted outline's pixels, median, where
  the object there is lit head-on enough to be told from the dark background (cos α ≥ 0.3, its region
  bright above the noise).
* **Borders** (share): of the pixels 2–8 px inside a region from its border with another, the share whose
  chromaticity is nearest another region's (each region's chromaticity: the median of its pixels away from
  every border, in this photograph).

Neither is zero for a placed object (quantised edges, highlights, shading at a border), so each is measured
also for the prediction moved by every shift up to :data:`SEARCH_PX` pixels: a placed object fits best
where it is; a misplaced one fits clearly better moved (by :data:`MOVED_PX` or more), or — misplaced by
far more than a shift can mimic (turned, centimetres off) — its outline fits no shift, and the pose is
flagged, with what to do: register.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hlr_lab.geometry.silhouette import signed_distance

SEARCH_PX = 10  # the prediction is moved by every whole-pixel shift up to this, each way
SHIFTS = [(dy, dx) for dy in range(-SEARCH_PX, SEARCH_PX + 1) for dx in range(-SEARCH_PX, SEARCH_PX + 1)]
# a photograph that fits best moved this far from the prediction … (a placed pebble: 1–2 px, the edge's
# half-covered pixels counted in the photograph, not in the prediction; 2.5 mm off: 5–9 px)
MOVED_PX = 3.0
OUTLINE_GAIN = 1.5  # … with its outline misfit this many times lower there (pebble 2.5 mm off: 5–13×),
# … or this share fewer border pixels coloured as the neighbour (a placed pebble: ≤ 0.005; turned 3°: 0.036
# and 0.045; 2.5 mm off: 0.06 and 0.08): flagged
BORDER_GAIN = 0.03
# an outline that no shift fits within this (px, median) is far from where the plan says (a placed object's
# fits within 0.5 px at its best shift; the bunny turned 200° and 14 mm off: 20 px at best in two poses)
GROSS_OUTLINE_PX = 2.0
BAND_PX = (2.0, 8.0)  # the border band: past the mixed pixels, within a misplacement's reach
HEAD_ON = 0.3  # cos α at the outline pixels used: a grazing-lit edge is too dark to tell from the background
CLEAR_SIGMA = 8.0  # the photographed object: radiance this many noise σ above black
MIN_POINTS = 50  # fewer outline pixels or border pixels than this: that measure says nothing


@dataclass(frozen=True)
class Misfit:
    """A measure of misfit for the prediction where it is (``at_zero``) and moved by the shift that fits
    best (``best``, at ``shift_px``: dx, dy)."""

    at_zero: float
    best: float
    shift_px: tuple[int, int]

    @classmethod
    def of(cls, cost: np.ndarray) -> Misfit:
        """From the misfit (len(SHIFTS),) at every shift of :data:`SHIFTS`."""
        k = int(np.argmin(cost))
        dy, dx = SHIFTS[k]
        return cls(float(cost[SHIFTS.index((0, 0))]), float(cost[k]), (dx, dy))

    @property
    def moved(self) -> bool:
        return float(np.hypot(*self.shift_px)) >= MOVED_PX


@dataclass(frozen=True)
class PoseAlignment:
    """One pose's check: the outline's misfit (median px) over ``outline_points`` pixels and the borders'
    (share of band pixels coloured as the neighbour) over ``border_pixels``, each where the prediction is
    and at its best shift; None where too few pixels could be used."""

    pose: str
    outline: Misfit | None
    outline_points: int
    borders: Misfit | None
    border_pixels: int

    @property
    def flagged(self) -> bool:
        """The photograph fits the prediction clearly better moved (:data:`MOVED_PX`) than where it is, or its
        outline fits no shift of it (:data:`GROSS_OUTLINE_PX`)."""
        o, b = self.outline, self.borders
        return bool(
            (o is not None and o.moved and o.at_zero >= OUTLINE_GAIN * o.best and o.at_zero - o.best >= 0.5)
            or (o is not None and o.best > GROSS_OUTLINE_PX)
            or (b is not None and b.moved and b.at_zero - b.best >= BORDER_GAIN)
        )

    def as_record(self) -> dict:
        """The pose's line in ``fit-diagnostics.json``'s ``alignment.poses``."""
        out: dict = {"pose": self.pose, "flagged": self.flagged}
        for name, m, count in (("outline", self.outline, self.outline_points),
                               ("borders", self.borders, self.border_pixels)):  # fmt: skip
            out[name] = {"pixels": count} | (_misfit_record(m) if m is not None else {})
        return out


def _misfit_record(m: Misfit) -> dict:
    return {"misfit": round(m.at_zero, 4), "best_misfit": round(m.best, 4), "best_shift_px": list(m.shift_px)}


def pose_alignment(
    pose: str,
    labels: np.ndarray,
    cos_alpha: np.ndarray,
    radiance: np.ndarray,
    usable: np.ndarray,
    noise: float,
) -> PoseAlignment:
    """The check of one pose.

    Parameters
    ----------
    labels
        (H, W) int: the region the placed mesh shows at each pixel, −1 off the object.
    cos_alpha
        (H, W) float: cos α where the pixel's point is lit (not in shadow), 0 elsewhere.
    radiance, usable
        (H, W, 3) the pose's radiance (NaN where not usable) and (H, W) bool where it is usable.
    noise
        The radiance of one read-noise σ in the pose's longest exposure.
    """
    total = np.where(usable, np.nansum(radiance, axis=2), 0.0)
    predicted = labels >= 0
    # regions bright enough here that their lit edge cannot be lost in the background
    bright = np.zeros(labels.shape, bool)
    for rid in np.unique(labels[predicted]):
        own = (labels == rid) & (cos_alpha >= HEAD_ON) & usable
        if own.any() and np.median(total[own]) > 10 * CLEAR_SIGMA * noise:
            bright |= labels == rid
    edge = predicted & ~cv2.erode(predicted.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    ys, xs = np.nonzero(edge & bright & (cos_alpha >= HEAD_ON))
    sdf = np.clip(signed_distance(total > CLEAR_SIGMA * noise), -2.0 * SEARCH_PX, 2.0 * SEARCH_PX)
    outline = None
    if len(ys) >= MIN_POINTS:
        # the outline's misfit for the prediction moved by each shift: the median of the photographed object's
        # |signed distance| at the moved outline pixels (a median: something else lit beside the object — a
        # white reference on the plate — touches a part of the outline without moving the whole)
        cost = np.array([np.median(np.abs(_at(sdf, ys + dy, xs + dx))) for dy, dx in SHIFTS])
        outline = Misfit.of(cost)
    borders, judged = _border_misfit(labels, radiance, usable & (cos_alpha >= HEAD_ON) & bright)
    return PoseAlignment(pose, outline, len(ys), borders, judged)


def _at(image: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    return image[np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)]


def _border_misfit(labels: np.ndarray, radiance: np.ndarray, good: np.ndarray) -> tuple[Misfit | None, int]:
    """How the regions' borders fit the photograph: the share of border-band pixels whose photographed
    colour is not their predicted region's, for the prediction moved by each shift; and how many pixels."""
    predicted = labels >= 0
    regions = [int(r) for r in np.unique(labels[predicted])]
    with np.errstate(invalid="ignore", divide="ignore"):
        chroma = radiance[..., :2] / np.nansum(radiance, axis=2, keepdims=True)  # (H, W, 2)
    good = good & np.isfinite(chroma).all(axis=2)
    boundary = np.zeros(labels.shape, bool)  # both pixels of every change of label (off the object too)
    boundary[:, 1:] |= labels[:, 1:] != labels[:, :-1]
    boundary[:, :-1] |= labels[:, 1:] != labels[:, :-1]
    boundary[1:] |= labels[1:] != labels[:-1]
    boundary[:-1] |= labels[1:] != labels[:-1]
    depth = cv2.distanceTransform((~boundary).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    references, spreads, ids = [], [], []
    for rid in regions:
        inside = (labels == rid) & good & (depth > BAND_PX[1])
        if inside.sum() >= MIN_POINTS:
            reference = np.median(chroma[inside], axis=0)
            references.append(reference)
            spreads.append(float(np.median(np.linalg.norm(chroma[inside] - reference, axis=1))))
            ids.append(rid)
    if len(ids) < 2:
        return None, 0
    references_a = np.array(references)  # (R, 2)
    # regions of nearly one chromaticity (greys of two lightnesses) are one colour here: a pixel is judged
    # by which colour it has, not which of those regions
    apart = np.linalg.norm(references_a[:, None] - references_a[None], axis=2)
    same = apart < 4 * (np.array(spreads)[:, None] + np.array(spreads)[None])
    colour_of = {rid: int(np.argmax(same[k])) for k, rid in enumerate(ids)}
    if len(set(colour_of.values())) < 2:
        return None, 0
    nearest = np.full(labels.shape, -1, np.int64)
    d = np.linalg.norm(chroma[good][:, None, :] - references_a[None], axis=2)  # (N, R)
    nearest[good] = np.array([colour_of[ids[k]] for k in range(len(ids))])[np.argmin(d, axis=1)]
    band = good & (depth > BAND_PX[0]) & (depth <= BAND_PX[1]) & np.isin(labels, ids)
    ys, xs = np.nonzero(band)
    if len(ys) < MIN_POINTS:
        return None, len(ys)
    want = np.array([colour_of[int(r)] for r in labels[ys, xs]])
    cost = np.array([np.mean(_at(nearest, ys + dy, xs + dx) != want) for dy, dx in SHIFTS])
    return Misfit.of(cost), len(ys)
