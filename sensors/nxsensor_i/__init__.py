"""NextWare nxSensor-I laser line sensor plugin.

Modules: :mod:`.wire` (the assumed USB wire format, all of it configuration),
:mod:`.config` (:class:`NxSensorConfig`), :mod:`.driver` (:class:`NxSensorDriver`, pyusb),
:mod:`.simbackend` (:class:`SimulatedNxSensorBackend`, a simulated device behind a real
pyusb backend), :mod:`.plugin` (registration). See ``docs/sensor-nxsensor-i.md``.
"""

from .config import NxSensorConfig
from .driver import NxSensorDriver, StreamedProfile
from .simbackend import SimulatedNxSensorBackend
from .wire import Frame, FrameFormatError, WireConfig

__all__ = [
    "Frame",
    "FrameFormatError",
    "NxSensorConfig",
    "NxSensorDriver",
    "SimulatedNxSensorBackend",
    "StreamedProfile",
    "WireConfig",
]
