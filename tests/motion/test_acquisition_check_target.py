"""Robot.check_target: a robot plugin's pre-motion check of each planned target joins
the plan check (documented in spherecal.devices.contract.Robot, docs/writing-a-robot-plugin.md and
docs/cli.md): every target at fault is listed, nothing is moved, and a robot without the
method is checked against the configured limits only."""

from __future__ import annotations

import numpy as np

from spherecal.motion.acquisition import Target, check_targets
from spherecal.config import AcquisitionConfig
from spherecal.devices.contract import Robot
from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose


class ReachLimitedRobot:
    """A robot whose own limit is a reach of 1000 mm from its base; it records every
    call, so the test sees that nothing moved."""

    def __init__(self):
        self.moves, self.checked = [], []

    def read_flange_pose(self):
        return Pose.identity()

    def read_joints_deg(self):
        return None

    def move_linear(self, base_from_flange, speed_mm_s):
        self.moves.append(base_from_flange)

    def close(self):
        pass

    def check_target(self, base_from_flange, speed_mm_s):
        self.checked.append((base_from_flange, speed_mm_s))
        reach = float(np.linalg.norm(base_from_flange.translation))
        if reach > 1000.0:
            raise DeviceError(f"out of reach: {reach:.0f} mm from the base, at most 1000 mm")


def targets(xs):
    return [Target(k, "S1", Pose.from_rt(np.eye(3), [x, 0.0, 500.0]), k == 0, 50.0) for k, x in enumerate(xs)]


def acquisition():
    return AcquisitionConfig.model_validate({"sphere_centre_mm": [900.0, 0.0, 400.0],
                                             "workspace": {"min_mm": [-2000.0, -2000.0, -2000.0],
                                                           "max_mm": [2000.0, 2000.0, 2000.0]}})


def test_a_robot_with_check_target_joins_the_plan_check():
    robot = ReachLimitedRobot()
    assert isinstance(robot, Robot)  # the optional method does not change the protocol
    plan = targets([600.0, 900.0, 950.0, 700.0])  # reaches 781, 1030, 1074, 860 mm
    problems = check_targets(plan, acquisition(), robot)
    assert problems == ["target 1 (station S1): out of reach: 1030 mm from the base, at most 1000 mm",
                        "target 2 (station S1): out of reach: 1074 mm from the base, at most 1000 mm"]
    assert len(robot.checked) == 4 and robot.checked[0][1] == 50.0 and robot.moves == []


def test_without_check_target_only_the_configured_limits_are_checked():
    class Plain(ReachLimitedRobot):
        check_target = None

    assert check_targets(targets([600.0, 900.0, 950.0]), acquisition(), Plain()) == []
    assert check_targets(targets([600.0, 2500.0]), acquisition(), Plain())[0].startswith(
        "target 1 (station S1) at [2500.0, 0.0, 500.0] mm is outside acquisition.workspace")


def test_check_target_is_documented_where_a_plugin_author_looks():
    from pathlib import Path

    docs = Path(__file__).resolve().parents[2] / "docs"
    assert "check_target(base_from_flange,\n    speed_mm_s)" in Robot.__doc__
    assert "| `check_target(base_from_flange, speed_mm_s)` *(optional)* |" in (
        docs / "writing-a-robot-plugin.md").read_text()
    assert "check_target" in (docs / "cli.md").read_text()
