"""What a calibration changed, as a table (label, the rig file before, calibrated) and the lines around
it: the command line and campaigns print them, the figures come from the procedure's outcome."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from rich.markup import escape
from rich.table import Table

from calibration.camera_procedure import CameraCalibration
from calibration.gantry_procedure import GantryCalibration
from calibration.procedures import Calibrated
from calibration.radiometric_procedure import RadiometricCalibration

Row = tuple[str, str, str]
TITLES = {
    "camera": "camera calibration",
    "gantry": "gantry calibration",
    "radiometric": "radiometric calibration",
}


def table(c: Calibrated) -> Table:
    """``c``'s figures: one row per calibrated field, the rig file's value beside the calibrated one."""
    t = Table(title=TITLES[c.procedure], title_justify="left")
    for column in ("", "rig file before", "calibrated"):
        t.add_column(column, justify="right", overflow="fold")
    for row in rows(c):
        t.add_row(*row)
    return t


def before_table(c: Calibrated) -> list[str]:
    """The line printed before ``c``'s table (rich markup): how the lamp's warm-up ended, if it had one."""
    if c.warmed is None:
        return []
    state = "stable" if c.warmed.stable else "[yellow]NOT stable[/]"
    return [
        f"lamp {state} after {c.warmed.minutes:.1f} min of warm-up ({100 * c.warmed.per_minute:.2f} % per minute)"
    ]


def after_table(c: Calibrated) -> list[str]:
    """The lines printed after ``c``'s table (rich markup): its warnings, then where everything went."""
    summary = f"; summary {escape(str(c.summary))}" if c.summary else ""
    if c.summary_problem:
        summary = f"; [yellow]no summary page ({escape(c.summary_problem)})[/]"
    where = f"photographs in {escape(str(c.images))}{summary}; wrote {escape(str(c.output))}"
    return [f"[yellow]{escape(w)}[/]" for w in warnings(c)] + [where]


def rows(c: Calibrated) -> list[Row]:
    """The rows of ``c``'s table."""
    if isinstance(c.result, CameraCalibration):
        return _camera_rows(c, c.result)
    if isinstance(c.result, GantryCalibration):
        return _gantry_rows(c, c.result)
    return _radiometric_rows(c, c.result)


def warnings(c: Calibrated) -> list[str]:
    """What the operator should know of ``c`` beyond its figures."""
    if isinstance(c.result, RadiometricCalibration) and not c.result.lamp.follows_inverse_square:
        return ["the lamp does not follow 1/d² within 2 %: it may need a diffuser, or another [light] type"]
    return []


def _camera_rows(c: Calibrated, result: CameraCalibration) -> list[Row]:
    before, after = c.before, c.rig
    kb, ka, se = before.camera.matrix, after.camera.matrix, result.pose.intrinsics_se_px
    used = sum(len(d.ids) >= 6 for d in result.detections)
    return [
        (
            "fx, fy (px)",
            f"{kb[0, 0]:.1f}, {kb[1, 1]:.1f}",
            f"{ka[0, 0]:.1f} ± {se[0]:.1f}, {ka[1, 1]:.1f} ± {se[1]:.1f}",
        ),
        (
            "cx, cy (px)",
            f"{kb[0, 2]:.2f}, {kb[1, 2]:.2f}",
            f"{ka[0, 2]:.2f} ± {se[2]:.2f}, {ka[1, 2]:.2f} ± {se[3]:.2f}",
        ),
        ("k1, k2", _pair(before.camera.distortion), _pair(after.camera.distortion)),
        ("position (m)", _vec(before.camera.centre), _vec(after.camera.centre)),
        ("moved by", "", f"{1e3 * np.linalg.norm(after.camera.centre - before.camera.centre):.2f} mm"),
        ("view turned by", "", f"{angle_deg(before.camera.forward, after.camera.forward):.3f}°"),
        ("roll (°)", f"{before.file.camera.roll_deg:.3f}", f"{after.file.camera.roll_deg:.3f}"),
        (
            "turntable zero (steps)",
            str(before.file.turntable.zero_steps),
            str(after.file.turntable.zero_steps),
        ),
        ("board azimuth on the plate", "", f"{result.pose.board_azimuth_deg:.3f}°"),
        (
            "reprojection RMS",
            "",
            f"{result.pose.rms_px:.3f} px (worst view {result.pose.per_view_rms_px.max():.3f})",
        ),
        ("views used", "", f"{used} of {len(result.frames)}"),
    ]


def _gantry_rows(c: Calibrated, result: GantryCalibration) -> list[Row]:
    k0, k1 = c.before.gantry.kinematics, c.rig.gantry.kinematics
    se = result.fit.standard_errors
    return [
        ("centre (m)", _vec(k0.centre), _vec(k1.centre)),
        ("arm radius (m)", f"{k0.arm_radius:.4f}", f"{k1.arm_radius:.4f} ± {se['arm_radius_m']:.4f}"),
        ("zero ticks", f"{k0.zero_ticks[0]}, {k0.zero_ticks[1]}", f"{k1.zero_ticks[0]}, {k1.zero_ticks[1]}"),
        (
            "azimuth axis tilt",
            f"{angle_deg(k0.frame[:, 2], [0, 0, 1]):.3f}°",
            f"{angle_deg(k1.frame[:, 2], [0, 0, 1]):.3f}°",
        ),
        ("rays used", "", f"{result.rays} ({result.refused} poses refused: lamp behind the ball)"),
        ("worst lamp miss", "", f"{result.fit.miss_mm.max():.2f} mm"),
    ]


def _radiometric_rows(c: Calibrated, result: RadiometricCalibration) -> list[Row]:
    before, after = c.before.file.sensor, c.rig.file.sensor
    gain = before.conversion_gain_dn_per_e
    sp = result.lamp.sensitivity_times_power
    return [
        ("black level (DN)", f"{before.black_level_dn:.2f}", f"{after.black_level_dn:.2f}"),
        ("read noise (DN)", f"{before.read_noise_dn:.3f}", f"{after.read_noise_dn:.3f}"),
        (
            "conversion gain (DN/e⁻)",
            "—" if gain is None else f"{gain:.4f}",
            f"{after.conversion_gain_dn_per_e:.4f}",
        ),
        (
            "sensitivity × power",
            f"{before.sensitivity * c.before.file.light.power:.1f}",
            f"{np.mean(sp):.1f} (channels {', '.join(f'{v:.1f}' for v in sp)})",
        ),
        ("worst deviation from linear", "", f"{100 * result.transfer.worst_nonlinearity:.2f} %"),
        ("1/d² residual over the lamp positions", "", f"{100 * result.lamp.inverse_square_residual:.2f} %"),
    ]


def angle_deg(a: ArrayLike, b: ArrayLike) -> float:
    """The angle between unit vectors ``a`` and ``b`` (each (3,)), in degrees."""
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def _pair(d: ArrayLike) -> str:
    values = [*np.asarray(d, dtype=float).ravel(), 0.0, 0.0]
    return f"{values[0]:.4f}, {values[1]:.4f}"


def _vec(v: ArrayLike) -> str:
    return ", ".join(f"{x:.4f}" for x in np.asarray(v, dtype=float))
