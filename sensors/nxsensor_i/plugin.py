"""Registers the NextWare nxSensor-I with spherecal (entry point ``nxsensor_i``).

With a simulated cell in the device context, the factory puts
:class:`~spherecal.sensors.nxsensor_i.simbackend.SimulatedNxSensorBackend` over that cell
under the real driver, so simulated runs exercise the same pyusb code path as the
hardware; otherwise pyusb's default backend (libusb-1.0) is used.
"""

from __future__ import annotations

from spherecal.devices import DeviceContext, SensorType
from spherecal.plugins import hookimpl

from .config import NxSensorConfig
from .driver import NxSensorDriver
from .simbackend import SimulatedNxSensorBackend

NAME = "nxsensor_i"


def create_sensor(config: NxSensorConfig, context: DeviceContext) -> NxSensorDriver:
    """Factory: a connected :class:`NxSensorDriver`. Raises
    :class:`spherecal.errors.DeviceError` when no USB backend is available or the device
    is not found (the message says which vid:pid was looked for and what to check)."""
    if context.cell is not None:
        backend = SimulatedNxSensorBackend(
            context.cell, wire=config.wire, serial_number=config.serial_number or "NXS-SIM-0001"
        )
        return NxSensorDriver(config, backend=backend, log=context.log)
    return NxSensorDriver(config, backend=None, log=context.log)


@hookimpl
def spherecal_register_devices(registry):
    registry.add_sensor(
        SensorType(
            name=NAME,
            config_model=NxSensorConfig,
            factory=create_sensor,
            description="NextWare nxSensor-I laser line sensor over USB (pyusb); z -60 .. +40 mm, 5 um "
            "resolution. The USB wire format is an assumption held in sensor.wire.",
        )
    )
