"""The built-in ``urdf`` robot type: any revolute arm from its URDF (Pinocchio kinematics
and limits, numerical inverse kinematics seeded from the current joints, a joint-convention
hook for coupled axes), talking the spherecal line protocol to its controller, with a
simulated controller for simulated runs. See docs/robot-urdf.md. The plugin entry point
is :mod:`.plugin`."""

from .config import JointMapConfig, UrdfRobotConfig
from .kinematics import JointLimitError, JointMap, UnreachableError, UrdfKinematics
from .plugin import UrdfRobot

__all__ = [
    "JointLimitError",
    "JointMap",
    "JointMapConfig",
    "UnreachableError",
    "UrdfKinematics",
    "UrdfRobot",
    "UrdfRobotConfig",
]
