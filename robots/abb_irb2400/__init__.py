"""ABB IRB 2400 robot plugin: kinematic model (Pinocchio), the spherecal line protocol,
a driver over a serial line or TCP, the RAPID server modules (with an offline syntax
check) and a simulated controller.

See docs/robot-abb-irb2400.md. The plugin entry point is :mod:`.plugin`.
"""

from .config import AbbIrb2400Config, SimulatedControllerSettings, WorkspaceBox
from .driver import AbbIrb2400Robot
from .kinematics import (
    Irb2400Geometry,
    Irb2400Kinematics,
    JointLimitError,
    UnreachableError,
    flange_pose_from_joints,
)
from .simulator import Faults, SimulatedIrb2400, SimulatorServer, start_simulator

__all__ = [
    "AbbIrb2400Config",
    "AbbIrb2400Robot",
    "Faults",
    "Irb2400Geometry",
    "Irb2400Kinematics",
    "JointLimitError",
    "SimulatedControllerSettings",
    "SimulatedIrb2400",
    "SimulatorServer",
    "UnreachableError",
    "WorkspaceBox",
    "flange_pose_from_joints",
    "start_simulator",
]
