"""Robot type ``example_cartesian``: a simulated Cartesian robot with a wrist.

Three linear axes carry a spherical wrist, so the robot can put its flange at any
position inside its workspace box with any orientation. It exists only in simulation:
it moves the flange of a :class:`spherecal.plugins.SimulatedCell` exactly to the commanded
pose and reports the pose as a controller would, with the cell's pose noise.

Poses are ``base_from_flange``: translation in mm, rotation as a quaternion
(w, x, y, z), as everywhere in spherecal (docs/conventions.md).
"""

from __future__ import annotations

import numpy as np
from pydantic import ConfigDict, Field

from spherecal.plugins import (
    DeviceContext,
    DeviceError,
    MotionLimits,
    MotionSafety,
    Pose,
    RobotType,
    WorkspaceBox,
    hookimpl,
    matrix_from_rotvec,
    rotvec_from_matrix,
)

TYPE_NAME = "example_cartesian"


class CartesianConfig(MotionLimits):
    """Configuration section of an ``example_cartesian`` robot::

        [robot]
        type = "example_cartesian"
        max_speed_mm_s = 250
        [robot.workspace]
        min_mm = [0, -1000, 0]
        max_mm = [2000, 1000, 1200]

    The limits are the core's :class:`~spherecal.plugins.MotionLimits` (``max_speed_mm_s``,
    ``orientation_speed_deg_s``, ``path_check_samples``, ``workspace``); this robot only
    gives the workspace box a default, the travel of its linear axes.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    workspace: WorkspaceBox = Field(
        default=WorkspaceBox(min_mm=(0.0, -1000.0, 0.0), max_mm=(2000.0, 1000.0, 1500.0)),
        description="the linear axes' travel: the box the flange centre stays in, base frame, mm",
    )


class CartesianAxes:
    """The arm's kinematics as :class:`~spherecal.plugins.MotionSafety` needs them. The
    axis readings are the flange position (x, y, z in mm: the three linear axes) and the
    wrist's rotation vector (deg). The wrist turns any way, so every pose whose position
    the linear axes reach is reachable: the workspace box is the whole reach check."""

    def flange_pose_from_joints(self, axes, check_limits: bool = True) -> Pose:
        a = np.asarray(axes, dtype=float)
        return Pose.from_rt(matrix_from_rotvec(np.radians(a[3:])), a[:3])

    def joints_from_flange_pose(self, pose: Pose, seed_joints_deg=None) -> np.ndarray:
        return np.concatenate([pose.translation, np.degrees(rotvec_from_matrix(pose.rotation_matrix))])


class AxisChecks(MotionSafety):
    """The core's motion checks on the cell's axes: the speed, both ends of a move in the
    workspace box, the reach along the path. It reads the axes for itself, because the
    robot reports no joints (:meth:`ExampleCartesianRobot.read_joints_deg`). Every
    refusal is an :class:`~spherecal.plugins.InputError` naming the limit, raised before
    anything moves."""

    name = TYPE_NAME

    def __init__(self, config: CartesianConfig, cell, tool_point_mm=None) -> None:
        super().__init__(config, CartesianAxes(), tool_point_mm=tool_point_mm)
        self._cell = cell

    def read_joints_deg(self) -> np.ndarray:
        return self.kin.joints_from_flange_pose(self._cell.current_base_from_flange)


class ExampleCartesianRobot:
    """The :class:`spherecal.plugins.Robot` of ``example_cartesian`` on a simulated cell."""

    def __init__(self, config: CartesianConfig, cell, tool_point_mm=None) -> None:
        self.config = config
        self._cell = cell
        self._checks = AxisChecks(config, cell, tool_point_mm)
        self._open = True
        self._reported = None  # the pose reported at this standstill

    def _require_open(self) -> None:
        if not self._open:
            raise DeviceError(f"{TYPE_NAME}: the robot has been closed; create a new one")

    def read_flange_pose(self) -> Pose:
        """The flange pose now, ``base_from_flange``, with the cell's pose noise: the same
        reading while the robot stands still, as a controller gives."""
        self._require_open()
        if self._reported is None:
            self._reported = self._cell.report_pose(self._cell.current_base_from_flange)
        return self._reported

    def read_joints_deg(self):
        """None: a Cartesian robot's linear axes have no angles to report."""
        self._require_open()
        return None

    def check_target(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """One planned target against the limits (speed, box), without moving: the
        run's plan check calls it for every target before the first motion."""
        self._require_open()
        self._checks.check_target(base_from_flange, speed_mm_s)

    def check_move(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """The move from where the flange is now, as :meth:`move_linear` checks it,
        without moving: the run's first move is checked before the first motion."""
        self._require_open()
        self._checks.check_move(base_from_flange, speed_mm_s)

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Move to ``base_from_flange`` (mm, quaternion (w, x, y, z)); checks the speed
        and the workspace box at both ends first, so a refused move does not move."""
        self._require_open()
        self._checks.check_move_from_here(base_from_flange, speed_mm_s)  # raises InputError before moving
        self._cell.move_flange_to(base_from_flange)
        self._reported = None  # a new standstill, a new reading

    def close(self) -> None:
        """Release the robot. Safe to call twice."""
        self._open = False


def create_robot(config: CartesianConfig, context: DeviceContext) -> ExampleCartesianRobot:
    """Factory called by the plugin host with the validated configuration."""
    if context.cell is None:
        raise DeviceError(
            f"{TYPE_NAME} is a simulated robot and has no hardware to connect to; "
            f"run it on a simulated cell (DeviceContext(cell=spherecal.plugins.standard_cell(fov=...)))"
        )
    context.log(f"{TYPE_NAME}: simulated Cartesian robot on a {context.cell.mounting} cell")
    return ExampleCartesianRobot(config, context.cell, context.tool_point_mm)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_robot(
        RobotType(
            name=TYPE_NAME,
            config_model=CartesianConfig,
            factory=create_robot,
            description="simulated Cartesian robot with a wrist (example plugin)",
            flange_pose_from_joints=None,  # it reports poses, not joints
        )
    )
