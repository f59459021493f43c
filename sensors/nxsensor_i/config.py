"""Configuration of the nxSensor-I plugin (the ``sensor`` section when ``type = "nxsensor_i"``)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .wire import WireConfig


class NxSensorConfig(BaseModel):
    """Settings of one nxSensor-I. ``wire`` holds the assumed USB protocol (see
    :mod:`spherecal.sensors.nxsensor_i.wire`); the rest are acquisition settings."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    wire: WireConfig = Field(default_factory=WireConfig, description="assumed USB wire format (ids, endpoints, framing, scaling)")
    serial_number: str | None = Field(
        None, min_length=1, max_length=126,
        description="USB serial number string of the unit to open; None opens the first unit with the configured ids",
    )
    timeout_ms: int = Field(1000, ge=1, le=60_000, description="time limit of one USB transfer, ms")
    exposure_us: int = Field(200, ge=1, le=1_000_000, description="laser exposure time, microseconds")
    rate_hz: float = Field(100.0, gt=0, le=10_000, description="profile rate while streaming, Hz (frame period 1e6/rate us)")
    retries: int = Field(
        1, ge=0, le=5,
        description="attempts after a timeout, stall, corrupt frame or disconnect before the error is raised (count)",
    )

    stall_timeout_ms: int = Field(
        500, ge=1, le=60_000,
        description="a profile stream that brings no frame for this long ends with an error, ms of the host's clock "
        "(must exceed two frame periods)",
    )
    late_after_periods: float = Field(
        0.5, gt=0, le=100,
        description="a streamed frame stamped more than this many frame periods after its slot is counted late "
        "(periods)",
    )
    clock_jump_periods: float = Field(
        4.0, gt=0, le=1000,
        description="a streamed frame stamped more than this many frame periods after its slot is a jump of the "
        "sensor's clock, which ends the stream (periods; above late_after_periods)",
    )

    @model_validator(mode="after")
    def _stream_limits(self):
        if self.stall_timeout_ms <= 2 * self.period_us / 1000:
            raise ValueError(
                f"stall_timeout_ms = {self.stall_timeout_ms} ms must exceed two frame periods of rate_hz = "
                f"{self.rate_hz} Hz ({2 * self.period_us / 1000:g} ms); raise stall_timeout_ms"
            )
        if self.late_after_periods >= self.clock_jump_periods:
            raise ValueError(
                f"late_after_periods = {self.late_after_periods} must be below clock_jump_periods = "
                f"{self.clock_jump_periods}"
            )
        return self

    @model_validator(mode="after")
    def _exposure_fits_period(self):
        period_us = 1e6 / self.rate_hz
        if self.exposure_us >= period_us:
            raise ValueError(
                f"exposure_us = {self.exposure_us} us does not fit the frame period of rate_hz = {self.rate_hz} Hz "
                f"({period_us:.0f} us); lower exposure_us or rate_hz"
            )
        return self

    @property
    def period_us(self) -> int:
        """Frame period while streaming, microseconds."""
        return max(1, round(1e6 / self.rate_hz))
