"""A calibration's photographs with what the solve saw in them, as one self-contained HTML page
(``summary.html`` beside the photographs; docs/calibration.md).

* Camera: each board view with the corners found (green) and each corner's residual after the joint
  fit drawn 50 times longer (red), the view's RMS; views left out say why.
* Gantry: the ball's outline frames with the ball where the fit puts it (green circle), and each
  highlight (magnified) with its centroid (red cross) and how far the fitted lamp lies from its ray.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calibration.camera_procedure import CameraCalibration
from calibration.gantry_procedure import BallFrame, GantryCalibration
from calibration.mirror_ball import ball_centres
from hlr_lab.files import atomic_write_text
from hlr_lab.report.html import escape, figure, page, table
from hlr_lab.rig.file import Rig

SUMMARY = "summary.html"
THUMB_WIDTH = 480  # px of a board view in the page
RESIDUAL_SCALE = 50.0  # a residual is drawn this many times its length
HIGHLIGHT_HALF = 12  # px either side of a highlight's centroid shown
HIGHLIGHT_ZOOM = 5


def _display(pixels: np.ndarray, white: float | None = None) -> np.ndarray:
    """(H, W[, C]) raw frame → (H, W, 3) uint8 grey for display, ``white`` (default: the 99.9th
    percentile) → 255, with a display gamma."""
    grey = pixels.astype(np.float64)
    grey = grey.mean(axis=2) if grey.ndim == 3 else grey
    white = white or max(float(np.percentile(grey, 99.9)), 1e-9)
    v = (np.clip(grey / white, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
    return np.repeat(v[..., None], 3, axis=2)


def camera_summary(result: CameraCalibration, rig: Rig, folder: Path) -> Path:
    """Write ``folder``/summary.html for a camera calibration (``rig``: the rig file it started from)."""
    pose = result.pose
    rows, figures = [], []
    for v, (frame, found) in enumerate(zip(result.frames, result.detections, strict=True)):
        turn = rig.turntable_kinematics.degrees_for(frame.turntable_steps)
        image = _display(frame.pixels)
        scale = THUMB_WIDTH / image.shape[1]
        thumb = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        residual = pose.residuals_px.get(v)
        for i, (x, y) in enumerate(found.pixels * scale):  # drawn on the thumbnail: lines stay visible
            cv2.circle(thumb, (round(x), round(y)), 3, (40, 220, 40), 1, cv2.LINE_AA)
            if residual is not None:
                d = RESIDUAL_SCALE * scale * residual[i]
                cv2.line(thumb, (round(x), round(y)), (round(x + d[0]), round(y + d[1])), (230, 30, 30), 1,
                         cv2.LINE_AA)  # fmt: skip
        if residual is None:
            verdict = f"not used ({len(found.ids)} corners found)"
        else:
            verdict = f"RMS {np.sqrt(np.mean(np.sum(residual**2, axis=1))):.3f} px"
        caption = f"view {v}: turntable {turn:.1f}°, wedge face {frame.placement}, {verdict}"
        figures.append(figure(thumb, caption))
        rows.append([str(v), f"{turn:.1f}", str(frame.placement), str(len(found.ids)), escape(verdict)])
    k = pose.matrix
    body = (
        f"<p>Reprojection RMS {pose.rms_px:.3f} px over {len(pose.residuals_px)} of {len(result.frames)} "
        f"views; fx {k[0, 0]:.1f}, fy {k[1, 1]:.1f}, cx {k[0, 2]:.2f}, cy {k[1, 2]:.2f} px. Green: the "
        f"corners found; red: each corner's residual after the fit, drawn {RESIDUAL_SCALE:g}× longer.</p>"
        + table(["view", "turntable (°)", "wedge face", "corners", "fit"], rows)
        + "".join(figures)
    )
    return _write(folder, page("Camera calibration", body))


def gantry_summary(result: GantryCalibration, frames: list[BallFrame], rig: Rig, folder: Path) -> Path:
    """Write ``folder``/summary.html for a gantry calibration (``rig``: the rig file it started from,
    whose camera saw the frames)."""
    from calibration.gantry_procedure import ball_spec

    radius, _ = ball_spec(rig)
    camera, fit = rig.camera, result.fit
    outlines = []
    for f in frames:
        if f.kind != "outline":
            continue
        a = np.radians(rig.turntable_kinematics.degrees_for(f.turntable_steps))
        centre = ball_centres(fit.place_xy_m, radius, np.array([a]))[0]
        (cx, cy), _ = (v[0] for v in camera.project(centre[None]))
        r_px = camera.matrix[0, 0] * radius / np.linalg.norm(centre - camera.centre)
        image = _display(f.pixels)
        cv2.circle(image, (round(cx), round(cy)), round(r_px), (40, 220, 40), 1)
        half = round(2.5 * r_px)
        crop = image[max(round(cy) - half, 0) : round(cy) + half, max(round(cx) - half, 0) : round(cx) + half]
        outlines.append(figure(crop, f"turntable {np.degrees(a):.1f}°: the ball where the fit puts it"))
    rows, spots = [], []
    for ray, (i, pixel) in enumerate(zip(result.frames_used, result.highlights.pixels, strict=True)):
        f = frames[i]
        x, y = (round(v) for v in pixel)
        h = HIGHLIGHT_HALF
        raw = f.pixels[max(y - h, 0) : y + h + 1, max(x - h, 0) : x + h + 1]
        crop = cv2.resize(_display(raw, white=float(raw.max()) or 1.0), None, fx=HIGHLIGHT_ZOOM,
                          fy=HIGHLIGHT_ZOOM, interpolation=cv2.INTER_NEAREST)  # fmt: skip
        at = ((pixel - (max(x - h, 0), max(y - h, 0))) + 0.5) * HIGHLIGHT_ZOOM
        cv2.drawMarker(crop, (round(at[0]), round(at[1])), (230, 30, 30), cv2.MARKER_CROSS, 14, 1)
        miss = fit.miss_mm[ray]
        turn = rig.turntable_kinematics.degrees_for(f.turntable_steps)
        spots.append(figure(crop, f"{f.gantry_ticks[0]}, {f.gantry_ticks[1]} ticks: {miss:.2f} mm"))
        rows.append([str(i), f"{turn:.1f}", f"{f.gantry_ticks[0]}, {f.gantry_ticks[1]}",
                     f"{pixel[0]:.2f}, {pixel[1]:.2f}", f"{miss:.2f}"])  # fmt: skip
    k, se = fit.kinematics, fit.standard_errors
    body = (
        f"<p>{result.rays} rays fitted ({result.refused} poses refused: the highlight on the ball's edge). "
        f"Arm radius {k.arm_radius * 1e3:.2f} ± {se['arm_radius_m'] * 1e3:.2f} mm, zero ticks "
        f"{k.zero_ticks[0]}, {k.zero_ticks[1]}, worst miss {fit.miss_mm.max():.2f} mm; the ball at "
        f"({fit.place_xy_m[0] * 1e3:.2f}, {fit.place_xy_m[1] * 1e3:.2f}) mm on the plate.</p>"
        + "".join(outlines)
        + "<h2>Highlights</h2><p>Each magnified, its centroid marked; the caption: the servo ticks and "
        "the fitted lamp's distance from the ray.</p>"
        + "".join(spots)
        + table(["frame", "turntable (°)", "servo ticks", "centroid (px)", "miss (mm)"], rows)
    )
    return _write(folder, page("Gantry calibration", body))


def _write(folder: Path, page: str) -> Path:
    path = folder / SUMMARY
    atomic_write_text(path, page)
    return path
