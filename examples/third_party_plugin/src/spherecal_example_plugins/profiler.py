"""Sensor type ``example_profiler``: a simulated laser line sensor.

It reads profiles from a :class:`spherecal.plugins.SimulatedCell`
(``cell.measure_profile()``: points (y, z) in mm in the sensor's laser plane, z positive
towards the sensor) and hands them on as :class:`spherecal.plugins.Profile`, or None
when too few points are valid.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from spherecal.plugins import DeviceContext, DeviceError, Profile, SensorFieldOfView, SensorType, hookimpl

TYPE_NAME = "example_profiler"

#: The profiler's field of view, sensor frame, mm: measuring range z from -60 (far end,
#: line 48 mm wide) to +40 (near end, 28 mm wide); a calibration sweep keeps the sphere's
#: centre at z = -20. The simulated cell measures with it.
FIELD_OF_VIEW = SensorFieldOfView(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=28.0, width_far_mm=48.0,
                                  standoff_z_mm=-20.0)


class ProfilerConfig(BaseModel):
    """Configuration section of an ``example_profiler`` sensor::

        [sensor]
        type = "example_profiler"
        min_points = 20
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    min_points: int = Field(
        20, ge=1, description="fewest valid points a profile must have; fewer gives no profile (points)"
    )
    decimate: int = Field(1, ge=1, le=16, description="keep every n-th point of the line (points)")
    order: Literal["sensor", "ascending_y"] = Field(
        "sensor", description="point order: as the sensor delivers them, or sorted by y (no unit)"
    )


class ExampleProfiler:
    """The :class:`spherecal.plugins.Sensor` of ``example_profiler`` on a simulated cell."""

    def __init__(self, config: ProfilerConfig, cell) -> None:
        self.config = config
        self._cell = cell
        self._open = True

    def read_profile(self) -> Profile | None:
        """One profile at the flange's current pose, or None when the line sees fewer than
        ``min_points`` points."""
        if not self._open:
            raise DeviceError(f"{TYPE_NAME}: the sensor has been closed; create a new one")
        points = self._cell.measure_profile()[:: self.config.decimate]
        if len(points) < self.config.min_points:
            return None
        if self.config.order == "ascending_y":
            points = points[np.argsort(points[:, 0], kind="stable")]
        return Profile.from_points(points)

    def close(self) -> None:
        """Release the sensor. Safe to call twice."""
        self._open = False


def create_sensor(config: ProfilerConfig, context: DeviceContext) -> ExampleProfiler:
    """Factory called by the plugin host with the validated configuration."""
    if context.cell is None:
        raise DeviceError(
            f"{TYPE_NAME} is a simulated sensor and has no hardware to connect to; "
            f"run it on a simulated cell (DeviceContext(cell=spherecal.plugins.standard_cell(fov=...)))"
        )
    return ExampleProfiler(config, context.cell)


@hookimpl
def spherecal_register_devices(registry) -> None:
    registry.add_sensor(
        SensorType(
            name=TYPE_NAME,
            config_model=ProfilerConfig,
            factory=create_sensor,
            description="simulated laser line sensor (example plugin)",
            field_of_view=FIELD_OF_VIEW,
        )
    )
