"""The devices' contract (what a robot and a sensor plugin provide), the protocol-free
motion safety checks and the line protocol both ends share. Imports :mod:`spherecal.core`,
:mod:`spherecal.config` and :mod:`spherecal.io`."""

from spherecal.devices.contract import (
    IDENTITY_KEYS,
    RESERVED_OPTION_NAMES,
    ControllerFrame,
    DeviceContext,
    ProfileStreamCounts,
    ProfileStreamError,
    ProfileStreamingSensor,
    Robot,
    RobotType,
    Sensor,
    SensorBody,
    SensorFieldOfView,
    SensorType,
    device_identity,
)

__all__ = ["IDENTITY_KEYS", "RESERVED_OPTION_NAMES", "ControllerFrame", "DeviceContext", "ProfileStreamCounts",
           "ProfileStreamError", "ProfileStreamingSensor", "Robot", "RobotType", "Sensor", "SensorBody",
           "SensorFieldOfView", "SensorType", "device_identity"]
