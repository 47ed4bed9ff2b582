"""Where the object can appear in a frame: the convex hull of its projected vertices, grown by a margin.

Conservative by construction (the silhouette lies inside the hull of the projected vertices), cheap
(one projection and one polygon fill per turntable angle), and enough for what it is for: telling the
object's pixels from a background that may have bright spots of its own (a lamp reflection on the
gantry, a window) when deciding whether a frame clips.
"""

from __future__ import annotations

import cv2
import numpy as np

from hlr_lab.geometry.camera import Camera
from hlr_lab.geometry.sphere import rotation_z


def object_window(
    camera: Camera, vertices: np.ndarray, turntable_deg: float, *, margin_px: int = 8
) -> np.ndarray:
    """(H, W) bool: True where the object may be seen with the turntable at ``turntable_deg``.

    camera: the rig's camera (world frame); vertices: (N, 3) the object in the turntable frame (m).
    """
    seen_from = camera.in_frame(rotation_z(np.radians(turntable_deg)))
    uv, _ = seen_from.project(vertices)
    uv = uv[np.isfinite(uv).all(axis=1)]  # NaN: behind the camera
    # far-off projections (a point near the camera plane) kept inside int32 with room to spare
    limit = 16 * max(camera.width, camera.height)
    uv = np.clip(uv, -limit, limit)
    window = np.zeros((camera.height, camera.width), np.uint8)
    if len(uv) >= 3:
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(window, hull, 1)
    if margin_px > 0:
        size = 2 * margin_px + 1
        window = cv2.dilate(window, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    return window.astype(bool)


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32: each pixel's distance (px) to the border of ``mask`` (H, W) bool, negative inside,
    zero half a pixel beyond the last pixel in (where a pixel the object half covers has its edge)."""
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(mask, 0.5 - inside, outside - 0.5).astype(np.float32)
