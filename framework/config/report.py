"""What the report and the result's provenance say besides the numbers, the ``[report]``
section (:class:`ReportConfig`)."""

from __future__ import annotations

from pydantic import Field

from spherecal.config.base import POINT_DISTANCE_MM, Section


class ReportConfig(Section):
    """What the report and the result's provenance say besides the numbers."""

    operator: str | None = Field(None, max_length=200, description="who ran the calibration (--operator overrides)")
    cell: str | None = Field(None, max_length=200, description="the cell's name or number")
    point_distance_mm: float = Field(
        POINT_DISTANCE_MM, gt=0, le=10_000, description="the report gives the uncertainty of a point this far from the sensor, "
        "mm (along its line of sight)"
    )
