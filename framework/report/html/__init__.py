"""A self-contained HTML report of a calibration (imports matplotlib): :func:`write_report`.
Part of :mod:`spherecal.report`.

The report is one HTML file that opens offline: the CSS is inlined and the figures (PNG,
drawn with matplotlib's Agg renderer, no pyplot state touched) are embedded as base64
data URIs; the same PNGs are saved next to the HTML file. It shows, top to bottom: what
a point measured at a new pose gets, the verdict, the transform with its direction and
uncertainties, what to do when something is off, residual plots, a 3-D view of the sphere
with the mapped points, the uncertainty, the robot error model (a kinematic calibration's
identified parameters and calibrated URDF), station and flagged-observation tables, an
optional validation table and the estimator's details. See docs/results.md for a tour.

- :mod:`.data`: what the report shows, computed from the solution (no matplotlib);
- :mod:`.figures`: the figures, and the limits on what they draw (``MAX_POINTS_PLOTTED``,
  ``MAX_BOXES``, ...);
- :mod:`.sections`: the HTML of each part, and the page template (``report.html``,
  ``report.css``, the interactive view's ``view3d.js``);
- :mod:`.signing`: what makes a report one can sign: its version (a later report is a new
  file, ``report-2.html``, ..., saying what it supersedes), the SIMULATED mark, the
  provenance table;
- :mod:`.page`: :func:`write_report`, which assembles and writes them, and
  :func:`write_report_version`, which writes a later version beside the calibration's.
"""

from spherecal.report.html.data import (binned_residuals, interactive_points, mapped_centres, mapped_points,
                                        plot_sample, point_uncertainty, profile_points_and_residuals,
                                        row_percentiles, sphere_directions)
from spherecal.report.html.figures import FIGURE_NAMES
from spherecal.report.html.page import write_report, write_report_version
from spherecal.report.html.signing import CALIBRATION_VERSION, ReportVersion, report_versions

__all__ = ["write_report", "write_report_version", "CALIBRATION_VERSION", "ReportVersion", "report_versions", "mapped_points", "FIGURE_NAMES", "binned_residuals", "interactive_points", "mapped_centres",
           "plot_sample", "point_uncertainty", "profile_points_and_residuals", "row_percentiles", "sphere_directions"]
