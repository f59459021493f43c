"""The built-in ``abb_irb2400`` robot plugin, registered through the ``spherecal``
entry-point group exactly as a third-party plugin would be.

A real run connects :class:`~.driver.AbbIrb2400Robot` to ``config.port``. A simulated
run (``context.cell`` is a SimulatedCell) starts the simulated controller on localhost
with that cell and connects the same driver to it through pyserial, so the simulated
path exercises the real protocol; closing the robot stops the simulator.

A calibrated model (``config.calibrated_model``, a URDF such as a kinematic
calibration's ``robot_calibrated.urdf``) is applied **on the PC side**: an ABB controller
cannot take new link lengths, so it keeps its nominal model. To put the flange at a pose
P, the driver solves the joints q that reach P on the calibrated model and sends the
controller the *nominal* pose of q, which the controller turns back into q; flange poses
are read as joints (GETJ) through the calibrated model, never as the controller's own
(nominal) pose. The plugin's forward kinematics, inverse kinematics and chain
(``flange_pose_from_joints``, ``arm_kinematics``) are then the calibrated model's too, so
``solve``, ``validate`` and ``scan`` map joints through it. The simulated controller
keeps the nominal model, as a real one does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

# The ``context.extras`` keys a simulated run sets for the simulated controller's EGM
# stream (the pose source, the simulated clock, the controller's clock: see :mod:`.egm_sim`);
# absent: the controller's own pose, an internal clock and ``simulated.egm``'s clock.
from spherecal.plugins import (POSE_STREAM_SOURCE_KEY, SIM_CLOCK_KEY, SIM_CONTROLLER_CLOCK_KEY, DeviceContext, Pose,
                               RobotType, hookimpl)

from .config import AbbIrb2400Config
from .export import RAPID_EXPORTER
from .kinematics import Irb2400Kinematics, kinematics_for

if TYPE_CHECKING:  # pragma: no cover
    from .driver import AbbIrb2400Robot

NAME = "abb_irb2400"
DESCRIPTION = (
    "ABB IRB 2400 on an IRC5 or S4C+ controller running SpherecalServer.mod over a serial line, or on an "
    "IRC5 over TCP (port = socket://host:port) (spherecal line protocol; simulated controller on localhost "
    "in simulated runs)"
)


#: The arm's home, controller convention, deg: where the core seeds inverse kinematics
#: when the joints are not known, as the simulated controller starts (upper arm upright,
#: forearm level, wrist bent down: no singularity).
HOME_JOINTS_DEG = (0.0, 0.0, 0.0, 0.0, 90.0, 0.0)


def start_simulator(*args, **kwargs):
    """:func:`.simulator.start_simulator`, imported when a simulated run starts one (the
    simulated controller's server is not needed to describe the plugin)."""
    from .simulator import start_simulator as start

    return start(*args, **kwargs)


def read_frame(text: str):
    """:func:`.frames.read_frame` (a ``tooldata`` or ``wobjdata`` line), imported when a
    command reads one (``compare`` and ``validate --tooldata``), not to describe the plugin."""
    from .frames import read_frame as read

    return read(text)


def kinematics_of(config: AbbIrb2400Config) -> Irb2400Kinematics:
    """The arm's kinematics as configured: the calibrated model's when
    ``calibrated_model`` is set, else the nominal geometry's."""
    return config.kinematics()


def create_robot(config: AbbIrb2400Config, context: DeviceContext) -> AbbIrb2400Robot:
    """Factory: a connected robot (checked with PING, and refused when the controller's
    wobj0 is not the robot base: :meth:`~.driver.AbbIrb2400Robot.check_base_frame`) on
    ``config.port``, or on a freshly started simulated controller when ``context.cell``
    is set (``context.extras`` may give its EGM stream a pose source and a clock:
    :data:`POSE_STREAM_SOURCE_KEY`, :data:`SIM_CLOCK_KEY`, :data:`SIM_CONTROLLER_CLOCK_KEY`)."""
    from .driver import AbbIrb2400Robot  # (loaded when a robot is opened: a solve needs the type alone)

    kin = kinematics_of(config)
    tool = context.tool_point_mm
    if context.cell is None:
        robot = AbbIrb2400Robot(config, kinematics=kin, tool_point_mm=tool)
    else:
        # the controller knows only the nominal model, calibrated or not
        server = start_simulator(kinematics_for(config.geometry, config.j23_coupled), config.simulated, context.cell,
                                 egm_source=context.extras.get(POSE_STREAM_SOURCE_KEY),
                                 egm_clock=context.extras.get(SIM_CLOCK_KEY),
                                 egm_controller_clock=context.extras.get(SIM_CONTROLLER_CLOCK_KEY))
        context.log(f"abb_irb2400: simulated controller serving on {server.url}")
        robot = AbbIrb2400Robot(config, url=server.url, kinematics=kin, on_close=server.stop, tool_point_mm=tool)
        robot.simulator = server  # for tests and fault injection
    try:
        robot.ping()
        robot.check_base_frame()  # wobj0 (world) must be the base the checks use
    except BaseException:
        robot.close()
        raise
    return robot


def flange_pose_from_joints(config: AbbIrb2400Config, joints_deg: np.ndarray) -> Pose:
    """``base_from_flange`` (mm, quaternion (w, x, y, z)) from controller joints in deg,
    through the calibrated model when one is configured."""
    return kinematics_of(config).flange_pose_from_joints(joints_deg)


def arm_kinematics(config: AbbIrb2400Config):
    """The arm's geometry (the calibrated model's when one is configured, else the
    nominal one), inverse kinematics and joint convention."""
    return kinematics_of(config)


ROBOT_TYPE = RobotType(
    name=NAME,
    config_model=AbbIrb2400Config,
    factory=create_robot,
    description=DESCRIPTION,
    flange_pose_from_joints=flange_pose_from_joints,
    arm_kinematics=arm_kinematics,
    home_joints_deg=HOME_JOINTS_DEG,
    read_frame=read_frame,
    frame_option="tooldata",  # spherecal compare/validate --tooldata LINE: the word RAPID users know
)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_robot(ROBOT_TYPE)


@hookimpl
def spherecal_register_exporters(registry) -> None:
    """The RAPID tooldata/wobjdata export, for this robot type (docs/results.md)."""
    registry.add_exporter(RAPID_EXPORTER)
