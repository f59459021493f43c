"""The field of view of a laser line sensor: a value object the sensor plugins declare,
the simulated cell measures with and the planners aim with."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class SensorFieldOfView(BaseModel):
    """The field of view of a laser line sensor, in its own frame (mm): the laser plane is
    its x = 0 plane, the line spans y, and it measures along z, looking towards -z (the
    near end has the larger z). The line's width grows linearly from ``width_near_mm`` at
    ``z_near_mm`` to ``width_far_mm`` at ``z_far_mm`` (a fan from an apex on the z axis).

    A sensor type declares its own (``SensorType.field_of_view``, :mod:`spherecal.plugins`); the simulated cell
    measures with it and the planner puts the sphere at :attr:`sweep_standoff_z_mm`. A
    configuration's ``[simulation.fov]`` overrides any of its fields."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    z_near_mm: float = Field(description="near end of the measuring range (z, mm)")
    z_far_mm: float = Field(description="far end of the measuring range (z, mm), below z_near_mm")
    width_near_mm: float = Field(gt=0, description="line width at the near end, mm")
    width_far_mm: float = Field(gt=0, description="line width at the far end, mm, more than width_near_mm")
    n_columns: int = Field(640, ge=16, le=100_000, description="points across the full line (simulation)")
    standoff_z_mm: float | None = Field(
        None, description="z of the sphere centre in a calibration sweep, mm (default: sized for the configured "
        "sphere, spherecal.motion.planning.sphere_standoff_z_mm; the middle of the range for a sphere of unknown size)")

    @model_validator(mode="after")
    def _a_fan(self):
        if not self.z_far_mm < self.z_near_mm:
            raise ValueError(f"z_far_mm ({self.z_far_mm}) must be below z_near_mm ({self.z_near_mm}): the sensor "
                             "looks towards -z")
        if not self.width_far_mm > self.width_near_mm:
            raise ValueError(f"width_far_mm ({self.width_far_mm}) must exceed width_near_mm ({self.width_near_mm}): "
                             "the line widens away from the sensor")
        if self.standoff_z_mm is not None and not self.z_far_mm <= self.standoff_z_mm <= self.z_near_mm:
            raise ValueError(f"standoff_z_mm ({self.standoff_z_mm}) must lie in the measuring range "
                             f"[{self.z_far_mm}, {self.z_near_mm}]")
        return self

    @property
    def middle_z_mm(self) -> float:
        """The middle of the measuring range (z, mm): where a flat surface is swept."""
        return (self.z_near_mm + self.z_far_mm) / 2

    @property
    def sweep_standoff_z_mm(self) -> float:
        """z of the sphere centre in a sweep (mm): ``standoff_z_mm``, else the middle (for a
        sphere of known radius the planner sizes it: :func:`spherecal.motion.planning.sphere_standoff_z_mm`)."""
        return self.middle_z_mm if self.standoff_z_mm is None else self.standoff_z_mm

    def width_at_mm(self, z_mm: float) -> float:
        """The line's width at sensor-frame z ``z_mm`` (mm), on the straight line through
        the two declared widths."""
        return self.width_near_mm + (self.width_far_mm - self.width_near_mm) * (self.z_near_mm - z_mm) / (
            self.z_near_mm - self.z_far_mm)

    @property
    def apex_z_mm(self) -> float:
        """z of the fan's apex, where the line width extrapolates to zero."""
        slope = (self.width_far_mm - self.width_near_mm) / 2 / (self.z_near_mm - self.z_far_mm)
        return self.z_near_mm + self.width_near_mm / 2 / slope

    @property
    def half_angle_rad(self) -> float:
        slope = (self.width_far_mm - self.width_near_mm) / 2 / (self.z_near_mm - self.z_far_mm)
        return float(np.arctan(slope))


class SensorBody(BaseModel):
    """The sensor's housing as a box in its own frame (mm), for the keep-out check before
    motion (:mod:`spherecal.core.keep_out`): no planned pose or move may bring it closer
    than a clearance to the reference sphere or what holds it. A box that holds the whole
    housing (window, connectors, cable gland, bracket if it moves with the sensor) errs
    on the safe side.

    A sensor type declares its own (``SensorType.body``, :mod:`spherecal.plugins`); a
    configuration's ``[keep_out.sensor_body]`` replaces it. The sensor looks towards -z,
    so a housing lies at z above the near end of the measuring range."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    min_mm: tuple[float, float, float] = Field(description="lower corner (x, y, z), sensor frame, mm")
    max_mm: tuple[float, float, float] = Field(description="upper corner (x, y, z), sensor frame, mm")

    @model_validator(mode="after")
    def _ordered(self):
        for axis, lo, hi in zip("xyz", self.min_mm, self.max_mm):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"min_mm {axis} = {lo} must be below max_mm {axis} = {hi} (finite, mm)")
        return self

    def overlap_with_range(self, fov: SensorFieldOfView) -> bool:
        """Whether the box reaches into the measuring range of ``fov`` (the laser plane x =
        0 between its far and near ends, within the line's width): a housing there would
        be in its own view, which is a box given with the wrong sign of z."""
        (x0, y0, z0), (x1, y1, z1) = self.min_mm, self.max_mm
        half = max(fov.width_near_mm, fov.width_far_mm) / 2
        return x0 < 0 < x1 and z0 < fov.z_near_mm and z1 > fov.z_far_mm and y0 < half and y1 > -half
