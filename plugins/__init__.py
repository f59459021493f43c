"""The plugin host: hook specifications, the plugin manager facade, device registries
and the pytest fixtures for plugin authors.

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
