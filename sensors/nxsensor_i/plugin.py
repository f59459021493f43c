"""Registers the NextWare nxSensor-I with spherecal (entry point ``nxsensor_i``).

With a simulated cell in the device context, the factory puts
:class:`~spherecal.sensors.nxsensor_i.simbackend.SimulatedNxSensorBackend` over that cell
under the real driver, so simulated runs exercise the same pyusb code path as the
hardware; otherwise pyusb's default backend (libusb-1.0) is used. A simulated stream runs
on the backend's own simulated time (moved by ``backend.advance_s``) at the cell's current
pose, unless the context's ``extras`` give the simulated time, the sensor's clock and the
profile source (``spherecal.plugins.SIM_NOW_KEY``, ``SIM_SENSOR_CLOCK_KEY``,
``SIM_PROFILE_SOURCE_KEY``).
"""

from __future__ import annotations

import importlib.util
from typing import TYPE_CHECKING

# The ``DeviceContext.extras`` keys a simulated run sets to drive the simulated device's
# stream (docs/sensor-nxsensor-i.md, "Simulation"): the simulated time now, the sensor's
# clock, the profile at a true time.
from spherecal.plugins import (SIM_NOW_KEY, SIM_PROFILE_SOURCE_KEY, SIM_SENSOR_CLOCK_KEY, DeviceContext, DeviceError,
                               SensorBody, SensorFieldOfView, SensorType, hookimpl)

from .config import NxSensorConfig

if TYPE_CHECKING:
    from .driver import NxSensorDriver

# The driver (and pyusb) and the simulated USB backend are imported when a sensor is
# opened: commands that only read files (`solve`, `plugins`) do not load them. Without
# pyusb installed the plugin does not load at all, as when it imported the driver here,
# so that every command says so at once (finding it costs no import).
if importlib.util.find_spec("usb") is None:
    raise ImportError("the nxsensor_i plugin needs pyusb, which is not installed: pip install pyusb")

NAME = "nxsensor_i"

#: The nxSensor-I's measuring range (NextWare's data, docs/sensor-nxsensor-i.md): z from
#: -60 mm (far end, line 48 mm wide) to +40 mm (near end, 28 mm), sensor frame; a
#: calibration sweep keeps the sphere's centre at z = -20 mm, so that its visible cap
#: (radius 19.1 mm) and the sweep's wander stay inside the range at every station offset.
FIELD_OF_VIEW = SensorFieldOfView(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=28.0, width_far_mm=48.0,
                                  standoff_z_mm=-20.0)

#: The nxSensor-I's housing as a box in the sensor frame, for the keep-out check before
#: motion. An ASSUMPTION: NextWare's data give no dimensions (docs/sensor-nxsensor-i.md).
#: Assumed: about 130 x 70 x 85 mm, its camera beside the laser along x (the laser
#: plane's normal), x -100..+30 and y -35..+35, and its window 40 mm above the near end of
#: the range (z +80..+165): profilers of this class leave several centimetres between
#: window and range, and the lower end errs on the safe side. Measure the real unit and
#: give its box in [keep_out.sensor_body].
BODY = SensorBody(min_mm=(-100.0, -35.0, 80.0), max_mm=(30.0, 35.0, 165.0))


def create_sensor(config: NxSensorConfig, context: DeviceContext) -> NxSensorDriver:
    """Factory: a connected :class:`NxSensorDriver`. Raises
    :class:`spherecal.plugins.DeviceError` when no USB backend is available or the device
    is not found (the message says which vid:pid was looked for and what to check)."""
    try:
        from .driver import NxSensorDriver
        from .simbackend import SimulatedNxSensorBackend
    except ImportError as exc:  # pyusb found but broken: stop before the run goes on
        raise DeviceError(f"nxsensor_i: the USB driver cannot be loaded ({exc}); reinstall pyusb "
                          "(pip install --force-reinstall pyusb)") from exc

    if context.cell is not None:
        extras = context.extras
        backend = SimulatedNxSensorBackend(
            context.cell, wire=config.wire, serial_number=config.serial_number or "NXS-SIM-0001",
            now_s=extras.get(SIM_NOW_KEY), clock=extras.get(SIM_SENSOR_CLOCK_KEY),
            source=extras.get(SIM_PROFILE_SOURCE_KEY),
        )
        # the stall limit of a stream runs on simulated time, as the simulated device's frames do
        return NxSensorDriver(config, backend=backend, log=context.log, host_clock_s=backend.now_s)
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
            field_of_view=FIELD_OF_VIEW,
            body=BODY,
        )
    )
