"""Robot type ``example_cartesian``: a simulated Cartesian robot with a wrist.

Three linear axes carry a spherical wrist, so the robot can put its flange at any
position inside its workspace box with any orientation. It exists only in simulation:
it moves the flange of a :class:`spherecal.plugins.SimulatedCell` exactly to the commanded
pose and reports the pose as a controller would, with the cell's pose noise.

Poses are ``base_from_flange``: translation in mm, rotation as a quaternion
(w, x, y, z), as everywhere in spherecal (docs/conventions.md).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from spherecal.plugins import DeviceContext, DeviceError, Pose, RobotType, hookimpl

TYPE_NAME = "example_cartesian"


class Workspace(BaseModel):
    """The box the flange centre must stay in, base frame, mm."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    min_x_mm: float = Field(0.0, description="lowest flange x in the base frame, mm")
    max_x_mm: float = Field(2000.0, description="highest flange x in the base frame, mm")
    min_y_mm: float = Field(-1000.0, description="lowest flange y in the base frame, mm")
    max_y_mm: float = Field(1000.0, description="highest flange y in the base frame, mm")
    min_z_mm: float = Field(0.0, description="lowest flange z in the base frame, mm")
    max_z_mm: float = Field(1500.0, description="highest flange z in the base frame, mm")

    @model_validator(mode="after")
    def _check_order(self):
        for axis in "xyz":
            lo, hi = getattr(self, f"min_{axis}_mm"), getattr(self, f"max_{axis}_mm")
            if lo >= hi:
                raise ValueError(f"min_{axis}_mm ({lo}) must be below max_{axis}_mm ({hi})")
        return self


class CartesianConfig(BaseModel):
    """Configuration section of an ``example_cartesian`` robot::

        [robot]
        type = "example_cartesian"
        max_speed_mm_s = 250
        [robot.workspace]
        max_z_mm = 1200
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_speed_mm_s: float = Field(
        250.0, gt=0, le=2000, description="highest linear speed a move may ask for, mm/s"
    )
    workspace: Workspace = Field(
        default_factory=Workspace, description="box the flange centre must stay in, base frame, mm"
    )


class ExampleCartesianRobot:
    """The :class:`spherecal.plugins.Robot` of ``example_cartesian`` on a simulated cell."""

    def __init__(self, config: CartesianConfig, cell) -> None:
        self.config = config
        self._cell = cell
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

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        """Move to ``base_from_flange`` (mm, quaternion (w, x, y, z)); checks the speed
        and the workspace first, so a refused move does not move."""
        self._require_open()
        limit = self.config.max_speed_mm_s
        if not (0 < speed_mm_s <= limit):
            raise DeviceError(
                f"{TYPE_NAME}: speed_mm_s = {speed_mm_s} is outside (0, {limit}] mm/s "
                f"(robot.max_speed_mm_s); ask for a slower move or raise the limit"
            )
        ws = self.config.workspace
        for axis, value in zip("xyz", base_from_flange.translation_mm):
            lo, hi = getattr(ws, f"min_{axis}_mm"), getattr(ws, f"max_{axis}_mm")
            if not (lo <= value <= hi):
                raise DeviceError(
                    f"{TYPE_NAME}: target flange {axis} = {value:.3f} mm is outside the workspace "
                    f"[{lo}, {hi}] mm (robot.workspace.min_{axis}_mm / max_{axis}_mm); nothing was moved"
                )
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
    return ExampleCartesianRobot(config, context.cell)


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
