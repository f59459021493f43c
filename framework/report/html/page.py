"""The report assembled and written: :func:`write_report` checks, draws the figures, writes the page."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from spherecal.core.errors import InputError
from spherecal.core.models import CalibrationResult
from spherecal.estimation.problem import KIND_PROFILE
from spherecal.io import files as safeio
from spherecal.io.exporters import ExportNote
from spherecal.report.assess import POINT_DISTANCE_MM, Thresholds, Verdict, advice, verdict
from spherecal.report.html import sections
from spherecal.report.html.data import centre_rows, mapped_points
from spherecal.report.html.figures import draw_figures
from spherecal.report.html.signing import ReportVersion, is_simulated, next_version, simulated_html, version_html


def write_report(
    solution,
    out_dir: str | Path,
    title: str = "spherecal calibration report",
    validation: Mapping[str, Any] | None = None,
    *,
    thresholds: Thresholds | None = None,
    filename: str = "report.html",
    verdict_override: Verdict | None = None,
    notes: Sequence[ExportNote] = (),
    validation_positions: Sequence[Mapping[str, Any]] | None = None,
    point_distance_mm: float = POINT_DISTANCE_MM,
    version: ReportVersion | None = None,
    calibrated_urdf: str | Path | None = None,
) -> Path:
    """Write the HTML report of ``solution`` (a :class:`spherecal.estimation.Solution`)
    into ``out_dir`` (created if needed) as ``filename``, with its figures saved beside
    it as ``<stem>_<figure>.png`` (:data:`FIGURE_NAMES`). ``validation`` is an optional
    mapping ``{figure name: value or {column: value}}`` shown as a table (a row whose
    ``passed`` is False is marked). ``verdict_override``: the verdict to show (e.g. with
    the likely cause ``app.solving`` found, or with the validation: ``assess.with_validation``),
    else the result's own. ``notes``: what the run's exporters say about using the result
    on the controller (:class:`ExportNote`, from ``ExportPlan.notes(result)``; the robot's
    own exporter first), shown under the transform. ``validation_positions``: the
    validation per position (``validation.position_rows``), shown under its figures.
    ``point_distance_mm``: the report gives the uncertainty of a point this far from the
    sensor. ``version``: the report's place among the calibration's reports, said under
    its title (:mod:`.signing`; :func:`write_report_version` writes a later one). A result
    whose provenance says it is simulated carries the SIMULATED mark. ``calibrated_urdf``:
    a kinematic calibration's ``robot_calibrated.urdf`` as written, linked from the report
    and shown in it. Returns the path of the HTML file. Overwrites an earlier report of the
    same name."""
    _check_arguments(solution, filename, notes, validation, validation_positions, point_distance_mm)
    result = solution.result
    th = thresholds or Thresholds()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if is_simulated(result.provenance):
        title = f"SIMULATED: {title}"
    pts = mapped_points(solution)  # the points in the sphere frame, mapped once for every figure
    figures = draw_figures(solution, result, out, filename[: -len(".html")], pts)
    body = _body(solution, title, figures, pts, th, verdict_override or verdict(result, th), notes, validation,
                 validation_positions, float(point_distance_mm), version, _urdf_link(calibrated_urdf, out))
    path = out / filename
    safeio.write_text(path, sections.document(title, "\n".join(body)))
    return path


def write_report_version(solution, out_dir: str | Path, added: str, **options) -> Path:
    """Write a later version of the calibration's report into ``out_dir``:
    ``report-<n>.html``, n one above the highest version there (at least 2), never over
    an existing file (the calibration's ``report.html`` and every earlier version stay as
    they were written). The page says which version it supersedes and that it adds
    ``added`` (one sentence). ``options``: those of :func:`write_report` but ``filename``
    and ``version``. Returns the path written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    taken = None
    for _ in range(100):
        version = next_version(out, added, after=taken)
        path = out / version.filename
        try:
            with safeio.open_for_write(path, exclusive=True):  # the name reserved: no other run takes it
                pass
        except FileExistsError:
            taken = version.number  # written since the versions were listed: the next one
            continue
        try:
            return write_report(solution, out, filename=version.filename, version=version, **options)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
    raise InputError(f"{out}: no free report version name found after {version.filename}")


def _urdf_link(path: str | Path | None, out: Path) -> tuple[str, str] | None:
    """(the link to a calibrated arm model from the report in ``out``, its text), or None."""
    if path is None:
        return None
    path = Path(path)
    href = path.name if path.parent.resolve() == out.resolve() else path.resolve().as_uri()
    return href, path.read_text(encoding="utf-8")


def _check_arguments(solution, filename, notes, validation, validation_positions, point_distance_mm) -> None:
    """Raise :class:`InputError` on an argument :func:`write_report` cannot use."""
    result = getattr(solution, "result", None)
    if not isinstance(result, CalibrationResult) or not hasattr(solution, "problem"):
        raise InputError(
            f"write_report needs the Solution returned by spherecal.estimation.solve, got {type(solution).__name__}"
        )
    if not filename.endswith(".html") or Path(filename).name != filename:
        raise InputError(f"filename {filename!r} must be a plain file name ending in .html")
    if isinstance(notes, (str, bytes)) or not all(isinstance(n, ExportNote) for n in notes):
        raise InputError("notes must be a sequence of spherecal.io.exporters.ExportNote")
    if validation is not None and not isinstance(validation, Mapping):
        raise InputError(f"validation must be a mapping of acceptance figures, got {type(validation).__name__}")
    if validation_positions is not None and (isinstance(validation_positions, (str, bytes, Mapping)) or not all(
            isinstance(r, Mapping) for r in validation_positions)):
        raise InputError("validation_positions must be a sequence of rows (mappings)")
    if not (isinstance(point_distance_mm, (int, float)) and np.isfinite(point_distance_mm) and point_distance_mm > 0):
        raise InputError(f"point_distance_mm must be a positive number of mm, got {point_distance_mm!r}")


def _body(solution, title: str, figures: Mapping[str, tuple[str, str]], pts: list[np.ndarray], th: Thresholds,
          ver: Verdict, notes: Sequence[ExportNote], validation: Mapping[str, Any] | None,
          validation_positions: Sequence[Mapping[str, Any]] | None, point_distance_mm: float,
          version: ReportVersion | None = None, urdf: tuple[str, str] | None = None) -> list[str]:
    """The parts of the page, top to bottom (a ``keep`` section is not split across printed pages)."""
    result = solution.result
    has_profiles = bool((solution.problem.kinds == KIND_PROFILE).any())
    has_centres = len(centre_rows(solution)) > 0
    with_validation = validation is not None or validation_positions is not None
    now = datetime.now(timezone.utc).isoformat(timespec="seconds")
    parts = [
        sections.header_html(title, result, has_centres, with_validation, now, has_profiles),
        version_html(version) if version is not None else "",
        simulated_html() if is_simulated(result.provenance) else "",
        sections.expectation_html(result),
        sections.headline_html(result, ver, th, notes, has_profiles),
        *(['<section class="keep"><h2 id="clock">The clock relation</h2>', sections.clock_html(result) + "</section>"]
          if result.timing is not None else []),
        '<section class="keep"><h2 id="identity">What was calibrated</h2>',
        sections.identity_html(result) + "</section>",
        '<h2 id="advice">What to do when something is off</h2>',
        sections.advice_html(advice(result, th)),
        '<section class="keep"><h2 id="residuals">Residuals</h2>',
        sections.residuals_intro_html(has_profiles, has_centres),
        sections.figure_html("residuals_per_profile", figures) + "</section>",
        *(sections.figure_html(key, figures) for key in (
            "residuals_per_centre", "residuals_per_station", "residual_histogram", "residuals_along_line",
            "residuals_on_sphere")),
        '<section class="keep"><h2 id="sphere">The sphere and the mapped points</h2>',
        sections.figure_html("sphere_3d", figures) + "</section>",
        sections.interactive_html(solution, result, pts) if has_profiles else "",
        '<section class="keep"><h2 id="uncertainty">Uncertainties</h2>',
        sections.uncertainty_html(result) + "</section>",
        '<section class="keep"><h3 id="correlation">Correlations of the parameters</h3>',
        sections.correlation_html(result) + "</section>",
        '<section class="keep"><h3 id="point">A point at a distance from the sensor</h3>',
        sections.point_html(result, point_distance_mm) + "</section>",
        *(['<h2 id="robot">Robot error</h2>', sections.robot_error_html(result, urdf)]
          if result.robot_error is not None else []),
        '<h2 id="stations">Stations</h2>',
        sections.stations_html(result, th),
        '<h2 id="flagged">Flagged observations</h2>',
        sections.flagged_html(result, has_profiles),
    ]
    if with_validation:
        parts += ['<section class="keep"><h2 id="validation">Validation</h2>',
                  (sections.validation_html(validation) if validation is not None else "") + "</section>"]
        if validation_positions is not None:
            parts.append('<section class="keep">' + sections.positions_html(validation_positions) + "</section>")
    parts += ['<h2 id="details">Details</h2>', sections.details_html(result),
              '<section class="keep"><h2 id="signature">Sign-off</h2>',
              sections.signature_html() + "</section>",
              sections.footer_html()]
    return parts
