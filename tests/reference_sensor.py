"""The sensor the tests' simulated cells measure with.

The simulator knows no sensor: a cell is given the field of view of the sensor it
simulates. The tests' cells use the nxSensor-I's, read from its sensor type through the
plugin host as a run reads it (``spherecal.app.cell.sensor_field_of_view``); the reference
results under tests/estimation/data were made with it. This module is the one place the tests
name it. (It is importable from every test folder: pytest puts tests/ on the path for
tests/conftest.py. Outside pytest, put it there yourself: ``PYTHONPATH=tests``.)
"""

from __future__ import annotations

from functools import cache

#: The registered name of the tests' reference sensor type.
REFERENCE_SENSOR = "nxsensor_i"


@cache
def _declared():
    from spherecal.plugins.host import PluginHost

    # built-ins only: an installed third-party plugin must not change the tests' cells
    fov = PluginHost(autoload=False).registry.sensor_type(REFERENCE_SENSOR).field_of_view
    assert fov is not None, f"sensor type {REFERENCE_SENSOR!r} declares no field of view"
    return fov


def reference_fov(**update):
    """The reference sensor's declared :class:`~spherecal.devices.contract.SensorFieldOfView`,
    with the fields in ``update`` replaced (``reference_fov(n_columns=160)``)."""
    fov = _declared()
    return fov.model_copy(update=update) if update else fov
