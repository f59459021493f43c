"""Reports and exports of calibration results. Imports the layers below it (core to sim),
never the plugin host or the commands.

- :mod:`.export`: the core's brand-free exports, the result as 4x4 matrices (both
  directions), xyz + quaternion (w, x, y, z), ROS 2 (static transform command, YAML,
  launch file, URDF joint) and JSON, each with a reader, and their exporters (the
  built-in plugin :mod:`spherecal.plugins.core_exports` registers them);
  :func:`write_exports` (:mod:`spherecal.io.exporters`) writes the files of any
  exporters, a robot plugin's included.
- :mod:`.assess`: the green/amber/red verdict and the advice driven by the diagnostics.
- :mod:`.html`: :func:`write_report`, a self-contained HTML report.

See docs/results.md. The names below load on first use (PEP 562): the exports' formatting
helpers a robot plugin uses do not load the verdict, and the verdict does not load
matplotlib.
"""

from spherecal.core.lazy import lazy_attributes

#: name -> the module that defines it
_WHERE = {
    "Advice": ".assess",
    "Thresholds": ".assess",
    "Verdict": ".assess",
    "advice": ".assess",
    "verdict": ".assess",
    "write_exports": "spherecal.io.exporters",
    "write_report": ".html",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_attributes(__name__, _WHERE)
