"""A registration's photographs with what it found, as one self-contained HTML page (``summary.html`` in
the photographs' folder; docs/placement.md): each view lit by all its lamps, the registered mesh's outline
drawn over it (green) and its colour regions' borders (yellow), the view's outline residual; above them,
where the object was found, how certain that is, and how far from where the plan assumed it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from hlr_lab.files import atomic_write_text
from hlr_lab.formats.plan import PlacementRecord, PlanFile
from hlr_lab.formats.planned_object import surface_regions
from hlr_lab.object.raycast import RayCaster
from hlr_lab.placement.photographs import lamp_radiance
from hlr_lab.registration.measure import Measured
from hlr_lab.registration.views import Photographs
from hlr_lab.report.html import escape, figure, page, table, tone_map

SUMMARY = "summary.html"
THUMB_WIDTH = 560  # px of a view in the page
OUTLINE_RGB, BORDER_RGB = (40, 230, 40), (250, 220, 40)


def write_summary(
    measured: Measured, photographs: Photographs, plan: PlanFile, record: PlacementRecord, folder: Path
) -> Path:
    """Write ``folder``/summary.html for ``measured`` (the views of ``photographs``, the regions of ``plan``)."""
    found = measured.found
    outlines = measured.outlines
    per_view = outlines.view_residuals_px(found.params, found.outline_offset_px)
    caster = RayCaster(measured.mesh)
    figures, rows = [], []
    for k, (view, frames) in enumerate(zip(measured.observed, photographs.views, strict=True)):
        radiance, _ = lamp_radiance(frames.frames, frames.exposures_s, photographs.sensor)
        lit = radiance.sum(axis=0)  # (H, W, 3): every lamp at once
        scale = THUMB_WIDTH / lit.shape[1]
        thumb = tone_map(
            cv2.resize(lit, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA),
            max(float(np.percentile(lit[view.mask], 99)), 1e-12),
        )
        labels = _regions_seen(measured, plan, caster, k, thumb.shape[:2], scale)
        borders = (labels != np.roll(labels, 1, axis=0)) | (labels != np.roll(labels, 1, axis=1))
        thumb[borders & (labels >= 0)] = BORDER_RGB
        predicted = outlines.predicted_mask(k, found.mesh_to_turntable).astype(np.uint8)
        contours, _ = cv2.findContours(predicted, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(thumb, [np.round(c * scale).astype(np.int32) for c in contours], -1, OUTLINE_RGB, 1,
                         cv2.LINE_AA)  # fmt: skip
        caption = f"turntable {view.turntable_deg:g}°: outline {per_view[k]:.2f} px RMS"
        figures.append(figure(thumb, caption))
        rows.append([f"{view.turntable_deg:g}", f"{per_view[k]:.2f}", f"{int(view.mask.sum())}"])
    se_shift = record.se_shift_mm or [0.0, 0.0, 0.0]
    se_rot = record.se_rotation_deg or [0.0, 0.0, 0.0]
    facts = [
        ["status", escape(record.status + (f": {record.why}" if record.why else ""))],
        ["method", escape(record.method)],
        ["offset from the plan's placement",
         escape(f"shift {_mm(record.offset_shift_mm)} mm, turn {record.offset_turn_deg:.2f}° about the axis, "
                f"tilt {record.offset_tilt_deg:.2f}°")],
        ["standard errors", escape(f"shift {_mm(se_shift)} mm, rotation {_mm(se_rot, '.3f')}°")],
        ["outline", escape(f"{record.residual_px:.2f} px RMS, {100 * (record.outline_seen or 0):.1f} % of it "
                           f"found on the photographs, {record.outline_offset_px or 0.0:+.2f} px outside the "
                           "mesh's all round")],
    ]  # fmt: skip
    body = (
        table(["", ""], facts, numeric_from=2)
        + "<p class='note'>Each view lit by all the registration lamps; green: the registered mesh's outline, "
        "yellow: its colour regions' borders. Where they miss the photograph's, the placement (or the mesh) "
        "is wrong there.</p>"
        + "".join(figures)
        + table(["turntable (°)", "outline RMS (px)", "object (px)"], rows)
    )
    path = folder / SUMMARY
    atomic_write_text(path, page("Registration: where the object lies", body))
    return path


def _regions_seen(
    measured: Measured, plan: PlanFile, caster: RayCaster, k: int, shape: tuple[int, int], scale: float
) -> np.ndarray:
    """(h, w) region id seen at each thumbnail pixel (−1: none), the mesh lying where it was found."""
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w]
    pixels = (np.stack([xs.ravel(), ys.ravel()], axis=1) + 0.5) / scale - 0.5  # thumbnail → image pixels
    origins, dirs = measured.outlines.cameras[k].pixel_rays(pixels.astype(np.float64))
    inverse = np.linalg.inv(measured.found.mesh_to_turntable)
    d = dirs @ inverse[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    surface = caster.surface_along(origins @ inverse[:3, :3].T + inverse[:3, 3], d)
    return surface_regions(plan, measured.mesh, surface).reshape(h, w)


def _mm(v: list[float] | None, spec: str = ".2f") -> str:
    return "(" + ", ".join(format(x, spec) for x in (v or [])) + ")"
