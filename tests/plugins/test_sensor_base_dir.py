"""``create_sensor`` hands the configuration's folder to the sensor's model, as
``create_robot`` does for the robot's: a relative path in a sensor section (a calibration
table, a parameter file) resolves against it; calls without it keep working."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from spherecal.devices.contract import DeviceContext, SensorType
from spherecal.plugins import BASE_DIR_CONTEXT_KEY, hookimpl
from spherecal.plugins.host import PluginHost


class TableSensorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    table: Path

    @field_validator("table")
    @classmethod
    def _resolve(cls, v: Path, info: ValidationInfo) -> Path:
        base = (info.context or {}).get(BASE_DIR_CONTEXT_KEY)
        return Path(base) / v if base is not None and not v.is_absolute() else v


class TableSensor:
    def __init__(self, config):
        self.config = config

    def read_profile(self):
        return None

    def close(self):
        pass


class Plugin:
    @staticmethod
    @hookimpl
    def spherecal_register_devices(registry):
        registry.add_sensor(SensorType(name="table_sensor", config_model=TableSensorConfig,
                                       factory=lambda c, ctx: TableSensor(c)))


def test_create_sensor_resolves_against_the_configuration_folder(tmp_path):
    host = PluginHost(plugins=[("table", Plugin)], load_entry_points=False)
    section = {"type": "table_sensor", "table": "cal/table.csv"}
    sensor = host.create_sensor(section, DeviceContext(), base_dir=tmp_path)
    assert sensor.config.table == tmp_path / "cal" / "table.csv"
    # the old calls: no folder known, the path as given
    assert host.create_sensor(section).config.table == Path("cal/table.csv")
    assert host.create_sensor(section, DeviceContext(), "sensor").config.table == Path("cal/table.csv")
