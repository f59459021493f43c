"""In-test plugin modules for the plugin-host tests."""

from __future__ import annotations

import types

from pydantic import BaseModel, ConfigDict, Field

from spherecal.devices.contract import RobotType, SensorType
from spherecal.plugins import hookimpl


class ToyRobotConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    speed_mm_s: float = Field(100.0, gt=0, description="speed, mm/s")


class ToySensorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    exposure_us: int = Field(200, ge=1, description="exposure, us")


class ToyRobot:
    def __init__(self, config):
        self.config = config

    def read_flange_pose(self):
        from spherecal.core.models import Pose

        return Pose.identity()

    def read_joints_deg(self):
        return None

    def move_linear(self, base_from_flange, speed_mm_s):
        pass

    def close(self):
        pass


class ToySensor:
    def read_profile(self):
        return None

    def close(self):
        pass


def make_plugin(module_name: str, *, robots=(), sensors=(), **functions) -> types.ModuleType:
    """A plugin module registering toy robot/sensor types with the given names, plus any
    extra module-level functions (hooks, misspelled hooks...)."""
    mod = types.ModuleType(module_name)

    if robots or sensors:

        @hookimpl
        def spherecal_register_devices(registry):
            for name in robots:
                registry.add_robot(RobotType(name=name, config_model=ToyRobotConfig,
                                             factory=lambda c, ctx: ToyRobot(c), description=f"toy robot {name}"))
            for name in sensors:
                registry.add_sensor(SensorType(name=name, config_model=ToySensorConfig,
                                               factory=lambda c, ctx: ToySensor(), description=f"toy sensor {name}"))

        mod.spherecal_register_devices = spherecal_register_devices
    for name, fn in functions.items():
        setattr(mod, name, fn)
    return mod


