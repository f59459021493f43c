"""A third-party plugin written against the module paths of the release before the
plugin API (``spherecal.devices``, ``spherecal.models``, ``spherecal.errors``,
``spherecal.linelink``, ``spherecal.lineproto``, ``spherecal.planning``,
``spherecal.exporters``, ``spherecal.geometry``), kept as such: tests/plugins/
test_old_paths.py loads it and checks that it still works, with DeprecationWarnings.

A simulated gantry (it moves the simulated cell's flange where it is told), a simulated
line sensor and an exporter."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

import spherecal.lineproto as lineproto
from spherecal.devices import DeviceContext, RobotType, SensorFieldOfView, SensorType
from spherecal.errors import DeviceError, InputError
from spherecal.exporters import Exporter
from spherecal.geometry import rotvec_from_matrix
from spherecal.linelink import LineLinkSettings, WorkspaceBox
from spherecal.models import Pose, Profile
from spherecal.planning import SweepPlan
from spherecal.plugins import hookimpl

ROBOT = "old_gantry"
SENSOR = "old_line"
EXPORTER = "old_rotvec"

FIELD_OF_VIEW = SensorFieldOfView(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=28.0, width_far_mm=48.0,
                                  standoff_z_mm=-20.0)
#: The plan this plugin's users were told to use.
PLAN = SweepPlan(profiles_per_station=6)


class GantryConfig(LineLinkSettings):
    """The line link's settings (speed limit and workspace box among them)."""

    workspace: WorkspaceBox = Field(default_factory=lambda: WorkspaceBox(min_mm=(-3000.0, -3000.0, -3000.0),
                                                                         max_mm=(3000.0, 3000.0, 3000.0)))


class Gantry:
    def __init__(self, config: GantryConfig, cell):
        self.config, self.cell = config, cell

    def read_flange_pose(self) -> Pose:
        return self.cell.report_pose(self.cell.current_base_from_flange)

    def read_joints_deg(self):
        return None

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        if not 0 < speed_mm_s <= self.config.max_speed_mm_s:
            raise InputError(f"{ROBOT}: speed {speed_mm_s} mm/s outside (0, {self.config.max_speed_mm_s}]")
        if not self.config.workspace.contains(base_from_flange.translation_mm):
            raise InputError(f"{ROBOT}: target outside the workspace box")
        self.cell.move_flange_to(base_from_flange)

    def close(self) -> None:
        pass

    def identity(self) -> dict:
        return {"model": "old gantry", "controller": f"line protocol {lineproto.PROTOCOL_VERSION}"}


class LineSensor:
    def __init__(self, cell):
        self.cell = cell

    def read_profile(self) -> Profile | None:
        points = self.cell.measure_profile()
        return Profile.from_points(points) if len(points) >= 20 else None

    def close(self) -> None:
        pass


class NoSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _rotvec_text(result, settings) -> dict[str, str]:
    rv = np.degrees(rotvec_from_matrix(result.transform.rotation_matrix))
    t = result.transform.translation_mm
    return {f"{result.transform_name}_rotvec.txt": " ".join(f"{v:.6f}" for v in (*t, *rv)) + "\n"}


def _create_robot(config: GantryConfig, context: DeviceContext) -> Gantry:
    if context.cell is None:
        raise DeviceError(f"{ROBOT}: simulated only")
    return Gantry(config, context.cell)


def _create_sensor(config: NoSettings, context: DeviceContext) -> LineSensor:
    if context.cell is None:
        raise DeviceError(f"{SENSOR}: simulated only")
    return LineSensor(context.cell)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_robot(RobotType(name=ROBOT, config_model=GantryConfig, factory=_create_robot))
    registry.add_sensor(SensorType(name=SENSOR, config_model=NoSettings, factory=_create_sensor,
                                   field_of_view=FIELD_OF_VIEW))


@hookimpl
def spherecal_register_exporters(registry) -> None:
    registry.add_exporter(Exporter(name=EXPORTER, description="x y z mm and a rotation vector, deg",
                                   files=("{transform_name}_rotvec.txt",), write=_rotvec_text,
                                   settings_model=NoSettings))
