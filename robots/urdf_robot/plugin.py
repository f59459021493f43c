"""The built-in ``urdf`` robot type: any revolute arm from its URDF, registered through the
``spherecal`` entry-point group exactly as a third-party plugin would be.

A real run connects a :class:`UrdfRobot` (the core's :class:`~spherecal.linelink.LineRobot`:
the spherecal line protocol over a serial line or TCP (``socket://host:port``), with the
speed, workspace and reachability checks before anything moves) to ``config.port``: the
controller runs a small server that speaks the protocol (docs/line-protocol.md). A
simulated run (``context.cell`` is a SimulatedCell) starts the core's simulated
controller (:mod:`spherecal.sim.controller`, on ``simulated.transport``) on localhost
with the URDF's kinematics and that cell, and connects the same robot to it, so the
simulated path exercises the real protocol; closing the robot stops the simulated
controller.

The robot type describes itself: forward kinematics (``flange_pose_from_joints``) and
the arm (``arm_kinematics``: the URDF's chain, its joint convention, limits and inverse
kinematics), so ``solve`` maps joints through it and the estimator's kinematic robot
error model and ``identify_kinematics`` work on it.
"""

from __future__ import annotations

import numpy as np

from spherecal.devices import DeviceContext, RobotType
from spherecal.linelink import LineRobot
from spherecal.models import Pose
from spherecal.plugins import hookimpl
from spherecal.sim.controller import start_controller

from .config import UrdfRobotConfig
from .kinematics import UrdfKinematics

NAME = "urdf"
DESCRIPTION = (
    "any revolute arm from its URDF (Pinocchio kinematics and limits, numerical IK), its controller "
    "running a spherecal line-protocol server over serial or socket:// (simulated controller on "
    "localhost in simulated runs)"
)


class UrdfRobot(LineRobot):
    """A connected arm described by a URDF (implements :class:`spherecal.devices.Robot`).
    Poses are ``base_from_flange`` (the flange link in the base link), mm, quaternion
    (w, x, y, z); joints are degrees in the controller's order and convention."""

    server_hint = "that the controller's spherecal line server is running (docs/line-protocol.md)"

    def __init__(self, config: UrdfRobotConfig, kinematics: UrdfKinematics | None = None, **kwargs):
        kin = kinematics or config.kinematics()
        self.name = f"urdf robot ({config.urdf.name})"
        super().__init__(config, kin, n_joints=kin.n_joints, workspace=config.workspace_box(kin), **kwargs)


def create_robot(config: UrdfRobotConfig, context: DeviceContext) -> UrdfRobot:
    """Factory: a connected robot (checked with PING) on ``config.port``, or on a freshly
    started simulated controller when ``context.cell`` is set."""
    kin = config.kinematics()
    tool = context.tool_point_mm
    if context.cell is None:
        robot = UrdfRobot(config, kin, tool_point_mm=tool)
    else:
        server = start_controller(kin, config.simulated, context.cell, kin.n_joints)
        context.log(f"urdf: simulated controller of {config.urdf.name} serving on {server.url}")
        robot = UrdfRobot(config, kin, url=server.url, on_close=server.stop, tool_point_mm=tool)
        robot.simulator = server  # for tests and fault injection
    try:
        robot.ping()
    except BaseException:
        robot.close()
        raise
    return robot


def flange_pose_from_joints(config: UrdfRobotConfig, joints_deg: np.ndarray) -> Pose:
    """``base_from_flange`` (mm, quaternion (w, x, y, z)) from controller joints in deg."""
    return config.kinematics().flange_pose_from_joints(joints_deg)


def arm_kinematics(config: UrdfRobotConfig) -> UrdfKinematics:
    """The arm as the URDF describes it: chain, joint convention, limits, inverse kinematics."""
    return config.kinematics()


ROBOT_TYPE = RobotType(
    name=NAME,
    config_model=UrdfRobotConfig,
    factory=create_robot,
    description=DESCRIPTION,
    flange_pose_from_joints=flange_pose_from_joints,
    arm_kinematics=arm_kinematics,
)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_robot(ROBOT_TYPE)
