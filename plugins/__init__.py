"""The plugin host: hook specifications, the plugin manager facade, device registries
and the pytest fixtures for plugin authors.

- :mod:`spherecal.plugins.hookspecs`: every hook a plugin can implement (the module is
  ``hookspecs``, plural, because ``hookspec`` here is the marker);
- :mod:`spherecal.plugins.host`: :class:`~spherecal.plugins.host.PluginHost`, built per
  run: loads plugins from the ``"spherecal"`` entry points, keeps the robot and sensor
  registry, validates configuration sections and creates devices;
- :mod:`spherecal.plugins.testing`: pytest fixtures for plugin authors.

A plugin module marks its hook implementations with :data:`hookimpl`::

    from spherecal.plugins import hookimpl

    @hookimpl
    def spherecal_register_devices(registry):
        registry.add_robot(RobotType(...))
"""

import pluggy

PROJECT_NAME = "spherecal"
#: Entry-point group that built-in and third-party plugins are registered under.
ENTRY_POINT_GROUP = "spherecal"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)
