"""A plan's poses as device targets: turntable steps and gantry servo ticks, checked against the rig.

Acquisition validates the whole plan here before the first move (issue 5): a pose outside the rig's
limits, or a light the plan placed on another rig's sphere, is refused with the pose and field named,
and nothing has moved. The drivers check their own tick limits again before sending anything.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import PlanFile
from hlr_lab.rig.file import Rig

# The plan stores light positions rounded to 1 µm and angles to 1e-4°, whose arc on a 0.3 m arm is
# 0.5 µm; a 1 mm disagreement between the two can only mean another centre or arm radius.
SPHERE_TOLERANCE_M = 1e-3


@dataclass(frozen=True)
class PoseTarget:
    """Where a pose sends the rig: angles in degrees, and the device units they convert to."""

    pose_id: str
    turntable_deg: float
    turntable_steps: int
    gantry_deg: tuple[float, float]  # azimuth, elevation
    gantry_ticks: tuple[int, int]  # azimuth servo, elevation servo


def motion_targets(plan: PlanFile, rig: Rig, plan_path: str | Path = "plan.json") -> list[PoseTarget]:
    """Every pose of ``plan`` as device targets on ``rig``; one :class:`InputError` for the first bad pose.

    The message counts the other bad poses too, so the operator knows whether one edit or a re-plan
    is needed.
    """
    if plan.parameters.sphere_source == "scale":
        raise InputError(
            f"this is an analysis plan: its lights lie on a sphere of {plan.parameters.sphere_radius_m:.3f} m "
            "about the object (plan --sphere-scale, the paper's setting), not on a gantry's, so no rig can take "
            "it; plan again without --sphere-scale to acquire",
            path=plan_path,
            field="parameters.sphere_source",
        )
    if not plan.poses:
        raise InputError(
            "the plan has no poses, so there is nothing to acquire; plan the object again (see the plan's "
            "'uncovered' for why its regions got no light)",
            path=plan_path,
            field="poses",
        )
    problems: list[tuple[str, str]] = []  # (field, message)
    targets = []
    for i, pose in enumerate(plan.poses):
        pose_problems = _pose_problems(pose.turntable_deg, pose.light, rig)
        problems += [(f"poses[{i}].{field}", message) for field, message in pose_problems]
        if not pose_problems:
            az, el = pose.light.azimuth_deg, pose.light.elevation_deg
            targets.append(
                PoseTarget(
                    pose.id,
                    pose.turntable_deg,
                    rig.turntable_kinematics.steps_for(pose.turntable_deg),
                    (az, el),
                    rig.gantry.kinematics.ticks_for(az, el),
                )
            )
    if problems:
        field, message = problems[0]
        more = f" ({len(problems) - 1} more problems in other poses)" if len(problems) > 1 else ""
        raise InputError(f"{message}{more}; re-plan with this rig", path=plan_path, field=field)
    return targets


def _pose_problems(turntable_deg: float, light, rig: Rig) -> list[tuple[str, str]]:
    g = rig.gantry
    checks = [
        ("turntable_deg", turntable_deg, rig.turntable_limits_deg),
        ("light.azimuth_deg", light.azimuth_deg, tuple(np.degrees(g.azimuth_limits))),
        ("light.elevation_deg", light.elevation_deg, tuple(np.degrees(g.elevation_limits))),
    ]
    problems = [
        (field, f"{value:g}° is outside the rig's limits [{lo:g}, {hi:g}]")
        for field, value, (lo, hi) in checks
        if not lo <= value <= hi
    ]
    ticks = g.kinematics.ticks_for(light.azimuth_deg, light.elevation_deg)
    for axis, tick, (lo, hi) in zip(("azimuth", "elevation"), ticks, g.servo_limits, strict=True):
        if not problems and not lo <= tick <= hi:
            problems.append(
                (f"light.{axis}_deg", f"maps to servo tick {tick}, outside the servo limits [{lo}, {hi}]")
            )
    angles = np.radians([light.azimuth_deg, light.elevation_deg])
    on_sphere = g.centre + g.arm_radius * g.kinematics.unit_direction(*angles)
    if on_sphere[2] < g.min_light_height - 1e-6:  # the lamp would hit the plate or what stands on it
        problems.append(
            (
                "light.elevation_deg",
                f"puts the lamp {1000 * on_sphere[2]:.0f} mm above the plate, below the rig's "
                f"min_light_height_m ({1000 * g.min_light_height:.0f} mm)",
            )
        )
    miss = float(np.linalg.norm(on_sphere - np.asarray(light.position_m)))
    if miss > SPHERE_TOLERANCE_M:
        problems.append(
            (
                "light.position_m",
                f"lies {miss * 1000:.1f} mm off this rig's gantry sphere at the pose's angles "
                "(the plan was made for another gantry centre or arm radius)",
            )
        )
    return problems


# Dynamixel X-series profile units (e-manual): velocity 0.229 rev/min, acceleration 214.6 rev/min²
_REV_PER_MIN = 1 / 60
VELOCITY_UNIT_REV_S = 0.229 * _REV_PER_MIN
ACCELERATION_UNIT_REV_S2 = 214.6 * _REV_PER_MIN * _REV_PER_MIN
FRAME_OVERHEAD_S = 0.3  # transfer, PNG encoding and the fsync'ed journal line (measured ≈ 0.2 s, 1280×960)


def trapezoid_s(distance: float, speed: float, acceleration: float) -> float:
    """Duration of a rest-to-rest move with a trapezoidal (or, when short, triangular) speed profile."""
    distance = abs(distance)
    if distance * acceleration >= speed * speed:
        return distance / speed + speed / acceleration
    return 2.0 * float(np.sqrt(distance / acceleration))


def estimate_duration_s(plan: PlanFile, targets: list[PoseTarget], rig: Rig) -> float:
    """How long the plan takes on this rig: per pose the slowest axis (from the previous pose; the first
    from the axes' zero), the settle time, the exposures, and a per-frame overhead."""
    g, t = rig.file.gantry, rig.file.turntable
    tick_speed = g.profile_velocity * VELOCITY_UNIT_REV_S * g.ticks_per_rev
    tick_acceleration = g.profile_acceleration * ACCELERATION_UNIT_REV_S2 * g.ticks_per_rev
    ticks, steps = tuple(g.zero_ticks), t.zero_steps
    total = 0.0
    for pose, target in zip(plan.poses, targets, strict=True):
        axes = [
            trapezoid_s(b - a, tick_speed, tick_acceleration)
            for a, b in zip(ticks, target.gantry_ticks, strict=True)
        ]
        axes.append(trapezoid_s(target.turntable_steps - steps, t.speed_steps_s, t.acceleration_steps_s2))
        total += max(axes) + g.settle_s + sum(pose.exposures_s) + FRAME_OVERHEAD_S * len(pose.exposures_s)
        ticks, steps = target.gantry_ticks, target.turntable_steps
    return total
