"""The registries a plugin adds to: robot and sensor types (:class:`DeviceRegistry`,
handed to ``spherecal_register_devices``) and exporters (:class:`ExporterRegistry`,
handed to ``spherecal_register_exporters``). Each checks what it is given and knows which
plugin registered what; the host (:mod:`spherecal.plugins.host`) fills and reads them."""

from __future__ import annotations

import difflib
import re
import types
from typing import Any, Literal, Mapping

from pydantic import BaseModel

from spherecal.core.errors import ConfigError, PluginError
from spherecal.devices.contract import RESERVED_OPTION_NAMES, RobotType, SensorBody, SensorType
from spherecal.io.exporters import MOUNTINGS, TEMPLATE_FIELDS, Exporter

__all__ = ["DISABLE_AUTOLOAD_ENV", "EXPORT_RUN_KEY", "TYPE_KEY", "DeviceKind", "DeviceRegistry", "ExporterRegistry"]

#: Environment variable that turns off autoloading of third-party plugins (named in the
#: registries' messages when a type is unknown).
DISABLE_AUTOLOAD_ENV = "SPHERECAL_DISABLE_PLUGIN_AUTOLOAD"
#: Key of a configuration section that selects the device type.
TYPE_KEY = "type"
#: The key of ``[export]`` that lists the exporters to run (so no exporter may be called so).
EXPORT_RUN_KEY = "run"

_TYPE_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_FRAME_OPTION_RE = re.compile(r"^[a-z][a-z0-9-]*$")

DeviceKind = Literal["robot", "sensor"]


# ---------------------------------------------------------------------------------------
# Registry (handed to spherecal_register_devices)
# ---------------------------------------------------------------------------------------
class DeviceRegistry:
    """Robot and sensor types by name, and which plugin provided each.

    Plugins add to it from ``spherecal_register_devices(registry)`` with
    :meth:`add_robot` and :meth:`add_sensor`; the host looks types up with
    :meth:`robot_type` and :meth:`sensor_type`."""

    def __init__(self) -> None:
        self._robots: dict[str, RobotType] = {}
        self._sensors: dict[str, SensorType] = {}
        self._provider: dict[tuple[str, str], str] = {}
        self._current_plugin: str | None = None
        #: Third-party entry points installed but not loaded (autoload off), for messages.
        self.not_loaded: tuple[str, ...] = ()

    # used by plugins -------------------------------------------------------------------
    def add_robot(self, robot_type: RobotType) -> None:
        """Register a :class:`~spherecal.devices.contract.RobotType`. Its name must be new."""
        self._add("robot", robot_type, RobotType, self._robots)

    def add_sensor(self, sensor_type: SensorType) -> None:
        """Register a :class:`~spherecal.devices.contract.SensorType`. Its name must be new."""
        self._add("sensor", sensor_type, SensorType, self._sensors)

    # used by the host ------------------------------------------------------------------
    @property
    def robots(self) -> Mapping[str, RobotType]:
        return types.MappingProxyType(self._robots)

    @property
    def sensors(self) -> Mapping[str, SensorType]:
        return types.MappingProxyType(self._sensors)

    def provider(self, kind: DeviceKind, name: str) -> str:
        """Name of the plugin that registered the type."""
        return self._provider[(kind, name)]

    def robot_type(self, name: str, path: str = "robot.type") -> RobotType:
        """The robot type called ``name``; a :class:`ConfigError` listing the installed
        ones if there is none."""
        return self._lookup("robot", name, self._robots, path)

    def sensor_type(self, name: str, path: str = "sensor.type") -> SensorType:
        """The sensor type called ``name``; a :class:`ConfigError` listing the installed
        ones if there is none."""
        return self._lookup("sensor", name, self._sensors, path)

    # internals -------------------------------------------------------------------------
    def _lookup(self, kind: DeviceKind, name: Any, table: dict, path: str):
        if isinstance(name, str) and name in table:
            return table[name]
        available = ", ".join(sorted(table)) or "none"
        hint = ""
        if isinstance(name, str):
            close = difflib.get_close_matches(name, list(table), n=1)
            if close:
                hint = f" Did you mean '{close[0]}'?"
        if self.not_loaded:
            advice = (
                f"Third-party plugins are not loaded because {DISABLE_AUTOLOAD_ENV} is set (installed but not "
                f"loaded: {', '.join(self.not_loaded)}): if one of them provides it, unset {DISABLE_AUTOLOAD_ENV} "
                f"or enable that plugin by name (PluginHost(enable=[...]))."
            )
        else:
            advice = "Fix the name, or install the plugin that provides it (list them with `spherecal plugins`)."
        raise ConfigError(f"{path}: unknown {kind} type {name!r}; installed {kind} types: {available}.{hint} {advice}")

    def _add(self, kind: DeviceKind, item: Any, cls: type, table: dict) -> None:
        plugin = self._current_plugin or "<unknown plugin>"
        method = f"registry.add_{kind}"
        if not isinstance(item, cls):
            raise PluginError(
                f"plugin '{plugin}' passed {type(item).__name__} to {method}(); "
                f"expected a spherecal.plugins.{cls.__name__}"
            )
        name = item.name
        if not isinstance(name, str) or not _TYPE_NAME_RE.match(name):
            raise PluginError(
                f"plugin '{plugin}' registered a {kind} type named {name!r}; a type name must be "
                f"lower case letters, digits and underscores, starting with a letter (e.g. 'abb_irb2400')"
            )
        model = item.config_model
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            raise PluginError(
                f"plugin '{plugin}': {kind} type '{name}' has config_model {model!r}; "
                f"expected a pydantic BaseModel subclass"
            )
        if model.model_config.get("extra") != "forbid":
            raise PluginError(
                f"plugin '{plugin}': the config_model {model.__name__} of {kind} type '{name}' must set "
                f"model_config = ConfigDict(extra='forbid', frozen=True), so that a misspelled setting "
                f"is an error rather than silently ignored"
            )
        if TYPE_KEY in model.model_fields:
            raise PluginError(
                f"plugin '{plugin}': the config_model {model.__name__} of {kind} type '{name}' has a field "
                f"'{TYPE_KEY}', which is reserved: '{TYPE_KEY}' selects the device type in a configuration section"
            )
        if not callable(item.factory):
            raise PluginError(f"plugin '{plugin}': the factory of {kind} type '{name}' is not callable")
        body = getattr(item, "body", None)
        if body is not None and not isinstance(body, SensorBody):
            raise PluginError(f"plugin '{plugin}': sensor type '{name}' has body {body!r}; expected a "
                              "spherecal.plugins.SensorBody (a box in the sensor frame, mm) or None")
        option = getattr(item, "frame_option", None)
        if option is not None:
            if not isinstance(option, str) or not _FRAME_OPTION_RE.match(option):
                raise PluginError(f"plugin '{plugin}': robot type '{name}' has frame_option {option!r}; it must be "
                                  "lower case letters, digits and '-', starting with a letter, without the dashes "
                                  "(e.g. 'tool-frame')")
            if option in RESERVED_OPTION_NAMES:
                raise PluginError(f"plugin '{plugin}': robot type '{name}' has frame_option {option!r}, an option "
                                  f"spherecal compare or validate already has (taken: "
                                  f"{', '.join(sorted(RESERVED_OPTION_NAMES))})")
            if item.read_frame is None:
                raise PluginError(f"plugin '{plugin}': robot type '{name}' has frame_option {option!r} but no "
                                  "read_frame to read what it is given")
        if name in table:
            other = self._provider[(kind, name)]
            raise PluginError(
                f"{kind} type '{name}' is registered twice: by plugin '{other}' and by plugin '{plugin}'. "
                f"Uninstall one of the two, or disable one (SPHERECAL_DISABLE_PLUGIN_AUTOLOAD=1 keeps "
                f"only the built-ins)"
            )
        table[name] = item
        self._provider[(kind, name)] = plugin


# ---------------------------------------------------------------------------------------
# Exporter registry (handed to spherecal_register_exporters)
# ---------------------------------------------------------------------------------------
class ExporterRegistry:
    """Exporters by name, and which plugin provided each. Plugins add to it from
    ``spherecal_register_exporters(registry)`` with :meth:`add_exporter`."""

    def __init__(self) -> None:
        self._exporters: dict[str, Exporter] = {}
        self._provider: dict[str, str] = {}
        self._current_plugin: str | None = None
        #: Third-party entry points installed but not loaded (autoload off), for messages.
        self.not_loaded: tuple[str, ...] = ()

    def add_exporter(self, exporter: Exporter) -> None:
        """Register a :class:`~spherecal.io.exporters.Exporter`. Its name must be new."""
        plugin = self._current_plugin or "<unknown plugin>"
        where = f"plugin '{plugin}'"
        if not isinstance(exporter, Exporter):
            raise PluginError(f"{where} passed {type(exporter).__name__} to registry.add_exporter(); "
                              "expected a spherecal.plugins.Exporter")
        name = exporter.name
        if not isinstance(name, str) or not _TYPE_NAME_RE.match(name) or name == EXPORT_RUN_KEY:
            raise PluginError(f"{where} registered an exporter named {name!r}; an exporter name must be lower case "
                              f"letters, digits and underscores, starting with a letter, and not "
                              f"'{EXPORT_RUN_KEY}' (e.g. 'abb_rapid')")
        model = exporter.settings_model
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            raise PluginError(f"{where}: exporter '{name}' has settings_model {model!r}; expected a pydantic "
                              "BaseModel subclass")
        if model.model_config.get("extra") != "forbid":
            raise PluginError(f"{where}: the settings_model {model.__name__} of exporter '{name}' must set "
                              "model_config = ConfigDict(extra='forbid', frozen=True), so that a misspelled setting "
                              "is an error rather than silently ignored")
        if not (isinstance(exporter.files, tuple) and exporter.files and all(isinstance(f, str) for f in exporter.files)):
            raise PluginError(f"{where}: exporter '{name}' must declare its files as a non-empty tuple of file-name "
                              f"templates, got {exporter.files!r}")
        try:
            unknown = exporter.template_fields() - set(TEMPLATE_FIELDS) - set(model.model_fields)
        except ValueError as exc:
            raise PluginError(f"{where}: exporter '{name}' has a malformed file-name template: {exc}") from None
        if unknown:
            raise PluginError(f"{where}: the file names of exporter '{name}' use {sorted(unknown)}, which are neither "
                              f"{', '.join(TEMPLATE_FIELDS)} nor fields of {model.__name__}")
        if not exporter.mountings or any(m not in MOUNTINGS for m in exporter.mountings):
            raise PluginError(f"{where}: exporter '{name}' has mountings {exporter.mountings!r}; give some of "
                              f"{', '.join(MOUNTINGS)}")
        rt = exporter.robot_types
        if rt is not None and not (isinstance(rt, tuple) and rt and all(isinstance(t, str) for t in rt)):
            raise PluginError(f"{where}: exporter '{name}' has robot_types {rt!r}; give a non-empty tuple of robot "
                              "type names, or None for any robot")
        if not callable(exporter.write) or not (exporter.note is None or callable(exporter.note)):
            raise PluginError(f"{where}: exporter '{name}': write (and note, when given) must be callable")
        if name in self._exporters:
            raise PluginError(f"exporter '{name}' is registered twice: by plugin '{self._provider[name]}' and by "
                              f"plugin '{plugin}'. Uninstall one of the two, or disable one")
        self._exporters[name] = exporter
        self._provider[name] = plugin

    @property
    def exporters(self) -> Mapping[str, Exporter]:
        return types.MappingProxyType(self._exporters)

    def provider(self, name: str) -> str:
        """Name of the plugin that registered the exporter."""
        return self._provider[name]

    def exporter(self, name: Any, path: str) -> Exporter:
        """The exporter called ``name``; a :class:`ConfigError` at ``path`` listing the
        installed ones if there is none."""
        if isinstance(name, str) and name in self._exporters:
            return self._exporters[name]
        close = difflib.get_close_matches(name, list(self._exporters), n=1) if isinstance(name, str) else []
        hint = f" Did you mean '{close[0]}'?" if close else ""
        advice = ""
        if self.not_loaded:
            advice = (f" Third-party plugins are not loaded because {DISABLE_AUTOLOAD_ENV} is set (installed but not "
                      f"loaded: {', '.join(self.not_loaded)}): if one of them provides it, unset "
                      f"{DISABLE_AUTOLOAD_ENV} or enable that plugin by name (PluginHost(enable=[...])).")
        raise ConfigError(f"{path}: unknown exporter {name!r}; installed exporters: "
                          f"{', '.join(sorted(self._exporters)) or 'none'}.{hint}{advice}")
