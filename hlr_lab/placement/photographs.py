"""A registration view's photographs → what the placement is compared with: the object's mask.

A view is one turntable angle photographed under four lamp positions (:func:`registration_lamps`: each
lights what the others leave in shadow), each as an exposure bracket. The background
must be darker than the object under the lamp (a dark plate and backdrop, as the rig is built:
docs/placement.md); the object is then the pixels the lamp lights.

* **Radiance**, per lamp: the longest unclipped exposure of each pixel, black level taken off, per second.
* **Mask**: lit in some lamp's photograph (8 read-noise σ) and, within 1 px of the unlit background, at
  least half as bright as the brightest pixel within 1 px — a pixel the object half covers is half as
  bright as its neighbour inside, so the mask's edge is where the object covers half a pixel, whatever
  the object's brightness (a dark region on the silhouette keeps its edge). The largest connected part
  (gaps of a few pixels bridged), its holes filled (a black pupil inside the object is the object).
* **Chromaticity** (r, g) = (R, G)/(R + G + B) under the lamp of the median brightness (the others may
  light a highlight or leave a shadow there): shading changes brightness, not chromaticity, so it tells
  the regions apart by their colour whatever their reflectance — what fixes the turn of a shape whose
  outline does not (``solve.turn_by_colours``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hlr_lab.errors import PlacementError
from hlr_lab.rig.file import Rig

CHROMA_NOISE_SIGMA = 30.0  # a pixel's colour is read where its sum is this many σ up (chroma noise ≲ 3 %)
MASK_NOISE_SIGMA = 8.0  # lit: this many read-noise σ above black (a false pixel per ~10¹⁵)
# px: the neighbourhood whose brightest pixel a half-covered edge pixel is half of. The pixel just inside, not
# one further in: where the shading brightens inward, a 5 px window's brightest overstated the full pixel's
# value and shrank the mask (Spot's outline +0.15 px all round; its vertices 0.044 → 0.029 mm RMS with 3 px)
_HALF_LIT_WINDOW = 3
PLATE_CLEARANCE_M = 0.01  # the side lamps: this far above the lowest the rig lets a lamp go
KEEPOUT_MARGIN_DEG = 3.0  # the lamp above the camera: this far outside the camera's keep-out cone
HIGH_ELEVATION_DEG = 70.0  # the lamp over what faces up


@dataclass(frozen=True, eq=False)
class ViewFrames:
    """One view's photographs: ``frames`` (L, E, H, W, 3) DN for L lamp positions and E exposures
    ``exposures_s`` (E,), at ``turntable_deg``."""

    turntable_deg: float
    frames: np.ndarray
    exposures_s: np.ndarray


@dataclass(frozen=True, eq=False)
class ObservedView:
    """What registration compares one view with: ``mask`` (H, W) bool, the object; ``chroma`` (H, W, 2)
    float32 chromaticity (NaN where too dark to tell, or not measured)."""

    turntable_deg: float
    mask: np.ndarray
    chroma: np.ndarray | None = None


@dataclass(frozen=True)
class Sensor:
    """What the frames need to be read: black level and read noise (DN), the largest value (DN)."""

    black_dn: float
    read_noise_dn: float
    full_scale_dn: float


def registration_lamps(rig: Rig) -> np.ndarray:
    """(4, 2) gantry azimuth and elevation (degrees) of the lamps that light a registration view, in the
    order the gantry visits them (a quarter turn at a time): one beside the object, 90° about the axis from
    the camera, as low as the rig lets the lamp go; one above the camera, just clear of its keep-out cone; one high
    over the camera's side; one on the object's other side. The side lamps light the outline head on (a
    lamp beside the camera meets it at grazing incidence and darkens it); the one above the camera lights
    what faces it, the outline's lower part included; the high one what faces up (a cylinder's top).
    Elevations are kept within the gantry's limits; whether the rig reaches them is checked with the rest
    of the motions."""
    g = rig.gantry
    to_camera = rig.camera.centre - np.asarray(g.centre)
    az, el = (
        float(np.degrees(a)) for a in g.kinematics.direction_angles(to_camera / np.linalg.norm(to_camera))
    )
    lo, hi = np.degrees(g.elevation_limits)
    # the side lamps as low as the gantry may go (a lamp level with the object's lower half lights its outline
    # there head on: pebble rotation error 0.6° with them at +10°, 0.2° at −5°), clear of the plate
    lowest = (g.min_light_height + PLATE_CLEARANCE_M - g.centre[2]) / g.arm_radius
    low = float(np.clip(np.degrees(np.arcsin(np.clip(lowest, -1.0, 1.0))), lo, hi))
    above = float(np.clip(el + np.degrees(g.camera_keepout) + KEEPOUT_MARGIN_DEG, lo, hi))
    high = float(np.clip(HIGH_ELEVATION_DEG, lo, hi))
    lamps = [(az + 90.0, low), (az, above), (az, high), (az - 90.0, low)]
    return np.array([((a + 180.0) % 360.0 - 180.0, e) for a, e in lamps])


def lamp_radiance(
    frames: np.ndarray, exposures_s: np.ndarray, sensor: Sensor
) -> tuple[np.ndarray, np.ndarray]:
    """Per lamp, the radiance (L, H, W, 3) in DN per second from the longest unclipped exposure of each
    pixel, and its noise (L, H, W) (read noise over that exposure). ``frames`` (L, E, H, W, 3) DN."""
    order = np.argsort(exposures_s)[::-1]  # longest first
    clip = sensor.full_scale_dn - 2 * sensor.read_noise_dn - 1
    times = np.asarray(exposures_s, np.float32)[order]  # (E,)
    radiance, noise = [], []
    for bracket in frames:  # (E, H, W, 3) of one lamp: one lamp at a time keeps the temporaries small
        ordered = bracket[order]
        # (E, H, W): the channels' maximum pairwise (numpy's reduction over a last axis of 3: 25× slower)
        unclipped = np.maximum(np.maximum(ordered[..., 0], ordered[..., 1]), ordered[..., 2]) < clip
        # the longest unclipped exposure; the shortest where even that clips (as bright as it gets)
        pick = np.where(unclipped.any(axis=0), np.argmax(unclipped, axis=0), len(order) - 1)  # (H, W)
        chosen = np.take_along_axis(ordered, pick[None, ..., None], axis=0)[0].astype(np.float32)
        t = times[pick][..., None]  # (H, W, 1)
        radiance.append((chosen - np.float32(sensor.black_dn)) / t)
        noise.append(np.float32(sensor.read_noise_dn) / t[..., 0])
    return np.stack(radiance), np.stack(noise)


def observe(view: ViewFrames, sensor: Sensor, *, where: str) -> ObservedView:
    """The mask and chromaticity of one view (module docstring); :class:`PlacementError` naming ``where``
    when nothing or too little is lit, or the object runs off the image."""
    radiance, noise = lamp_radiance(view.frames, view.exposures_s, sensor)
    brightness = radiance.max(axis=3)  # (L, H, W)
    lit = brightness > MASK_NOISE_SIGMA * noise
    signal = np.where(lit, brightness, 0.0).max(axis=0).astype(np.float32)
    size = 2 * (_HALF_LIT_WINDOW // 2) + 1
    window = np.ones((size, size), np.uint8)
    neighbourhood = cv2.dilate(signal, window)
    # the half-bright rule only where the object meets the unlit background: inside, a near surface in
    # front of a brighter far one is no edge of the object (it would cut cracks along occlusions)
    near_background = cv2.dilate((signal <= 0).astype(np.uint8), window) > 0
    raw = (signal > 0) & ~(near_background & (signal < 0.5 * neighbourhood))
    mask = _filled_largest(raw)
    if mask.sum() < 100:
        raise PlacementError(
            f"{where}: the lamp lights almost nothing ({int(mask.sum())} px): is the object on the plate, "
            "in view, and the lamp on?"
        )
    edge = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
    if edge.any():
        raise PlacementError(
            f"{where}: the object runs off the image ({int(edge.sum())} px on its border): it lies too far "
            "from the turntable's centre, or the camera does not see the plate's middle"
        )
    total = radiance.sum(axis=3)  # (L, H, W)
    median = np.argsort(total, axis=0)[len(total) // 2]  # (H, W): the lamp of the median brightness
    pick = np.take_along_axis(radiance, median[None, ..., None], axis=0)[0]  # (H, W, 3)
    pick_total = np.take_along_axis(total, median[None], axis=0)[0]
    pick_noise = np.take_along_axis(noise, median[None], axis=0)[0]
    readable = mask & (pick_total > CHROMA_NOISE_SIGMA * pick_noise)
    chroma = np.full((*mask.shape, 2), np.nan, np.float32)
    chroma[readable] = pick[readable][:, :2] / pick_total[readable, None]
    return ObservedView(view.turntable_deg, mask, chroma)


def _filled_largest(raw: np.ndarray) -> np.ndarray:
    """(H, W) bool: the largest 8-connected part of ``raw`` closed over gaps of up to 4 px, its holes
    filled. The closing keeps the object one part across a dark line a few pixels wide (an edge that no lamp
    lights well would otherwise cut a piece off, and the largest part would lose it); it rounds only
    concave corners tighter than ~2 px."""
    bridged = cv2.morphologyEx(raw.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(bridged, connectivity=8)
    if count <= 1:
        return np.zeros_like(raw)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    part = labels == largest
    # holes: background not reachable from the image's border
    outside = ~part
    _, back, _, _ = cv2.connectedComponentsWithStats(outside.astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([back[0], back[-1], back[:, 0], back[:, -1]]))
    reachable = np.isin(back, border[border > 0])
    return ~reachable
