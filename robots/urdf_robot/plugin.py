"""The built-in ``urdf`` robot type: any revolute arm from its URDF, registered through the
``spherecal`` entry-point group exactly as a third-party plugin would be.

A real run connects a :class:`UrdfRobot` (the core's :class:`~spherecal.plugins.LineRobot`:
the spherecal line protocol over a serial line or TCP (``socket://host:port``), with the
speed, workspace and reachability checks before anything moves) to ``config.port``: the
controller runs a small server that speaks the protocol (docs/line-protocol.md). A
simulated run (``context.cell`` is a SimulatedCell) starts the core's simulated
controller (:func:`spherecal.plugins.start_controller`, on ``simulated.transport``) on localhost
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

from spherecal.plugins import DeviceContext, DeviceError, LineRobot, Pose, RobotType, hookimpl

from .config import UrdfRobotConfig
from .kinematics import UrdfKinematics

NAME = "urdf"
DESCRIPTION = (
    "any revolute arm from its URDF (Pinocchio kinematics and limits, numerical IK), its controller "
    "running a spherecal line-protocol server over serial or socket:// (simulated controller on "
    "localhost in simulated runs)"
)


class UrdfRobot(LineRobot):
    """A connected arm described by a URDF (implements :class:`spherecal.plugins.Robot`).
    Poses are ``base_from_flange`` (the flange link in the base link), mm, quaternion
    (w, x, y, z); joints are degrees in the controller's order and convention."""

    server_hint = "that the controller's spherecal line server is running (docs/line-protocol.md)"

    def __init__(self, config: UrdfRobotConfig, kinematics: UrdfKinematics | None = None, **kwargs):
        kin = kinematics or config.kinematics()
        self.name = f"urdf robot ({config.urdf.name})"
        super().__init__(config, kin, n_joints=kin.n_joints, workspace=config.workspace_box(kin), **kwargs)

    def check_base_frame(self) -> None:
        """Refuse a controller that reports (and takes) poses in another frame than the
        URDF's ``base_link``: spherecal plans, checks the workspace and the paths, and
        moves in that frame, so its checks would not hold for the motion the controller
        makes. The controller's pose (GETP) is compared with the URDF's pose of the joints
        it reports (GETJ); beyond ``base_frame_tolerance_mm`` / ``_deg`` a DeviceError
        says by how much and what to do. Nothing has moved. The same check catches a
        URDF, ``joint_map`` or ``flange_link`` that does not match the arm."""
        off = self.controller_frame_offset(self.kin)
        cfg = self.config
        if off.within(cfg.base_frame_tolerance_mm, cfg.base_frame_tolerance_deg):
            return
        raise DeviceError(
            f"{self.name} on {self.url}: the controller reports the flange (GETP) {off.offset_mm:.1f} mm and "
            f"{off.angle_deg:.2f} deg away from where the URDF puts {cfg.flange_link!r} in {cfg.base_link!r} at the "
            f"joints it reports ({off.joints_text()} deg), beyond robot.base_frame_tolerance_mm = "
            f"{cfg.base_frame_tolerance_mm:g} / _deg = {cfg.base_frame_tolerance_deg:g}: about controller_from_urdf = "
            f"{off.frame_text()}. spherecal plans, checks the workspace and the "
            "paths, and moves in the URDF's base frame, so its checks would not hold. Nothing was moved. Make the "
            "controller-side server read and move the flange in the robot's base frame (no base frame offset, riser "
            "or user frame applied), or, if it already does, check robot.urdf, robot.joint_map, robot.base_link and "
            "robot.flange_link against the arm"
        )


def create_robot(config: UrdfRobotConfig, context: DeviceContext) -> UrdfRobot:
    """Factory: a connected robot (checked with PING, and refused when the controller's
    frame is not the URDF's base: :meth:`UrdfRobot.check_base_frame`) on ``config.port``,
    or on a freshly started simulated controller when ``context.cell`` is set."""
    kin = config.kinematics()
    tool = context.tool_point_mm
    if context.cell is None:
        robot = UrdfRobot(config, kin, tool_point_mm=tool)
    else:
        from spherecal.plugins import start_controller  # (a simulated run only: loads the simulated controller)

        server = start_controller(kin, config.simulated, context.cell, kin.n_joints)
        context.log(f"urdf: simulated controller of {config.urdf.name} serving on {server.url}")
        robot = UrdfRobot(config, kin, url=server.url, on_close=server.stop, tool_point_mm=tool)
        robot.simulator = server  # for tests and fault injection
    try:
        robot.ping()
        robot.check_base_frame()  # the controller's frame must be the URDF's base before anything moves
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
