"""The built-in ``abb_irb2400`` robot plugin, registered through the ``spherecal``
entry-point group exactly as a third-party plugin would be.

A real run connects :class:`~.driver.AbbIrb2400Robot` to ``config.port``. A simulated
run (``context.cell`` is a SimulatedCell) starts the simulated controller on localhost
with that cell and connects the same driver to it through pyserial, so the simulated
path exercises the real protocol; closing the robot stops the simulator.
"""

from __future__ import annotations

import numpy as np

from spherecal.devices import DeviceContext, RobotType
from spherecal.models import Pose
from spherecal.plugins import hookimpl

from .config import AbbIrb2400Config
from .driver import AbbIrb2400Robot
from .kinematics import kinematics_for
from .simulator import start_simulator

NAME = "abb_irb2400"
DESCRIPTION = (
    "ABB IRB 2400 on an IRC5 or S4C+ controller running SpherecalServer.mod over a serial line "
    "(spherecal line protocol; simulated controller on localhost in simulated runs)"
)


def create_robot(config: AbbIrb2400Config, context: DeviceContext) -> AbbIrb2400Robot:
    """Factory: a connected robot (checked with PING) on ``config.port``, or on a freshly
    started simulated controller when ``context.cell`` is set."""
    kin = kinematics_for(config.geometry, config.j23_coupled)
    tool = context.tool_point_mm
    if context.cell is None:
        robot = AbbIrb2400Robot(config, kinematics=kin, tool_point_mm=tool)
    else:
        server = start_simulator(kin, config.simulated, context.cell)
        context.log(f"abb_irb2400: simulated controller serving on {server.url}")
        robot = AbbIrb2400Robot(config, url=server.url, kinematics=kin, on_close=server.stop, tool_point_mm=tool)
        robot.simulator = server  # for tests and fault injection
    try:
        robot.ping()
    except BaseException:
        robot.close()
        raise
    return robot


def flange_pose_from_joints(config: AbbIrb2400Config, joints_deg: np.ndarray) -> Pose:
    """``base_from_flange`` (mm, quaternion (w, x, y, z)) from controller joints in deg."""
    return kinematics_for(config.geometry, config.j23_coupled).flange_pose_from_joints(joints_deg)


def arm_kinematics(config: AbbIrb2400Config):
    """The arm's nominal geometry, inverse kinematics and joint convention."""
    return kinematics_for(config.geometry, config.j23_coupled)


ROBOT_TYPE = RobotType(
    name=NAME,
    config_model=AbbIrb2400Config,
    factory=create_robot,
    description=DESCRIPTION,
    flange_pose_from_joints=flange_pose_from_joints,
    arm_kinematics=arm_kinematics,
)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_robot(ROBOT_TYPE)
