"""NextWare nxSensor-I laser line sensor plugin.

Modules: :mod:`.wire` (the assumed USB wire format, all of it configuration),
:mod:`.config` (:class:`NxSensorConfig`), :mod:`.driver` (:class:`NxSensorDriver`, pyusb),
:mod:`.simbackend` (:class:`SimulatedNxSensorBackend`, a simulated device behind a real
pyusb backend), :mod:`.plugin` (registration). See ``docs/sensor-nxsensor-i.md``.
"""

from .config import NxSensorConfig
from .wire import Frame, FrameFormatError, WireConfig

#: Names imported on first use (PEP 562): the driver (and pyusb) and the simulated
#: backend load when a sensor is opened, not when the plugin registers itself.
_LAZY = {"NxSensorDriver": ".driver", "StreamedProfile": ".driver", "SimulatedNxSensorBackend": ".simbackend"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})

__all__ = [
    "Frame",
    "FrameFormatError",
    "NxSensorConfig",
    "NxSensorDriver",
    "SimulatedNxSensorBackend",
    "StreamedProfile",
    "WireConfig",
]
