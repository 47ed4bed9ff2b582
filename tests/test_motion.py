"""A plan's poses as device targets, and the refusal of poses the rig cannot reach — before any motion."""

from dataclasses import replace

import numpy as np
import pytest

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import read_plan
from hlr_lab.instrument.motion import motion_targets
from sim.camera import GantryGeometry, StageGeometry

# The servo rounds each angle to the nearest of 4096 ticks: at most half a tick (0.044°) per axis, an arc
# of at most R·√2·π/4096 = 0.33 mm on the 0.30 m arm.
HALF_TICK_ARC_M = 0.30 * np.sqrt(2) * np.pi / 4096


def test_every_pose_becomes_ticks_and_steps_that_put_the_sim_lamp_where_planned(plan_file, rig):
    path, *_ = plan_file
    plan = read_plan(path)
    targets = motion_targets(plan, rig, path)
    assert [t.pose_id for t in targets] == [p.id for p in plan.poses]
    truth, stage = GantryGeometry(), StageGeometry()
    for pose, target in zip(plan.poses, targets, strict=True):
        lamp = truth.light_position(*target.gantry_ticks)
        assert np.linalg.norm(lamp - pose.light.position_m) <= HALF_TICK_ARC_M
        assert abs(target.turntable_steps / stage.steps_per_degree - pose.turntable_deg) <= 0.5 / 100


def _with_pose(plan, i, **light_or_pose):
    bad = plan.model_copy(deep=True)
    pose = bad.poses[i]
    for key, value in light_or_pose.items():
        setattr(pose.light if hasattr(pose.light, key) else pose, key, value)
    return bad


@pytest.mark.parametrize(
    ("change", "field", "message"),
    [
        ({"turntable_deg": 200.0}, "poses[1].turntable_deg", "outside the rig's limits"),
        ({"elevation_deg": 85.0}, "poses[1].light.elevation_deg", "outside the rig's limits"),
        ({"azimuth_deg": -181.0}, "poses[1].light.azimuth_deg", "outside the rig's limits"),
        # within the elevation limits, but 28 mm above the plate where the rig allows 30
        (
            {"elevation_deg": -8.0},
            "poses[1].light.elevation_deg",
            r"28 mm above the plate, below .*\(30 mm\)",
        ),
        # +180° is −180°, but position mode's one turn ends at tick 4095: the planner's −180° is reachable
        ({"azimuth_deg": 180.0}, "poses[1].light.azimuth_deg", r"servo tick 4096, .* \[0, 4095\]"),
    ],
)
def test_a_pose_outside_the_limits_is_named(plan_file, rig, change, field, message):
    path, *_ = plan_file
    bad = _with_pose(read_plan(path), 1, **change)
    with pytest.raises(InputError, match=message) as err:
        motion_targets(bad, rig, path)
    assert err.value.field == field
    assert err.value.path == path
    assert "re-plan with this rig" in str(err.value)


def test_a_plan_for_another_gantry_is_refused(plan_file, rig):
    path, *_ = plan_file
    plan = read_plan(path)
    other = replace(rig, gantry=replace(rig.gantry, arm_radius=0.35))
    with pytest.raises(InputError, match=r"off this rig's gantry sphere") as err:
        motion_targets(plan, other, path)
    assert err.value.field == "poses[0].light.position_m"
    assert f"({len(plan.poses) - 1} more problems in other poses)" in str(err.value)
