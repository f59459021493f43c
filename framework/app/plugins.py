"""``spherecal plugins``: the installed robots, sensors and exporters; and the robot
types' own names for ``--controller-frame``, which the command line offers."""

from __future__ import annotations

from spherecal.app import plugin_host


def describe_plugins(host=None) -> str:
    """The installed plugins with their configuration fields, as ``spherecal plugins``
    prints them. ``host``: the run's plugin host (default: made here)."""
    return (host if host is not None else plugin_host.make_host()).format_description()


def controller_frame_options(host) -> dict[str, list[str]]:
    """The robot types' names for ``--controller-frame``
    (:attr:`spherecal.devices.contract.RobotType.frame_option`): ``{option: [robot type, ...]}``."""
    found: dict[str, list[str]] = {}
    for t in host.registry.robots.values():
        if t.frame_option:
            found.setdefault(t.frame_option, []).append(t.name)
    return found


def host_and_frame_options():
    """The run's plugin host and its robot types' names for ``--controller-frame``
    (:func:`controller_frame_options`); ``(None, {})`` when the host cannot be made: the
    command that needs it makes it again and reports why, with its exit code."""
    try:
        host = plugin_host.make_host()
    except Exception:  # noqa: BLE001 - reported by the command itself, with its exit code
        return None, {}
    return host, controller_frame_options(host)
