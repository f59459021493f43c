"""Hook specifications: every hook a spherecal plugin can implement.

This module is the whole contract between the host and its plugins. A plugin is a
module (or any object) with functions named like the hooks below, marked with
:data:`spherecal.plugins.hookimpl`. The host (:class:`spherecal.plugins.host.PluginHost`)
calls them with **keyword arguments only**, so an implementation may accept any subset
of a hook's arguments, in any order, and new arguments can be added to a hook later
without breaking existing plugins.

Any function whose name starts with ``spherecal_`` in a registered plugin is taken as an
implementation, marked or not, and must match a hook here: a misspelled name is an error
that names the plugin and the hook, never a silently ignored function.

Spec flags used below (see pluggy's documentation for the full list):

- ``firstresult``: the call stops at the first implementation that returns something
  other than None and that value is the result. None of the current hooks set it.
- ``historic``: implementations registered late are called with the arguments of earlier
  calls. None of the current hooks set it; the host is built once per run, so every plugin
  is registered before the first call.

Without flags every implementation is called (most recently registered first) and the
host ignores what they return: all hooks here are notifications or registrations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from . import hookspec

if TYPE_CHECKING:  # pragma: no cover - imports for the annotations only
    from spherecal.models import CalibrationResult, Dataset, Observation

    from .host import DeviceRegistry


@hookspec
def spherecal_register_devices(registry: "DeviceRegistry") -> None:
    """Add the robot and sensor types this plugin provides.

    :param registry: the host's device registry. Call
        ``registry.add_robot(RobotType(...))`` and ``registry.add_sensor(SensorType(...))``
        (both from :mod:`spherecal.devices`) once per type.
    :return: nothing; the return value is ignored.

    Called once per plugin, while the host is being built, after every plugin has been
    loaded and checked and before any configuration is validated.

    A type name must be unique across all installed plugins: registering a name another
    plugin already registered is a :class:`~spherecal.errors.PluginError` naming both
    plugins. Each type's ``config_model`` must be a pydantic model with
    ``extra="forbid"`` and without a field called ``type`` (``type`` selects the device in
    a configuration section). An exception raised here is reported as a
    :class:`~spherecal.errors.PluginError` naming the plugin; the host is then not built.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_observation_taken(observation: "Observation") -> None:
    """Be told about each observation as soon as it has been acquired.

    :param observation: the new :class:`spherecal.models.Observation`: the flange pose as
        the robot reported it (``base_from_flange``, quaternion (w, x, y, z)), the joints
        if any (degrees, controller convention) and the profile (y, z in mm, sensor frame).
        It is frozen; do not try to change it.
    :return: nothing; the return value is ignored.

    Called by the acquisition once per shot that produced a profile, in acquisition order,
    while the robot stands at that pose. Keep it quick (it holds up the acquisition). Use
    it for live display, logging or an external record of the acquisition. An exception
    raised here stops the acquisition with a :class:`~spherecal.errors.PluginError` naming
    the plugin.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_acquisition_finished(dataset: "Dataset") -> None:
    """Be told that an acquisition is complete, before the calibration runs.

    :param dataset: the complete :class:`spherecal.models.Dataset` (mounting mode, sphere
        radius in mm, every observation in order, provenance).
    :return: nothing; the return value is ignored.

    Called once per acquisition, after the last observation and before the dataset is
    written or calibrated. Not called when the acquisition fails. An exception raised here
    is a :class:`~spherecal.errors.PluginError` naming the plugin.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_calibration_finished(result: "CalibrationResult", dataset: "Dataset") -> None:
    """Be told the result of a calibration.

    :param result: the :class:`spherecal.models.CalibrationResult`: ``transform`` is
        ``flange_from_sensor`` (eye-in-hand) or ``base_from_sensor`` (eye-to-hand) as its
        ``transform_name`` says, quaternion (w, x, y, z), mm; with uncertainties and
        residuals.
    :param dataset: the :class:`spherecal.models.Dataset` it was estimated from.
    :return: nothing; the return value is ignored.

    Called once per successful calibration, after the estimator returned and before the
    result is written. Use it to export the result in another format or to push it to a
    controller. An exception raised here is a :class:`~spherecal.errors.PluginError`
    naming the plugin.

    No spec flags: every plugin's implementation is called.
    """
