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

The lifecycle hooks (``spherecal_observation_taken``, ``spherecal_acquisition_finished``,
``spherecal_calibration_finished``) are called for every run, whatever its devices, and
tell which: ``robot_type`` and ``sensor_type`` are the configured type names (``"abb_irb2400"``),
so a robot or sensor plugin acts on its own runs only (``if robot_type != NAME: return``)
without reading the dataset's free-form provenance.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from spherecal.plugins.markers import hookspec

if TYPE_CHECKING:  # pragma: no cover - imports for the annotations only
    from pathlib import Path

    from spherecal.core.models import CalibrationResult, Dataset, Observation

    from .registry import DeviceRegistry, ExporterRegistry


@hookspec
def spherecal_register_devices(registry: "DeviceRegistry") -> None:
    """Add the robot and sensor types this plugin provides.

    :param registry: the host's device registry. Call
        ``registry.add_robot(RobotType(...))`` and ``registry.add_sensor(SensorType(...))``
        (both from :mod:`spherecal.plugins`) once per type.
    :return: nothing; the return value is ignored.

    Called once per plugin, while the host is being built, after every plugin has been
    loaded and checked and before any configuration is validated.

    A type name must be unique across all installed plugins: registering a name another
    plugin already registered is a :class:`~spherecal.core.errors.PluginError` naming both
    plugins. Each type's ``config_model`` must be a pydantic model with
    ``extra="forbid"`` and without a field called ``type`` (``type`` selects the device in
    a configuration section). An exception raised here is reported as a
    :class:`~spherecal.core.errors.PluginError` naming the plugin; the host is then not built.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_register_exporters(registry: "ExporterRegistry") -> None:
    """Add the exporters this plugin provides.

    :param registry: the host's exporter registry. Call
        ``registry.add_exporter(Exporter(...))`` (:class:`spherecal.plugins.Exporter`)
        once per exporter: its name, the files it writes (templates such as
        ``"{module_name}.mod"``), a pure ``write(result, settings)`` returning their text,
        its settings model (validated from ``[export.<name>]``), the mounting modes and
        robot types it applies to, and optionally a ``note`` for the report (how to use
        the files on the controller).
    :return: nothing; the return value is ignored.

    Called once per plugin, while the host is being built, after
    ``spherecal_register_devices``. An exporter name must be unique across all installed
    plugins, lower case letters, digits and underscores, and not ``run``; its
    ``settings_model`` must be a pydantic model with ``extra="forbid"``; its file-name
    templates may use only ``{transform_name}``, ``{mounting}`` and the settings' fields.
    Anything else is a :class:`~spherecal.core.errors.PluginError` naming the plugin; the host
    is then not built.

    Which exporters run is the user's choice (``[export] run``, default every one that
    applies to the run's mounting and robot type; docs/configuration.md); the files are
    written by the core into the output folder, never by the exporter.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_observation_taken(observation: "Observation", robot_type: "str | None",
                                sensor_type: "str | None") -> None:
    """Be told about each observation as soon as it has been acquired.

    :param observation: the new :class:`spherecal.core.models.Observation`: the flange pose as
        the robot reported it (``base_from_flange``, quaternion (w, x, y, z)), the joints
        if any (degrees, controller convention) and the profile (y, z in mm, sensor frame).
        It is frozen; do not try to change it.
    :param robot_type: the run's robot type name (``[robot] type``), None when not known.
    :param sensor_type: the run's sensor type name (``[sensor] type``), None when not known.
    :return: nothing; the return value is ignored.

    Called by the acquisition once per shot that produced a profile, in acquisition order,
    while the robot stands at that pose. Keep it quick (it holds up the acquisition). Use
    it for live display, logging or an external record of the acquisition. An exception
    raised here stops the acquisition with a :class:`~spherecal.core.errors.PluginError` naming
    the plugin.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_acquisition_finished(dataset: "Dataset", robot_type: "str | None", sensor_type: "str | None") -> None:
    """Be told that an acquisition is complete, before the calibration runs.

    :param dataset: the complete :class:`spherecal.core.models.Dataset` (mounting mode, sphere
        radius in mm, every observation in order, provenance).
    :param robot_type: the run's robot type name, None when not known.
    :param sensor_type: the run's sensor type name, None when not known.
    :return: nothing; the return value is ignored.

    Called once per acquisition, after the last observation and before the dataset is
    written or calibrated. Not called when the acquisition fails. An exception raised here
    is a :class:`~spherecal.core.errors.PluginError` naming the plugin.

    No spec flags: every plugin's implementation is called.
    """


@hookspec
def spherecal_calibration_finished(
    result: "CalibrationResult",
    dataset: "Dataset",
    out_dir: "Path | None",
    exports_written: bool,
    robot_type: "str | None",
    sensor_type: "str | None",
) -> None:
    """Be told the result of a calibration, once its files are written.

    :param result: the :class:`spherecal.core.models.CalibrationResult`: ``transform`` is
        ``flange_from_sensor`` (eye-in-hand) or ``base_from_sensor`` (eye-to-hand) as its
        ``transform_name`` says, quaternion (w, x, y, z), mm; with uncertainties and
        residuals.
    :param dataset: the :class:`spherecal.core.models.Dataset` it was estimated from.
    :param out_dir: the run's output folder (a :class:`pathlib.Path`), holding
        ``result.json``, the exports and ``report.html``; a plugin may write files of its
        own there (choose names no exporter uses, and do not overwrite). None when the
        caller wrote no files (a calibration run from Python).
    :param exports_written: whether ``result.json`` and the exports were written: False
        for a RED result without ``--force`` (docs/results.md), which must not be used;
        a plugin that pushes the result to a controller must then do nothing.
    :param robot_type: the run's robot type name (``[robot] type``, or for ``spherecal
        solve`` ``--robot`` or the dataset's provenance), None when not known.
    :param sensor_type: the run's sensor type name, None when not known.
    :return: nothing; the return value is ignored.

    Called once per calibration by ``spherecal calibrate`` and ``spherecal solve``, after
    the result, the exports and the report are written. For a file format every run
    should have, register an exporter instead (``spherecal_register_exporters``): the user
    can then choose it and set it up in ``[export]``. An exception raised here is a
    :class:`~spherecal.core.errors.PluginError` naming the plugin.

    No spec flags: every plugin's implementation is called. An implementation may take any
    subset of the arguments, so one written for ``(result, dataset)`` keeps working.
    """
