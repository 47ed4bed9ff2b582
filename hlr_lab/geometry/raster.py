"""Triangles rasterised at once: the pixels whose centres they cover, found for many small triangles in a few
vectorised steps rather than a drawing call each (a scan's millions of faces are millions of calls).

Coordinates are fixed point, 1/16 px (OpenCV's ``shift=4``), so the covering test is exact integer arithmetic:
a pixel centre on an edge two triangles share is covered by both, and a watertight mesh's triangles cover
every pixel centre inside its outline — what a ray cast through each pixel centre sees.
"""

from __future__ import annotations

import cv2
import numpy as np

SUBPIXEL_BITS = 4  # fixed point: 1/16 px, as OpenCV's drawing functions' ``shift``
ONE_PX = 1 << SUBPIXEL_BITS
# triangles whose corners' pixels lie within these many pixels of each other, in each direction, are tested
# against every pixel centre of that box at once, a class at a time ((span + 1)² centres each); wider ones are
# few (a coarse mesh's largest faces) and go to OpenCV, a call each
SPANS = (2, 4, 8, 16)
_CENTRES_PER_STEP = 1 << 22  # a step tests this many (triangle, centre) pairs: ~130 MB of temporaries


def corner_pixels(fixed: np.ndarray) -> np.ndarray:
    """(..., 2) int: the pixel (column, row) each fixed-point point ``fixed`` (..., 2) lies in."""
    return (fixed + ONE_PX // 2) >> SUBPIXEL_BITS


def fill_triangles(mask: np.ndarray, triangles: np.ndarray) -> None:
    """Set in ``mask`` (H, W) uint8 every pixel whose centre lies in (or on the edge of) one of ``triangles``
    (T, 3, 2) int, fixed-point (column, row) corners (1/16 px). Triangles wider than the largest of
    :data:`SPANS` are filled by OpenCV (which sets a few pixels along their edges whose centres lie just
    outside). Degenerate triangles (no area) cover nothing."""
    if not len(triangles):
        return
    t = triangles.astype(np.int64)
    pixel = corner_pixels(t)  # (T, 3, 2)
    low = pixel.min(axis=1)  # (T, 2)
    spread = (pixel.max(axis=1) - low).max(axis=1)  # (T,)
    smaller = -1
    for span in SPANS:
        which = np.flatnonzero((spread > smaller) & (spread <= span))
        smaller = span
        step = max(1, _CENTRES_PER_STEP // (span + 1) ** 2)
        for start in range(0, len(which), step):
            chosen = which[start : start + step]
            _cover(mask, t[chosen], low[chosen], span)
    for triangle in triangles[spread > SPANS[-1]]:
        cv2.fillConvexPoly(mask, triangle.astype(np.int32), 1, lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)


def _cover(mask: np.ndarray, t: np.ndarray, low: np.ndarray, span: int) -> None:
    """Set the pixels of ``mask`` whose centres lie in the triangles ``t`` (B, 3, 2) fixed point, each within
    the (span + 1)² pixels from ``low`` (B, 2)."""
    grid = np.arange(span + 1, dtype=np.int32)
    cx, cy = (g.ravel() << SUBPIXEL_BITS for g in np.meshgrid(grid, grid, indexing="xy"))  # (K,) the centres
    # the corners relative to the box's first pixel centre: a few hundred sixteenths, so int32 products are exact
    r = (t - (low[:, None, :] << SUBPIXEL_BITS)).astype(np.int32)  # (B, 3, 2)
    inside_all = np.ones((len(t), len(cx)), bool)  # (B, K) on the inner side of every edge so far
    inside_none = np.ones_like(inside_all)  # on the outer side (the triangle wound the other way)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        dx, dy = r[:, b, 0] - r[:, a, 0], r[:, b, 1] - r[:, a, 1]  # (B,)
        offset = dy * r[:, a, 0] - dx * r[:, a, 1]
        # twice the signed area of (a, b, centre): dx (cy − ay) − dy (cx − ax)
        side = dx[:, None] * cy[None] - dy[:, None] * cx[None] + offset[:, None]  # (B, K)
        inside_all &= side >= 0
        inside_none &= side <= 0
    area = (r[:, 1, 0] - r[:, 0, 0]) * (r[:, 2, 1] - r[:, 0, 1]) - (r[:, 1, 1] - r[:, 0, 1]) * (
        r[:, 2, 0] - r[:, 0, 0]
    )
    which, k = np.nonzero((inside_all | inside_none) & (area != 0)[:, None])
    col = low[which, 0] + (cx[k] >> SUBPIXEL_BITS)
    row = low[which, 1] + (cy[k] >> SUBPIXEL_BITS)
    h, w = mask.shape
    seen = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    mask[row[seen], col[seen]] = 1
