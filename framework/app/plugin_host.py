"""The run's plugin host (one per run) and what it builds from the configuration: the
arm's kinematics, the exporters, the robot and the sensor.

:func:`make_host` is the one place a run's host is made; the commands call it through
this module (``plugin_host.make_host()``), so that a test or an embedding application
can give every command other plugins by replacing it here."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Callable, Iterator

from spherecal.core.errors import ConfigError
from spherecal.devices.contract import DeviceContext
from spherecal.io.exporters import ExportPlan
from spherecal.plugins.host import PluginHost

if TYPE_CHECKING:  # (neither is loaded by solve: tests/cli/test_startup_imports.py)
    from spherecal.config import LoadedConfig, RunConfig
    from spherecal.sim import SimulatedCell


def make_host(enable: list[str] | None = None) -> PluginHost:
    """The run's plugin host: the installed plugins (only ``enable``'s when given)."""
    return PluginHost(enable=enable) if enable else PluginHost()


def in_file(loaded: LoadedConfig, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, a :class:`ConfigError` it raises naming the configuration file."""
    try:
        return fn(*args, **kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{loaded.path}: {exc}") from None


def export_plan(loaded: LoadedConfig, host: PluginHost, log: Callable[[str], None] | None = None) -> ExportPlan:
    """The exporters of a configured run (``[export]``), checked before anything moves;
    ``log`` hears which exporters were left out and why."""
    cfg = loaded.config
    plan = in_file(loaded, host.export_plan, cfg.export, cfg.mounting, cfg.robot["type"])
    if log is not None:
        for why in plan.left_out.values():
            log(f"export: {why}")
    return plan


def robot_arm(loaded: LoadedConfig, host: PluginHost):
    """The configured robot's arm kinematics (None when its type does not describe it);
    relative paths in the robot section resolve against the configuration's folder."""
    return in_file(loaded, host.arm_kinematics, loaded.config.robot, base_dir=loaded.path.parent)


def tool_point_mm(cfg: RunConfig) -> tuple[float, float, float] | None:
    """The point on the flange whose speed the moves limit (flange frame, mm): the
    sensor's origin from the nominal transform (eye-in-hand), the rough sphere centre
    (eye-to-hand)."""
    if cfg.mounting == "eye_in_hand":
        return tuple(cfg.nominal_transform.translation_mm)
    return tuple(cfg.acquisition.sphere_centre_mm) if cfg.acquisition is not None else None


@contextlib.contextmanager
def open_devices(loaded: LoadedConfig, host: PluginHost, cell: SimulatedCell | None,
                 log: Callable[[str], None]) -> Iterator:
    """Robot and sensor from the configuration, closed on the way out whatever happens.
    In a simulated run the factories get the simulated world's time, clocks and motion
    too (:func:`spherecal.sim.live.device_extras`), so that streaming devices stream what
    the simulated arm does at each simulated instant."""
    cfg = loaded.config
    extras = {}
    if cell is not None:
        from spherecal.sim.live import device_extras  # (only simulated runs load the simulated world)

        extras = device_extras(cell)
    context = DeviceContext(cell=cell, log=log, extras=extras, tool_point_mm=tool_point_mm(cfg))
    robot = in_file(loaded, host.create_robot, cfg.robot, context, base_dir=loaded.path.parent)
    try:
        sensor = in_file(loaded, host.create_sensor, cfg.sensor, context, base_dir=loaded.path.parent)
    except BaseException:
        robot.close()
        raise
    try:
        yield robot, sensor
    finally:
        with contextlib.suppress(Exception):
            sensor.close()
        robot.close()
