"""Reports and exports of calibration results.

- :mod:`.export`: the core's brand-free exports, the result as 4x4 matrices (both
  directions), xyz + quaternion (w, x, y, z), ROS 2 (static transform command, YAML,
  launch file, URDF joint) and JSON, each with a reader, and their exporters (the
  built-in plugin :mod:`spherecal.plugins.core_exports` registers them);
  :func:`write_exports` (:mod:`spherecal.io.exporters`) writes the files of any
  exporters, a robot plugin's included.
- :mod:`.assess`: the green/amber/red verdict and the advice driven by the diagnostics.
- :mod:`.html`: :func:`write_report`, a self-contained HTML report (imports matplotlib,
  so it is loaded on first use).

See docs/results.md.
"""

from spherecal.report.assess import Advice, Thresholds, Verdict, advice, verdict
from spherecal.io.exporters import write_exports

__all__ = ["Advice", "Thresholds", "Verdict", "advice", "verdict", "write_exports", "write_report"]


def __getattr__(name):
    if name == "write_report":
        from spherecal.report.html import write_report

        return write_report
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
