"""NextWare nxSensor-I laser line sensor plugin.

Modules: :mod:`.wire` (the assumed USB wire format, all of it configuration),
:mod:`.config` (:class:`NxSensorConfig`), :mod:`.driver` (:class:`NxSensorDriver`, pyusb),
:mod:`.shots` (which frame is which trigger's), :mod:`.stamps` and :mod:`.streaming` (a
stream's frames on the sensor's clock, its reader thread), :mod:`.simbackend`
(:class:`SimulatedNxSensorBackend`, a simulated device behind a real pyusb backend) with
:mod:`.simstream` (its simulated time), :mod:`.plugin` (registration). See
``docs/sensor-nxsensor-i.md``.
"""

from spherecal.plugins import lazy_attributes

from .config import NxSensorConfig
from .wire import Frame, FrameFormatError, WireConfig

#: Names imported on first use (PEP 562): the driver (and pyusb) and the simulated
#: backend load when a sensor is opened, not when the plugin registers itself.
_LAZY = {"NxSensorDriver": ".driver", "SimulatedNxSensorBackend": ".simbackend", "SensorClock": ".simstream",
         "SimTime": ".simstream", "cell_source": ".simstream"}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)

__all__ = [
    "Frame",
    "FrameFormatError",
    "NxSensorConfig",
    "NxSensorDriver",
    "SensorClock",
    "SimTime",
    "SimulatedNxSensorBackend",
    "WireConfig",
    "cell_source",
]
