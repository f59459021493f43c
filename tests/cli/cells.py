"""The simulated cell of a configuration as a run builds it, with the installed plugins."""

from spherecal.app.cell import make_cell, sensor_field_of_view
from spherecal.plugins.host import PluginHost


def simulated_cell(cfg, arm=None):
    """:func:`spherecal.app.cell.make_cell` with the field of view the installed sensor
    plugin declares (and ``[simulation.fov]`` completes)."""
    return make_cell(cfg, arm, sensor_field_of_view(cfg, PluginHost()))
