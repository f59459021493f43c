"""The plugin host: loads plugins, keeps the registries of robot and sensor types and of
exporters, validates their configuration sections, creates devices and chooses the
exporters of a run.

The rest of spherecal talks to plugins only through :class:`PluginHost`; nothing else
touches the pluggy plugin manager. A host is built per run (there is no module-level
manager), so two hosts never share state::

    host = PluginHost()                      # built-ins + installed third-party plugins
    robot = host.create_robot({"type": "abb_irb2400", ...}, context)
    host.observation_taken(observation=obs, robot_type="abb_irb2400")  # keyword arguments only
    plan = host.export_plan(config.export, "eye_in_hand", "abb_irb2400")  # the run's exporters

Where plugins come from
-----------------------
Built-in and third-party plugins are found the same way: entry points in the group
``"spherecal"`` (:data:`spherecal.plugins.ENTRY_POINT_GROUP`). An entry point whose
module starts with ``spherecal.`` is a built-in. Setting the environment variable
``SPHERECAL_DISABLE_PLUGIN_AUTOLOAD=1`` turns off loading of third-party entry points;
built-ins still load, and third-party ones can still be enabled by name (``enable=``).

Errors
------
Everything that can go wrong with a plugin is a :class:`~spherecal.core.errors.PluginError`
naming the plugin (an import error, a misspelled hook, an exception in a hook, a bad or
duplicate device type); a host either builds completely or raises. A bad configuration
section is a :class:`~spherecal.core.errors.ConfigError` listing every problem with its
dotted path (``robot.workspace.max_x_mm: ...``).
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import os
import re
import types
import typing
from dataclasses import dataclass
from importlib import metadata
from typing import Any, Callable, Iterable, Literal, Mapping, Sequence

import numpy as np
import pluggy
from pydantic import BaseModel, ValidationError
from pydantic_core import PydanticUndefined

from spherecal.core.errors import ConfigError, InputError, PluginError, SpherecalError
from spherecal.core.kinematics import ArmWithHome, declared_home_joints_deg
from spherecal.core.validation_errors import location_text, validation_error_lines
from spherecal.devices.contract import DeviceContext, Robot, Sensor
from spherecal.io.exporters import Exporter, ExportPlan, SelectedExporter

from spherecal.config.base import BASE_DIR_CONTEXT_KEY

from spherecal.plugins import hookspecs as _hookspec_module
from spherecal.plugins.markers import ENTRY_POINT_GROUP, PROJECT_NAME, hookimpl
from .registry import (  # noqa: F401 - DeviceRegistry and ExporterRegistry: importable from the host too
    DISABLE_AUTOLOAD_ENV,
    EXPORT_RUN_KEY,
    TYPE_KEY,
    DeviceKind,
    DeviceRegistry,
    ExporterRegistry,
)

#: Module prefix of built-in plugins (always loaded).
BUILTIN_MODULE_PREFIX = "spherecal."
#: Prefix every hook name carries.
HOOK_PREFIX = PROJECT_NAME + "_"

_FALSE_WORDS = {"", "0", "false", "no", "off"}


def autoload_disabled(environ: Mapping[str, str] | None = None) -> bool:
    """True when ``SPHERECAL_DISABLE_PLUGIN_AUTOLOAD`` is set to anything but
    ``""``, ``0``, ``false``, ``no`` or ``off`` (case-insensitive)."""
    environ = os.environ if environ is None else environ
    return environ.get(DISABLE_AUTOLOAD_ENV, "").strip().lower() not in _FALSE_WORDS


# ---------------------------------------------------------------------------------------
# Records
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PluginInfo:
    """One loaded plugin: its name, module and where it came from."""

    name: str
    module: str
    source: Literal["built-in", "entry point", "registered"]
    distribution: str | None = None

    def label(self) -> str:
        where = f"module {self.module}"
        if self.distribution:
            where += f", distribution {self.distribution}"
        return f"plugin '{self.name}' ({self.source}, {where})"


@dataclass(frozen=True)
class FieldDescription:
    """One configuration field of a device type. Nested models, optional ones
    (``WorkspaceBox | None``) too, are flattened with dotted names (``workspace.min_mm``);
    ``type`` names the annotation without module paths."""

    name: str
    type: str
    required: bool
    default: Any
    description: str
    constraints: str = ""


@dataclass(frozen=True)
class DeviceDescription:
    """An installed robot or sensor type, for listings (``spherecal plugins``)."""

    kind: DeviceKind
    name: str
    plugin: str
    description: str
    fields: tuple[FieldDescription, ...]
    has_kinematics: bool = False


@dataclass(frozen=True)
class ExporterDescription:
    """An installed exporter, for listings (``spherecal plugins``)."""

    name: str
    plugin: str
    description: str
    files: tuple[str, ...]
    applies: str
    fields: tuple[FieldDescription, ...]


# ---------------------------------------------------------------------------------------
# Plugin manager (private: only PluginHost uses it)
# ---------------------------------------------------------------------------------------
def _default_impl_opts() -> dict:
    def probe():  # pragma: no cover - never called
        pass

    hookimpl(probe)
    return dict(getattr(probe, PROJECT_NAME + "_impl"))


class _Manager(pluggy.PluginManager):
    """A pluggy manager that takes every ``spherecal_*`` function as a hook
    implementation, marked or not, so that a misspelled hook is caught by
    :meth:`check_pending` instead of being ignored."""

    _defaults = _default_impl_opts()

    def parse_hookimpl_opts(self, plugin, name):
        opts = super().parse_hookimpl_opts(plugin, name)
        if opts is not None or not name.startswith(HOOK_PREFIX):
            return opts
        try:
            obj = inspect.getattr_static(plugin, name)
        except AttributeError:
            return None
        if isinstance(obj, (staticmethod, classmethod)):
            obj = obj.__func__
        if inspect.isfunction(obj) or inspect.ismethod(obj) or inspect.isbuiltin(obj):
            return dict(self._defaults)
        return None


def _module_name(plugin: object) -> str:
    if isinstance(plugin, types.ModuleType):
        return plugin.__name__
    return getattr(plugin, "__module__", None) or type(plugin).__module__


#: A dotted module path before a name (``spherecal.core.workspace.``), or a quoted
#: string (a ``Literal`` value), which is kept as it is.
_MODULE_PATH = re.compile(r"""('[^']*'|"[^"]*")|\b(?:[A-Za-z_]\w*\.)+(?=[A-Za-z_])""")


def _field_type_name(annotation: Any) -> str:
    """The annotation as a reader writes it: ``WorkspaceBox | None``, ``tuple[JointSpec, ...]``,
    without module paths (``spherecal.core.workspace.``, ``typing.``)."""
    if annotation is None:
        return "None"
    if isinstance(annotation, type) and not getattr(annotation, "__args__", None):
        return annotation.__name__
    return _MODULE_PATH.sub(lambda m: m.group(1) or "", repr(annotation))


def _nested_model(annotation: Any) -> type[BaseModel] | None:
    """The model a field holds, ``X`` or ``X | None`` (``Optional[X]``); None otherwise."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1 and isinstance(args[0], type) and issubclass(args[0], BaseModel):
            return args[0]
    return None


def _constraints_text(metadata_items: Iterable[Any]) -> str:
    parts = []
    for m in metadata_items:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("multiple_of", "multiple of"),
                          ("min_length", "min length"), ("max_length", "max length")):
            value = getattr(m, attr, None)
            if value is not None:
                parts.append(f"{sym} {value}")
    return ", ".join(parts)


_NO_PARENT = object()


def _field_default(info) -> Any:
    if info.default is not PydanticUndefined:
        return info.default
    if info.default_factory is not None:
        try:
            return info.default_factory()
        except Exception:  # noqa: BLE001 - a description must not fail on a factory
            return "<computed>"
    return None


def _describe_fields(model: type[BaseModel], prefix: str = "", parent: Any = _NO_PARENT) -> list[FieldDescription]:
    """The fields of ``model``, nested models (``X``, or ``X | None`` alike) opened into
    dotted names. ``parent`` is the default of the field holding ``model`` when it has
    one (a model instance, or None: the table may be left out): the nested fields are then
    not required and their defaults are the parent default's values. An optional table's
    own description (what leaving it out means) follows its first field's."""
    out: list[FieldDescription] = []
    for fname, info in model.model_fields.items():
        dotted = prefix + fname
        required = info.is_required()
        default = _field_default(info)
        if parent is not _NO_PARENT:
            required = False
            default = getattr(parent, fname, None) if isinstance(parent, BaseModel) else None
        nested = _nested_model(info.annotation)
        if nested is not None:
            fields = _describe_fields(nested, dotted + ".", _NO_PARENT if required else default)
            if nested is not info.annotation and info.description and fields:  # X | None
                first = fields[0]
                text = f"{first.description}; {dotted}: {info.description}" if first.description else info.description
                fields[0] = dataclasses.replace(first, description=text)
            out.extend(fields)
            continue
        if isinstance(default, BaseModel):
            default = default.model_dump()
        out.append(
            FieldDescription(
                name=dotted,
                type=_field_type_name(info.annotation),
                required=required,
                default=default,
                description=info.description or "",
                constraints=_constraints_text(info.metadata),
            )
        )
    return out


def _field_description(model: type[BaseModel], loc: Sequence[Any]) -> str:
    info = model.model_fields.get(loc[0]) if loc and isinstance(loc[0], str) else None
    return (info.description if info is not None and info.description else "required")


def _applies_text(exporter: Exporter) -> str:
    robots = "any robot" if exporter.robot_types is None else "robot types " + ", ".join(exporter.robot_types)
    return f"it is for {' and '.join(exporter.mountings)}, {robots}"


# ---------------------------------------------------------------------------------------
# The facade
# ---------------------------------------------------------------------------------------
class PluginHost:
    """Loads plugins and answers for them. Build one per run.

    :param plugins: extra plugins to register (modules or objects, or ``(name, plugin)``
        pairs), for tests and for embedding; registered after the entry points.
    :param load_entry_points: load plugins from the ``"spherecal"`` entry-point group
        (default True). With False only ``plugins`` are registered.
    :param autoload: load third-party entry points. Default: yes, unless the environment
        variable ``SPHERECAL_DISABLE_PLUGIN_AUTOLOAD`` is set (see
        :func:`autoload_disabled`). Built-ins are loaded either way.
    :param enable: names of third-party entry points to load even when autoloading is off.
    :param environ: the environment to read (default ``os.environ``).
    :raises PluginError: a plugin failed to import, to register, has a misspelled hook,
        raised in ``spherecal_register_devices`` or ``spherecal_register_exporters``, or
        registered a bad or duplicate device type or exporter.
    """

    def __init__(
        self,
        plugins: Iterable[object | tuple[str, object]] = (),
        *,
        load_entry_points: bool = True,
        autoload: bool | None = None,
        enable: Iterable[str] = (),
        environ: Mapping[str, str] | None = None,
    ) -> None:
        self._pm = _Manager(PROJECT_NAME)
        self._pm.add_hookspecs(_hookspec_module)
        self._infos: dict[str, PluginInfo] = {}
        self.registry = DeviceRegistry()
        self.exporters = ExporterRegistry()
        if autoload is None:
            autoload = not autoload_disabled(environ)
        self.autoload = autoload
        enable = set(enable)
        if load_entry_points:
            self._load_entry_points(autoload, enable)
        elif enable:
            raise PluginError(f"enable={sorted(enable)} needs load_entry_points=True")
        for item in plugins:
            if isinstance(item, tuple):
                name, plugin = item
            else:
                plugin = item
                name = getattr(plugin, "__name__", None) or type(plugin).__name__
            self._register(plugin, PluginInfo(name=name, module=_module_name(plugin), source="registered"))
        self._check_pending()
        self._collect("spherecal_register_devices", self.registry)
        self._collect("spherecal_register_exporters", self.exporters)

    # loading ---------------------------------------------------------------------------
    def _load_entry_points(self, autoload: bool, enable: set[str]) -> None:
        found = list(metadata.entry_points(group=ENTRY_POINT_GROUP))
        names = {ep.name for ep in found}
        missing = enable - names
        if missing:
            raise PluginError(
                f"cannot enable plugin(s) {sorted(missing)}: no such entry point in group "
                f"'{ENTRY_POINT_GROUP}'; installed: {', '.join(sorted(names)) or 'none'}"
            )
        seen: set[tuple[str, str]] = set()
        not_loaded: list[str] = []
        dist_texts: dict[int, str] = {}  # a distribution's metadata is parsed on each read: once each
        for ep in sorted(found, key=lambda e: (not e.value.startswith(BUILTIN_MODULE_PREFIX), e.name)):
            if (ep.name, ep.value) in seen:
                continue  # the same distribution seen twice on sys.path
            seen.add((ep.name, ep.value))
            builtin = ep.value.startswith(BUILTIN_MODULE_PREFIX)
            if not builtin and not autoload and ep.name not in enable:
                not_loaded.append(ep.name)
                continue
            dist = getattr(ep, "dist", None)
            dist_text = None
            if dist is not None:
                if id(dist) not in dist_texts:
                    meta = dist.metadata
                    dist_texts[id(dist)] = f"{meta['Name']} {meta['Version']}"
                dist_text = dist_texts[id(dist)]
            info = PluginInfo(
                name=ep.name,
                module=ep.value.split(":")[0],
                source="built-in" if builtin else "entry point",
                distribution=dist_text,
            )
            try:
                plugin = ep.load()
            except Exception as exc:
                hint = (
                    "" if builtin
                    else f" Uninstall or fix it, or set {DISABLE_AUTOLOAD_ENV}=1 to run with the built-ins only."
                )
                raise PluginError(
                    f"{info.label()} failed to import: {type(exc).__name__}: {exc}.{hint}"
                ) from exc
            self._register(plugin, info)
        self.registry.not_loaded = self.exporters.not_loaded = tuple(sorted(set(not_loaded)))

    def _register(self, plugin: object, info: PluginInfo) -> None:
        if info.name in self._infos:
            raise PluginError(
                f"two plugins are named '{info.name}': {self._infos[info.name].label()} and {info.label()}"
            )
        try:
            self._pm.register(plugin, name=info.name)
        except pluggy.PluginValidationError as exc:
            raise PluginError(f"{info.label()} is invalid: {str(exc).strip().replace(chr(10), '; ')}") from exc
        except ValueError as exc:  # pluggy: the same object registered twice
            raise PluginError(f"{info.label()} cannot be registered: {exc}") from exc
        self._infos[info.name] = info

    def _check_pending(self) -> None:
        known = sorted(n for n in dir(_hookspec_module) if n.startswith(HOOK_PREFIX))
        for name in sorted(vars(self._pm.hook)):
            if name.startswith("_"):
                continue
            caller = getattr(self._pm.hook, name)
            if caller.has_spec():
                continue
            for impl in caller.get_hookimpls():
                if impl.optionalhook:
                    continue
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" Did you mean '{close[0]}'?" if close else ""
                raise PluginError(
                    f"{self._infos[impl.plugin_name].label()} defines '{name}', which is not a spherecal hook."
                    f"{hint} Known hooks: {', '.join(known)}."
                )
        self._pm.check_pending()  # belt and braces: pluggy's own check

    def _collect(self, hook_name: str, registry) -> None:
        """Call a registration hook one plugin at a time, so that the registry knows who
        registers what."""
        caller = getattr(self._pm.hook, hook_name)
        impls = caller.get_hookimpls()
        all_plugins = [impl.plugin for impl in impls]
        for impl in impls:  # get_hookimpls() lists them in registration order
            only = self._pm.subset_hook_caller(hook_name, [p for p in all_plugins if p is not impl.plugin])
            registry._current_plugin = impl.plugin_name
            try:
                only(registry=registry)
            except SpherecalError as exc:
                if isinstance(exc, PluginError):
                    raise
                raise PluginError(f"{self._infos[impl.plugin_name].label()} failed in {hook_name}: {exc}") from exc
            except Exception as exc:
                raise PluginError(
                    f"{self._infos[impl.plugin_name].label()} raised in {hook_name}: {type(exc).__name__}: {exc}"
                ) from exc
            finally:
                registry._current_plugin = None

    # hooks -----------------------------------------------------------------------------
    def _call(self, hook_name: str, **kwargs: Any) -> list[Any]:
        caller = getattr(self._pm.hook, hook_name)
        try:
            return caller(**kwargs)
        except Exception as exc:
            culprit = self._culprit(caller, exc)
            raise PluginError(f"{culprit} raised in {hook_name}: {type(exc).__name__}: {exc}") from exc

    def _culprit(self, caller, exc: BaseException) -> str:
        """Which plugin's implementation the exception came from (from the traceback)."""
        impls = caller.get_hookimpls()
        codes = {getattr(impl.function, "__code__", None): impl.plugin_name for impl in impls}
        tb = exc.__traceback__
        while tb is not None:
            name = codes.get(tb.tb_frame.f_code)
            if name is not None:
                return self._infos[name].label()
            tb = tb.tb_next
        names = ", ".join(f"'{impl.plugin_name}'" for impl in impls)
        return f"one of the plugins {names}"

    def observation_taken(self, *, observation, robot_type: str | None = None, sensor_type: str | None = None) -> None:
        """Call ``spherecal_observation_taken`` (see :mod:`spherecal.plugins.hookspecs`)."""
        self._call("spherecal_observation_taken", observation=observation, robot_type=robot_type,
                   sensor_type=sensor_type)

    def acquisition_finished(self, *, dataset, robot_type: str | None = None, sensor_type: str | None = None) -> None:
        """Call ``spherecal_acquisition_finished``."""
        self._call("spherecal_acquisition_finished", dataset=dataset, robot_type=robot_type, sensor_type=sensor_type)

    def calibration_finished(self, *, result, dataset, out_dir=None, exports_written: bool = False,
                             robot_type: str | None = None, sensor_type: str | None = None) -> None:
        """Call ``spherecal_calibration_finished``; ``out_dir`` None: no files were written
        (then ``exports_written`` is False too)."""
        self._call("spherecal_calibration_finished", result=result, dataset=dataset, out_dir=out_dir,
                   exports_written=bool(exports_written and out_dir is not None), robot_type=robot_type,
                   sensor_type=sensor_type)

    # plugins ---------------------------------------------------------------------------
    @property
    def plugins(self) -> tuple[PluginInfo, ...]:
        """The loaded plugins, in registration order."""
        return tuple(self._infos.values())

    def plugin_names(self) -> list[str]:
        return list(self._infos)

    # configuration ---------------------------------------------------------------------
    def validate_robot_config(self, type_name: str, section: Mapping[str, Any], path: str = "robot",
                              base_dir=None) -> BaseModel:
        """Validate a robot section against the config model of ``type_name``.

        :param type_name: the robot type (``"abb_irb2400"``).
        :param section: the settings, as read from the configuration file; a ``type`` key,
            if present, must equal ``type_name`` and is not passed to the model.
        :param path: where the section sits in the configuration, for messages.
        :param base_dir: the configuration file's folder, handed to the model's validators
            as the pydantic validation context ``{"base_dir": base_dir}``
            (:data:`spherecal.plugins.BASE_DIR_CONTEXT_KEY`) so that a plugin
            can resolve relative file paths against it (None: not known).
        :return: an instance of the type's ``config_model``.
        :raises ConfigError: listing every error with its dotted path.
        """
        rt = self.registry.robot_type(type_name, path=f"{path}.{TYPE_KEY}")
        return self._validate("robot", rt, section, path, base_dir)

    def validate_sensor_config(self, type_name: str, section: Mapping[str, Any], path: str = "sensor",
                               base_dir=None) -> BaseModel:
        """The sensor twin of :meth:`validate_robot_config`."""
        st = self.registry.sensor_type(type_name, path=f"{path}.{TYPE_KEY}")
        return self._validate("sensor", st, section, path, base_dir)

    def _validate(self, kind: DeviceKind, dtype, section: Any, path: str, base_dir=None) -> BaseModel:
        if isinstance(section, BaseModel):
            section = section.model_dump()
        if not isinstance(section, Mapping):
            raise ConfigError(f"{path}: expected a table of {kind} settings, got {type(section).__name__}")
        settings = dict(section)
        if TYPE_KEY in settings:
            given = settings.pop(TYPE_KEY)
            if given != dtype.name:
                raise ConfigError(
                    f"{path}.{TYPE_KEY}: the section says {given!r} but is being validated as '{dtype.name}'"
                )
        model = dtype.config_model
        try:
            context = None if base_dir is None else {BASE_DIR_CONTEXT_KEY: base_dir}
            return model.model_validate(settings, context=context)
        except ValidationError as exc:
            lines = validation_error_lines(exc, path, model)
            plugin = self.registry.provider(kind, dtype.name)
            head = (
                f"invalid configuration for {kind} type '{dtype.name}' (plugin '{plugin}'), "
                f"{len(lines)} error{'s' if len(lines) != 1 else ''}:"
            )
            raise ConfigError("\n  ".join([head, *lines])) from None

    def _type_of(self, kind: DeviceKind, section: Any, path: str) -> str:
        if not isinstance(section, Mapping):
            raise ConfigError(f"{path}: expected a table of {kind} settings, got {type(section).__name__}")
        if TYPE_KEY not in section:
            table = self.registry.robots if kind == "robot" else self.registry.sensors
            raise ConfigError(
                f"{path}.{TYPE_KEY}: missing; say which {kind} this is, one of: {', '.join(sorted(table)) or 'none'}"
            )
        return section[TYPE_KEY]

    # devices ---------------------------------------------------------------------------
    def create_robot(self, section: Mapping[str, Any], context: DeviceContext | None = None,
                     path: str = "robot", base_dir=None) -> Robot:
        """Validate ``section`` (``{"type": "abb_irb2400", ...settings}``; ``base_dir`` as for
        :meth:`validate_robot_config`) and call the robot type's factory with the validated
        config and ``context``.

        :raises ConfigError: unknown type or invalid settings.
        :raises DeviceError: (and other spherecal errors) as the factory raised them.
        :raises PluginError: the factory raised anything else or returned something that
            is not a :class:`~spherecal.devices.contract.Robot`.
        """
        type_name = self._type_of("robot", section, path)
        config = self.validate_robot_config(type_name, section, path, base_dir)
        rt = self.registry.robot_type(type_name)
        return self._make("robot", rt, config, context, Robot)

    def create_sensor(self, section: Mapping[str, Any], context: DeviceContext | None = None,
                      path: str = "sensor", base_dir=None) -> Sensor:
        """The sensor twin of :meth:`create_robot` (``base_dir``: the configuration file's
        folder, for the model's validators to resolve relative paths against; None: not known)."""
        type_name = self._type_of("sensor", section, path)
        config = self.validate_sensor_config(type_name, section, path, base_dir)
        st = self.registry.sensor_type(type_name)
        return self._make("sensor", st, config, context, Sensor)

    def _make(self, kind: DeviceKind, dtype, config: BaseModel, context, protocol) -> Any:
        context = context if context is not None else DeviceContext()
        plugin = self.registry.provider(kind, dtype.name)
        try:
            device = dtype.factory(config, context)
        except SpherecalError:
            raise
        except Exception as exc:
            raise PluginError(
                f"plugin '{plugin}': the factory of {kind} type '{dtype.name}' raised {type(exc).__name__}: {exc}"
            ) from exc
        if not isinstance(device, protocol):
            missing = [m for m in ("read_flange_pose", "read_joints_deg", "move_linear", "close")
                       if kind == "robot" and not callable(getattr(device, m, None))]
            missing += [m for m in ("read_profile", "close")
                        if kind == "sensor" and not callable(getattr(device, m, None))]
            raise PluginError(
                f"plugin '{plugin}': the factory of {kind} type '{dtype.name}' returned a "
                f"{type(device).__name__}, which lacks {', '.join(missing)} of the {protocol.__name__} protocol"
            )
        return device

    def robot_kinematics(self, section: Mapping[str, Any], path: str = "robot", base_dir=None) -> Callable | None:
        """Forward kinematics of the configured robot, ``joints_deg -> base_from_flange``
        (a :class:`~spherecal.core.models.Pose`, quaternion (w, x, y, z), mm), or None when the
        robot type has none. For ``spherecal.estimation.calibrate(..., flange_pose_from_joints=)``."""
        type_name = self._type_of("robot", section, path)
        config = self.validate_robot_config(type_name, section, path, base_dir)
        fk = self.registry.robot_type(type_name).flange_pose_from_joints
        if fk is None:
            return None

        def flange_pose_from_joints(joints_deg):
            return fk(config, joints_deg)

        return flange_pose_from_joints

    def arm_kinematics(self, section: Mapping[str, Any], path: str = "robot", base_dir=None):
        """The configured robot's :class:`~spherecal.core.kinematics.ArmKinematics` (its
        nominal geometry, inverse kinematics and joint convention), or None when the
        robot type does not describe its arm. When the type declares a home
        (:attr:`~spherecal.devices.contract.RobotType.home_joints_deg`) the arm carries it
        as ``home_joints_deg``."""
        type_name = self._type_of("robot", section, path)
        config = self.validate_robot_config(type_name, section, path, base_dir)
        rtype = self.registry.robot_type(type_name)
        if rtype.arm_kinematics is None:
            return None
        arm = rtype.arm_kinematics(config)
        home = rtype.home_joints_deg(config) if callable(rtype.home_joints_deg) else rtype.home_joints_deg
        if home is None or arm is None:
            return arm
        try:
            if np.array_equal(declared_home_joints_deg(arm), np.asarray(home, dtype=float)):
                return arm  # the arm carries its home already
            return ArmWithHome(arm, home)
        except InputError as exc:
            raise PluginError(f"plugin '{self.registry.provider('robot', type_name)}': robot type "
                              f"'{type_name}' declares {exc}") from None

    # exporters -------------------------------------------------------------------------
    def export_plan(self, section: Mapping[str, Any] | BaseModel | None, mounting: str, robot_type: str | None,
                    path: str = "export") -> ExportPlan:
        """The exporters a run uses, with their validated settings.

        :param section: the ``[export]`` section (a mapping, or the configuration's
            ``ExportConfig``; None: all defaults): ``run`` lists the exporters to run
            (default: every installed one that applies), and each ``[export.<name>]``
            table holds one exporter's settings.
        :param mounting: the run's mounting mode.
        :param robot_type: the run's robot type, None when not known (then every exporter
            for the mounting applies).
        :param path: where the section sits in the configuration, for messages.
        :return: an :class:`~spherecal.io.exporters.ExportPlan`: the robot's own exporters
            first, then the others by name; ``left_out`` says why an exporter that would
            have run by default did not (its required settings are missing).
        :raises ConfigError: an unknown exporter (listed or with a settings table), one
            listed in ``run`` that does not apply to this mounting or robot, a listed one
            whose required settings are missing, or invalid settings; every message names
            the key at fault (``export.abb_rapid.mass_kg: ...``).
        """
        if isinstance(section, BaseModel):
            section = {**section.model_dump(exclude_none=True, exclude=set(section.model_extra or {})),
                       **(section.model_extra or {})}
        section = dict(section or {})
        run = section.pop(EXPORT_RUN_KEY, None)
        reg = self.exporters
        given = {}
        for name, table in section.items():  # every table is checked, for this run's exporters or not
            e = reg.exporter(name, f"{path}.{name}")
            if not isinstance(table, Mapping):
                raise ConfigError(f"{path}.{name}: expected a table [{path}.{name}] of the exporter's settings, got "
                                  f"{type(table).__name__}")
            given[name] = self._export_settings(e, table, f"{path}.{name}")
        if run is not None:
            if not isinstance(run, (list, tuple)) or not all(isinstance(n, str) for n in run):
                raise ConfigError(f"{path}.{EXPORT_RUN_KEY}: expected a list of exporter names, got {run!r:.60}")
            dupes = sorted({n for n in run if list(run).count(n) > 1})
            if dupes:
                raise ConfigError(f"{path}.{EXPORT_RUN_KEY}: {', '.join(dupes)} listed twice")
            for k, name in enumerate(run):
                e = reg.exporter(name, f"{path}.{EXPORT_RUN_KEY}[{k}]")
                if not e.applies_to(mounting, robot_type):
                    raise ConfigError(f"{path}.{EXPORT_RUN_KEY}[{k}]: exporter '{name}' does not apply to this run "
                                      f"({_applies_text(e)}; the run is {mounting} with robot type "
                                      f"{robot_type or 'unknown'}): remove it")
            names = list(run)
        else:
            names = [n for n, e in reg.exporters.items() if e.applies_to(mounting, robot_type)]
        selected, left_out = [], {}
        for name in names:
            e = reg.exporters[name]
            where = f"{path}.{name}"
            settings = given[name] if name in given else self._export_settings(e, {}, where)
            if isinstance(settings, list):  # required settings missing
                why = (f"exporter '{name}' (plugin '{reg.provider(name)}') needs settings: " + "; ".join(settings)
                       + f". Set them in [{where}]")
                if run is not None:
                    raise ConfigError(why)
                left_out[name] = why + f", or list the exporters to run in {path}.{EXPORT_RUN_KEY}"
                continue
            selected.append(SelectedExporter(e, settings, reg.provider(name)))
        own = [s for s in selected if s.exporter.robot_types is not None]
        rest = sorted((s for s in selected if s.exporter.robot_types is None), key=lambda s: s.name)
        return ExportPlan(tuple(sorted(own, key=lambda s: s.name) + rest), left_out, robot_type)

    def _export_settings(self, exporter: Exporter, table: Mapping[str, Any], where: str):
        """The validated settings, or the list of missing required settings (one line
        each, with their description); ConfigError for any other problem."""
        model = exporter.settings_model
        problems = []
        if table:  # (an empty table has nothing to check: `solve` without a configuration does not load its module)
            from spherecal.config import not_numbers

            problems = not_numbers(dict(table), model, where)
        if problems:
            raise ConfigError("\n  ".join([f"invalid settings for exporter '{exporter.name}' (plugin "
                                           f"'{self.exporters.provider(exporter.name)}'):", *problems]))
        try:
            return model.model_validate(dict(table))
        except ValidationError as exc:
            errors = exc.errors(include_url=False)
            if all(err.get("type") == "missing" and len(err["loc"]) == 1 and err["loc"][0] not in table
                   for err in errors):
                return [f"{location_text(where, err['loc'])} ({_field_description(model, err['loc'])})"
                        for err in errors]
            lines = validation_error_lines(exc, where, model)
            head = (f"invalid settings for exporter '{exporter.name}' (plugin '{self.exporters.provider(exporter.name)}'), "
                    f"{len(lines)} error{'s' if len(lines) != 1 else ''}:")
            raise ConfigError("\n  ".join([head, *lines])) from None

    # listing ---------------------------------------------------------------------------
    def describe(self) -> list[DeviceDescription]:
        """Every installed robot and sensor type with its configuration fields, robots
        first, each group sorted by name."""
        out = []
        for kind, table in (("robot", self.registry.robots), ("sensor", self.registry.sensors)):
            for name in sorted(table):
                dtype = table[name]
                out.append(
                    DeviceDescription(
                        kind=kind,
                        name=name,
                        plugin=self.registry.provider(kind, name),
                        description=dtype.description,
                        fields=tuple(_describe_fields(dtype.config_model)),
                        has_kinematics=kind == "robot" and dtype.flange_pose_from_joints is not None,
                    )
                )
        return out

    def describe_exporters(self) -> list[ExporterDescription]:
        """Every installed exporter with its files, what it applies to and its settings
        (``[export.<name>]``), sorted by name."""
        reg = self.exporters
        return [ExporterDescription(name=n, plugin=reg.provider(n), description=e.description, files=e.files,
                                    applies=_applies_text(e).removeprefix("it is "),
                                    fields=tuple(_describe_fields(e.settings_model)))
                for n, e in sorted(reg.exporters.items())]

    def format_description(self) -> str:
        """:meth:`describe` and :meth:`describe_exporters` as text, for a ``spherecal
        plugins`` command."""
        lines = ["plugins:"]
        for info in self.plugins:
            lines.append(f"  {info.name}: {info.source}, {info.module}"
                         + (f" ({info.distribution})" if info.distribution else ""))
        if not self.autoload:
            lines.append(f"  (third-party autoload off: {DISABLE_AUTOLOAD_ENV} is set)")
        for d in self.describe():
            lines.append(f"{d.kind} type '{d.name}' (plugin '{d.plugin}'): {d.description}".rstrip(": "))
            for f in d.fields:
                default = "required" if f.required else f"default {f.default!r}"
                extra = f", {f.constraints}" if f.constraints else ""
                lines.append(f"    {f.name} ({f.type}, {default}{extra}): {f.description}")
        for e in self.describe_exporters():
            lines.append(f"exporter '{e.name}' (plugin '{e.plugin}'): {e.description}; {e.applies}; "
                         f"writes {', '.join(e.files)}")
            for f in e.fields:
                default = "required" if f.required else f"default {f.default!r}"
                extra = f", {f.constraints}" if f.constraints else ""
                lines.append(f"    export.{e.name}.{f.name} ({f.type}, {default}{extra}): {f.description}")
        return "\n".join(lines)
