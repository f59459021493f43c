"""The HTML of each part of the report: the verdict and transform, tables, the interactive view, the page frame."""

from __future__ import annotations

import html
import json
from collections.abc import Mapping, Sequence
from importlib import resources
from string import Template
from typing import Any

import numpy as np

from spherecal import __version__
from spherecal.core.errors import InputError
from spherecal.core.models import SPHERE_FRAME, CalibrationResult
from spherecal.estimation.pipeline import POINT_ERROR_PARTS
from spherecal.io.exporters import CALIBRATED_URDF_NAME, ExportNote, calibrated_model_warning
from spherecal.report import export
from spherecal.report.assess import (Thresholds, expected_rms_mm, inconsistent_stations, station_disagreement_text,
                                     start_vs_refined, station_prediction)
from spherecal.report.html.data import K_EXPANDED, interactive_points, point_uncertainty
from spherecal.report.html.signing import is_simulated, provenance_rows
from spherecal.report.terminal import point_error_lines, timing_lines


def _e(value: Any) -> str:
    """``value`` as HTML text, quotes escaped (safe in an attribute)."""
    return html.escape(str(value), quote=True)


def _n(value: float | None, decimals: int = export.MM_DECIMALS) -> str:
    """``value`` with ``decimals`` fixed decimals (by default the exports' millimetres); a
    dash for None."""
    if value is None:
        return "&ndash;"
    return export.fixed(value, decimals)


def interactive_html(solution, result, pts: list[np.ndarray] | None = None) -> str:
    """An interactive 3-D view that works offline: the data inline as JSON and a small
    self-contained script drawing on a canvas (drag to turn, wheel to zoom). Hidden in
    print, where the static figures stand."""
    data = interactive_points(solution, pts=pts)
    if not data["points"]:
        return ""
    data["frame"] = SPHERE_FRAME[result.mounting]
    js = resources.files(__package__).joinpath("view3d.js").read_text(encoding="utf-8")
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    n = len(data["residuals"])
    return ('<section class="interactive"><h3 id="view3d">Interactive 3-D view</h3>'
            f'<p>{n} of {data["total"]} points, relative to the fitted centre in the {_e(data["frame"])} frame, '
            "coloured by their residual (blue: negative, red: positive). Drag to turn, wheel or +/- to zoom, "
            "double-click to reset; the residuals can be exaggerated radially with the slider. Works offline: "
            "nothing is loaded from the network.</p>"
            '<canvas id="view3d-canvas" width="720" height="520" tabindex="0"></canvas>'
            '<div class="view3d-controls"><label>radial exaggeration <input id="view3d-gain" type="range" '
            'min="0" max="3" step="0.05" value="0"> <output id="view3d-gain-out">x1</output></label></div>'
            f'<script type="application/json" id="view3d-data">{payload}</script>'
            f"<script>{js}</script></section>")


def _table(header: list[str], rows: list[list[str]], row_classes: list[str] | None = None) -> str:
    head = "".join(f"<th>{h}</th>" for h in header)
    body = []
    for k, row in enumerate(rows):
        cls = f' class="{row_classes[k]}"' if row_classes and row_classes[k] else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _notes_html(notes: Sequence[ExportNote]) -> str:
    """The exporters' notes: how to use the result on the controller, the robot's own
    exporter first."""
    if not notes:
        return ("<p>No exporter of this run says how to load the result on a controller; the files next to this "
                "report hold it (docs/results.md).</p>")
    return "".join(f"<h4>{_e(n.title)}</h4><p>{_e(n.text)}</p>" + (f"<pre>{_e(n.code)}</pre>" if n.code else "")
                   for n in notes)


def headline_html(result: CalibrationResult, ver, th: Thresholds, notes: Sequence[ExportNote] = (),
                  has_profiles: bool = True) -> str:
    """The verdict, the transform's cards (a profile's tile only with profiles; numbers
    with the exports' decimals), its matrices and the exporters' notes."""
    name = result.transform_name
    a, b = export.frames_of(name)
    inv = export.inverse_name(name)
    x, y, z = result.transform.translation_mm
    q = result.transform.quaternion_wxyz
    sr, st = result.std_rotation_deg, result.std_translation_mm
    reasons = "".join(f'<li><span class="dot {lv}"></span>{_e(text)}</li>' for lv, text in ver.reasons)
    exp = expected_rms_mm(result, th)
    point = (result.diagnostics.noise or {}).get("point_noise_mm")
    cards = [
        ("translation (mm)", f"{_n(x)}, {_n(y)}, {_n(z)}"),
        ("quaternion (w, x, y, z)", ", ".join(_n(v, export.QUAT_DECIMALS) for v in q)),
        (f"rotation 1-sigma about {a} x, y, z (deg)", ", ".join(_n(v) for v in sr)
         + f"<br><span class='muted'>U (k = 2): {', '.join(_n(K_EXPANDED * v) for v in sr)}</span>"),
        (f"translation 1-sigma along {a} x, y, z (mm)", ", ".join(_n(v) for v in st)
         + f"<br><span class='muted'>U (k = 2): {', '.join(_n(K_EXPANDED * v) for v in st)}</span>"),
        ("residual RMS (mm)", f"{_n(result.residuals.rms_mm)} <span class='muted'>expected {_n(exp)}</span>"),
        ("sensor point noise (mm)", f"{_n(point)}" + (
            f" <span class='muted'>RMS / noise {result.residuals.rms_mm / point:.1f}</span>" if point else "")),
        *([("profiles used / flagged", f"{result.residuals.n_profiles_used} / {len(result.flagged)}")]
          if has_profiles else [("observations flagged", str(len(result.flagged)))]),
        *([("centre observations used", f"{result.residuals.n_centres_used} (residual RMS "
            f"{_n(result.residuals.centre_rms_mm)} mm, 3-D)")] if result.residuals.n_centres_used else []),
        *([("points used / rejected", f"{result.residuals.n_points_used} / {result.residuals.n_points_rejected}")]
          if has_profiles else []),
    ]
    card_html = "".join(f'<div class="card"><div class="label">{_e(lbl)}</div><div class="value">{val}</div></div>'
                        for lbl, val in cards)
    return f"""
<div class="verdict {ver.level}" id="verdict">
  <div class="big">Verdict: {ver.level.upper()} &mdash; {_e(ver.headline)}</div>
  <ul>{reasons}</ul>
</div>
<h2 id="transform">The transform: <code>{_e(name)}</code></h2>
<p class="direction"><b>{_e(name)}</b> maps points from the <b>{_e(b)}</b> frame into the <b>{_e(a)}</b> frame:
<code>p_{_e(a)} = R p_{_e(b)} + t</code>; its translation is the origin of {_e(b)} in {_e(a)} (mm).
Mounting: {_e(result.mounting)}. Its inverse is <code>{_e(inv)}</code>.</p>
<div class="cards">{card_html}</div>
<h3>As 4x4 matrices (mm), both directions</h3>
<pre>{_e(export.matrix_text(result))}</pre>
<h3 id="controller">For the robot controller and for ROS</h3>
{_notes_html(notes)}
<p class="muted">Uncertainties are one standard deviation (double them for about 95 %), after scaling by the
a-posteriori variance factor {result.variance_factor:.3f}. Rotations are small rotations about the axes of the
{_e(a)} frame. The files next to this report hold the same numbers (see docs/results.md).</p>
"""


def clock_html(result: CalibrationResult) -> str:
    """A recording's clock relation in the terminal's words (:func:`~spherecal.report.terminal.timing_lines`):
    the model, the offset and drift with their 1-sigma, whether the data identify it, and
    poses that were not measured; what the terms mean below. Empty without ``timing``
    (stop-and-go data)."""
    timing = result.timing
    if timing is None:
        return ""
    first, *rest = (line.strip() for line in timing_lines(timing))
    items = "".join(f"<li>{f'<b>{_e(line)}</b>' if 'NOT' in line else _e(line)}</li>" for line in rest)
    return (f'<div class="advice {"green" if timing.identifiable else "amber"}"><p>{_e(first)}</p><ul>{items}</ul>'
            "</div><p class=\"muted\">A profile stamped t_sensor by the sensor's clock was exposed when the robot's "
            "clock read t_robot. The offset is the robot clock minus the sensor clock at t_sensor0, the first "
            "profile's stamp; the drift is the robot clock's rate relative to the sensor's, minus 1, in parts per "
            "million. They were estimated with the transform (1-sigma from the joint fit; a drift said to be held was "
            "not estimated); result.json holds them as "
            "<code>timing</code> (docs/conventions.md, \"Time: two clocks\").</p>")


def advice_html(items) -> str:
    if not items:
        return "<p>Nothing calls for action: residuals, uncertainties and stations look as they should.</p>"
    return "".join(f'<div class="advice {a.level}"><h3><span class="dot {a.level}"></span>{_e(a.title)}</h3>'
                    f"<p>{_e(a.text)}</p></div>" for a in items)


def uncertainty_html(result: CalibrationResult) -> str:
    a, b = export.frames_of(result.transform_name)
    frame = result.sphere_centre_frame
    rows = []

    def add(name, value, sd, unit):
        rows.append([name, value, _n(sd), _n(K_EXPANDED * sd) if sd is not None else "&ndash;", unit])

    for k, ax in enumerate("xyz"):
        add(f"rotation about {a} {ax}", "&ndash;", result.std_rotation_deg[k], "deg")
    for k, ax in enumerate("xyz"):
        add(f"translation along {a} {ax}", _n(result.transform.translation_mm[k]), result.std_translation_mm[k], "mm")
    for k, ax in enumerate("xyz"):
        add(f"sphere centre {ax} ({frame} frame)", _n(result.sphere_centre_mm[k]), result.std_sphere_centre_mm[k], "mm")
    if result.radius_fitted:
        add("sphere radius (fitted)", _n(result.sphere_radius_mm), result.std_sphere_radius_mm, "mm")
    else:
        rows.append(["sphere radius (certified, fixed)", _n(result.sphere_radius_mm), "fixed", "fixed", "mm"])
    robot = result.robot_error
    note = ""
    if robot is not None:
        note = ("<p class=\"muted\">Relative to the robot's own frame (the robot's accuracy shared by every station "
                "left out: what two calibrations on this robot can differ by), 1-sigma / k = 2: rotation "
                + ", ".join(f"{_n(v)} / {_n(K_EXPANDED * v)}" for v in robot.std_rotation_deg_robot_frame)
                + " deg; translation "
                + ", ".join(f"{_n(v)} / {_n(K_EXPANDED * v)}" for v in robot.std_translation_mm_robot_frame)
                + " mm.</p>")
    pred = station_prediction(result)
    if pred is not None:
        note += _gauge_note(pred)
    return (_table(["quantity", "value", "1-sigma", f"expanded U (k = {K_EXPANDED:g})", "unit"], rows)
            + "<p class=\"muted\">1-sigma is the standard uncertainty; U = 2 sigma the expanded uncertainty, about "
              "95 % coverage for a normal distribution. Both include the robot's accuracy (its error shared by every "
              "station, which no data from one sphere location can see; docs/estimation.md).</p>" + note)


def _gauge_note(pred) -> str:
    """A kinematic calibration: the transform's own uncertainties are gauge-dependent;
    what a point at a new pose gets, through the calibrated arm and the transform."""
    worst = ("station(s) " + ", ".join(pred.unpredictable_stations) + " cannot be predicted from the others"
             if pred.unpredictable_stations else
             f"worst {_n(pred.per_station_mm[pred.worst_station])} mm at station {_e(pred.worst_station)}")
    return ("<p><strong>Gauge-dependent.</strong> The arm's geometry was identified with the transform: the two trade "
            "against each other along directions the data see only together, so the transform's 1-sigmas above "
            "(and relative to the robot's frame) depend on how that trade is fixed (the arm's parameters no data "
            "from one sphere can see are kept at their nominal values) and are not graded. Use the transform only "
            "with the calibrated arm model (robot_calibrated.urdf). What a point at a new pose gets through both: "
            f"each station predicted from the others misses where it sees the sphere by {_n(pred.rms_mm)} mm RMS "
            f"(3-D; {worst}), against {_n(pred.expected_rms_mm)} mm that the noise and the fit's uncertainty "
            "explain. This is what the verdict grades.</p>")


def expectation_html(result: CalibrationResult) -> str:
    """What the result means for a point measured at a new pose, as the terminal leads with
    it (:func:`spherecal.report.terminal.point_error_lines`); for a kinematic calibration,
    marked: the accuracy holds only through spherecal's calibrated arm model, and the
    controller's nominal model gives the first figure. Empty without a robot error model."""
    lines = point_error_lines(result)
    if not lines:
        return ""
    warning = calibrated_model_warning(result)
    text = "".join(f"<p>{_e(line.strip()[:1].upper() + line.strip()[1:])}</p>" for line in lines)
    if warning:
        text += ("<p>The transform goes with the calibrated arm model: a controller given the transform alone keeps "
                 "its nominal model. Give the robot the model (<a href=\"#kinematic\">the identified geometry "
                 "below</a>, robot_calibrated.urdf) wherever the calibrated accuracy is needed. Every export says the "
                 "same in its first comment.</p>")
    return (f'<div class="advice {"amber" if warning else ""}" id="expectation"><h3>A point measured at a new pose'
            f"</h3>{text}</div>")


def robot_error_html(result: CalibrationResult, urdf: tuple[str, str] | None = None) -> str:
    """The robot error model's terms: which model and why (``auto``'s likelihood ratio),
    the arm's parameters seen, identified or marginalised and the prior spread, the
    stations' disagreement, the point error's parts (k = 1) and totals (k = 2); for a
    kinematic calibration the identified parameters and the calibrated model
    (:func:`_kinematic_html`; ``urdf``: its link and text, None when it was not written)."""
    err = result.robot_error
    if err is None:
        return "<p>No robot error model: the robot's pose error entered as noise only.</p>"
    params = err.kinematic_parameters
    if params is not None:
        n_cal, n_seen = sum(p.identified for p in params), sum(p.identifiable for p in params)
        model = ("the arm's geometry (kinematic model): "
                 + (f"{n_cal} of its {len(params)} geometric parameters identified with the transform" if n_cal else
                    f"{n_seen} of its {len(params)} geometric parameters seen by the data, all marginalised (their "
                    f"prior spread x {export.fixed(err.kinematic_prior_scale or 1.0, 2)}, as the data showed it)"))
    else:
        model = {"station": "a pose offset shared by the shots of a station (the station model)",
                 "kinematic+station": "the arm's geometry and a pose offset per station",
                 "none": "none: the robot's pose error entered as noise only"}.get(err.model, err.model)
    rows = [[_e(POINT_ERROR_PARTS.get(k, k)), _n(v)] for k, v in err.point_error_parts_rms_mm.items()]
    calibrated = any(p.identified for p in params or [])
    through = " through the calibrated arm model" if calibrated else ""
    rows.append([f"<b>expected error{through}, k = 2</b>", f"<b>{_n(err.point_error_k2_mm)}</b>"])
    if err.point_error_nominal_arm_k2_mm is not None:
        rows.append(["expected error on the controller's nominal arm model, k = 2",
                     _n(err.point_error_nominal_arm_k2_mm)])
    stated = " as the options state it, not estimated" if err.model == "station" and not err.estimated else ""
    disagreement = (f"<p>The stations disagree by {_e(station_disagreement_text(err))} (1-sigma{stated}).</p>"
                    if not calibrated else "")
    assumed = (f"<p>Assumed accuracy of the robot shared by every station: {_n(err.common_translation_mm)} mm, "
               f"{_n(err.common_rotation_deg)} deg per axis.</p>" if err.model in ("station", "kinematic+station") else "")
    return (f"<p>Model: {_e(model)}.</p>" + (f"<p>{_e(err.model_choice)}.</p>" if err.model_choice else "")
            + disagreement + assumed
            + "<h3 id=\"point-budget\">A point measured at a new pose like the calibration's</h3>"
            + _table(["part", "RMS 3-D, k = 1 (mm)"], rows)
            + (_kinematic_html(result, urdf) if calibrated else ""))


def _kinematic_html(result: CalibrationResult, urdf: tuple[str, str] | None) -> str:
    """A kinematic calibration: where its accuracy holds, the identified parameters with
    their 1-sigma, and the calibrated arm model offered (a link and its text)."""
    params = result.robot_error.kinematic_parameters
    rows = [[_e(p.name), _n(p.value), _n(p.std), _e(p.unit)] for p in params if p.identified]
    held = len(params) - len(rows)
    if urdf is None:
        model = (f"<p>{CALIBRATED_URDF_NAME} was not written (a RED result written without --force, or the robot's "
                 "kinematics not given to the run).</p>")
    else:
        href, text = urdf
        model = (f'<p>The calibrated arm model: <a href="{_e(href)}">{_e(CALIBRATED_URDF_NAME)}</a> (URDF, metres and '
                 "radians, the joint zero offsets folded into the joint origins; docs/conventions.md, \"URDF\").</p>"
                 f"<details><summary>its text</summary><pre>{_e(text)}</pre></details>")
    return ('<h3 id="kinematic">The arm\'s identified geometry</h3>'
            f"<p><strong>{_e(calibrated_model_warning(result))}.</strong></p>"
            + _table(["parameter", "estimate", "1-sigma", "unit"], rows)
            + f"<p class=\"muted\">In the robot model's joint frames; the other {held} parameters are held at their "
              "nominal values (no data from one sphere can tell them from the transform and the sphere). result.json: "
              "robot_error.kinematic_parameters.</p>" + model)


def _short_label(label: str) -> str:
    """``rotation about flange x`` -> ``rot x``; for the correlation matrix's columns."""
    for long, short in (("rotation about ", "rot "), ("translation along ", "t "), ("sphere centre ", "c "),
                        ("sphere radius", "r")):
        if label.startswith(long):
            rest = label[len(long):].split(" (")[0]
            return short + rest.split(" ")[-1] if short != "r" else "r"
    return label


def correlation_html(result: CalibrationResult) -> str:
    corr = result.correlation
    if corr is None:
        return "<p>No correlation matrix: the result has no covariance.</p>"
    labels = corr.parameters
    m = np.asarray(corr.matrix, dtype=float)
    head = "".join(f"<th title=\"{_e(lbl)}\">{_e(_short_label(lbl))}</th>" for lbl in labels)
    body = []
    for i, lbl in enumerate(labels):
        cells = []
        for j in range(len(labels)):
            v = m[i, j]
            cls = "diag" if i == j else "strong" if abs(v) >= 0.9 else "notable" if abs(v) >= 0.7 else ""
            cells.append(f'<td class="{cls}">{v:+.2f}</td>' if cls else f"<td>{v:+.2f}</td>")
        body.append(f"<tr><th>{_e(lbl)}</th>{''.join(cells)}</tr>")
    strongest = max(((abs(m[i, j]), i, j) for i in range(len(labels)) for j in range(i)), default=None)
    text = ""
    if strongest is not None:
        v, i, j = strongest
        text = (f"<p>Largest correlation: {m[i, j]:+.2f} between {_e(labels[i])} and {_e(labels[j])}. Strongly "
                "correlated parameters (|r| &ge; 0.9, marked) are determined together: each alone is known worse "
                "than their combination; more varied tilts between the stations decorrelate them.</p>")
    return (f'<table class="matrix"><thead><tr><th>correlation</th>{head}</tr></thead><tbody>{"".join(body)}'
            "</tbody></table>" + text + "<p class=\"muted\">Derived from the covariance (result.json "
            "<code>correlation</code>): r = cov / (sigma sigma).</p>")


def point_html(result: CalibrationResult, distance_mm: float) -> str:
    a = export.frames_of(result.transform_name)[0]
    distances = sorted({0.0, distance_mm / 2, float(distance_mm), 2.0 * distance_mm})
    rows, classes = [], []
    for d in distances:
        u = point_uncertainty(result, d)
        rows.append([f"{d:g}", *(_n(x) for x in u["sd_mm"]), _n(u["rms_mm"]), f"<b>{_n(u['expanded_k2_mm'])}</b>"])
        classes.append("chosen" if d == distance_mm else "")
    chosen = point_uncertainty(result, distance_mm)
    return (f"<p>A point measured <b>{distance_mm:g} mm</b> from the sensor, along its line of sight, lands within "
            f"<b>{_n(chosen['expanded_k2_mm'])} mm</b> (3-D, k = 2) of where the calibration puts it, from the "
            f"transform's uncertainty alone (the chosen distance: <code>[report] point_distance_mm</code>). The robot's "
            "pose error and the sensor's noise at that pose come on top (the verdict's point error).</p>"
            + _table(["distance (mm)", f"1-sigma {a} x (mm)", f"1-sigma {a} y (mm)", f"1-sigma {a} z (mm)",
                      "RMS 3-D (mm)", "U 3-D, k = 2 (mm)"], rows, classes))


def stations_html(result: CalibrationResult, th: Thresholds) -> str:
    cons = result.diagnostics.station_consistency or {}
    per = result.residuals.per_station_rms_mm
    bad = inconsistent_stations(result, th)
    flagged_by_station: dict[str, int] = {}
    for f in result.flagged:
        flagged_by_station[f.station] = flagged_by_station.get(f.station, 0) + 1
    labels = list(dict.fromkeys(list(per) + list(cons) + list(flagged_by_station)))
    rows, classes = [], []
    for label in labels:
        c = cons.get(label, {})
        status = '<span class="dot red"></span>inconsistent' if label in bad else '<span class="dot green"></span>ok'
        if label not in per:
            status = '<span class="dot red"></span>not used'
        rows.append([_e(label), str(c.get("n_profiles", "&ndash;")), _n(per.get(label)), _n(c.get("rms_mm")),
                     _n(c.get("max_mm")), str(flagged_by_station.get(label, 0)), status])
        classes.append("bad" if label in bad or label not in per else "")
    return (_table(["station", "profiles", "residual RMS (mm)", "consistency RMS (mm)", "consistency max (mm)",
                    "flagged", "status"], rows, classes)
            + '<p class="muted">Consistency: within a station the robot only translates, so the sphere centre seen '
              "by the sensor must move exactly as the robot moved; RMS and max of the mismatch.</p>")


def flagged_html(result: CalibrationResult, has_profiles: bool = True) -> str:
    if not result.flagged:
        return f"<p>No observation was flagged: every {'profile' if has_profiles else 'observation'} was used.</p>"
    rows = [[str(f.index), _e(f.station), f'<span class="reason">{_e(f.reason)}</span>'] for f in result.flagged]
    return _table(["observation", "station", "why it was left out"], rows, ["bad"] * len(rows))


def validation_html(validation: Mapping[str, Any]) -> str:
    if not isinstance(validation, Mapping):
        raise InputError(f"validation must be a mapping of acceptance figures, got {type(validation).__name__}")
    columns: list[str] = []
    for value in validation.values():
        for key in (value if isinstance(value, Mapping) else {"value": None}):
            if key not in columns:
                columns.append(key)

    def cell(v):
        if isinstance(v, bool):
            return '<span class="dot green"></span>yes' if v else '<span class="dot red"></span>no'
        if isinstance(v, (int, float, np.floating)) and not isinstance(v, bool):
            return _n(float(v)) if isinstance(v, (float, np.floating)) else str(v)
        return "&ndash;" if v is None else _e(v)

    rows, classes = [], []
    for name, value in validation.items():
        row = value if isinstance(value, Mapping) else {"value": value}
        rows.append([_e(name)] + [cell(row.get(col)) for col in columns])
        failed = any(row.get(k) is False for k in ("passed", "pass", "ok", "accepted"))
        classes.append("bad" if failed else "")
    return _table(["figure"] + [_e(c) for c in columns], rows, classes)


def positions_html(rows: Sequence[Mapping[str, Any]]) -> str:
    """The validation per position: one row per position and figure."""
    body, classes = [], []
    for r in rows:
        passed = r.get("passed")
        verdict_cell = {True: '<span class="dot green"></span>pass', False: '<span class="dot red"></span>FAIL',
                        None: "not judged"}[passed]
        mpe = r.get("MPE (mm)")
        if passed and r.get("U (mm, k = 2)") is not None and abs(r["error (mm)"]) > mpe:  # beyond the MPE, within U
            verdict_cell = f'<span class="dot green"></span>within U ({_n(r.get("U (mm, k = 2)"))} mm, k = 2)'
        body.append([_e(r.get("position", "")), _e(r.get("artefact", "")), _e(r.get("figure", "")),
                     _n(r.get("error (mm)")), "&ndash;" if mpe is None else _n(mpe), verdict_cell])
        classes.append("bad" if passed is False else "")
    return ("<h3>Per position</h3>"
            + _table(["position", "artefact", "figure", "error (mm)", "MPE (mm)", "verdict"], body, classes))


def identity_html(result: CalibrationResult) -> str:
    """What was calibrated, by whom, when, from which files: the result's provenance as a
    table, what it holds besides the rows below in rows of their own."""
    p = result.provenance or {}

    def device(kind: str) -> str:
        d = p.get(kind)
        if not isinstance(d, Mapping):
            return _e(d) if d else "&ndash;"
        parts = [f"<b>{_e(d['type'])}</b>" if d.get("type") else "type not recorded"]
        for key in ("manufacturer", "model", "serial_number", "firmware", "controller"):
            if d.get(key):
                parts.append(f"{key.replace('_', ' ')}: {_e(d[key])}")
        if not d.get("serial_number"):
            parts.append('<span class="muted">serial number not reported</span>')
        return "; ".join(parts)

    sphere = p.get("sphere") if isinstance(p.get("sphere"), Mapping) else {}
    radius = sphere.get("radius_mm", result.sphere_radius_mm)
    u = sphere.get("radius_uncertainty_mm_k2")
    cert = (f"radius {_n(radius)} mm" + (f", U = {_n(u)} mm (k = 2)" if u is not None else
                                          ' <span class="muted">(uncertainty not given: sphere.radius_uncertainty_mm)'
                                          "</span>")
            + (f"; certificate {_e(sphere['certificate'])}" if sphere.get("certificate") else ""))

    def sha(key: str, file_key: str) -> str:
        if not p.get(key):
            return "&ndash;"
        return f'<code class="hash">{_e(p[key])}</code><br><span class="muted">{_e(p.get(file_key) or "")}</span>'

    rows = [
        ["cell", _e(p.get("cell") or "&ndash;") if p.get("cell") else "&ndash;"],
        ["robot", device("robot")],
        ["sensor", device("sensor")],
        ["reference sphere", cert],
        ["operator", _e(p["operator"]) if p.get("operator") else "&ndash;"],
        ["calibrated", _e(p.get("calibrated_at") or "&ndash;")],
        ["software", _e(p.get("software") or f"spherecal {__version__}")],
        ["dataset (SHA-256)", sha("dataset_sha256", "dataset_file")],
        ["configuration (SHA-256)", sha("configuration_sha256", "configuration_file")],
    ]
    rows.append(["data from", _e(p.get("dataset") or "&ndash;") if p.get("dataset") else "&ndash;"])
    if result.timing is not None and result.timing.poses_assumed:
        rows.append(["robot poses", f"<b>not measured</b>: {_e(result.timing.poses_assumed)}"])
    rows.append(["simulated", "<b>yes: SIMULATED</b>, not a real cell" if is_simulated(p)
                 else "no" if p.get("simulated") is False else "&ndash; (not recorded)"])
    shown = ("cell", "robot", "sensor", "sphere", "operator", "calibrated_at", "software", "dataset_sha256",
             "dataset_file", "configuration_sha256", "configuration_file", "dataset", "simulated")
    rows += [[k, v] for k, v in provenance_rows(p, leave_out=shown)]
    return "<table>" + "".join(f'<tr><th>{k}</th><td class="text">{v}</td></tr>' for k, v in rows) + "</table>"


def signature_html() -> str:
    """Lines to sign on paper: who calibrated, who approved, with dates."""
    return "".join(f'<div class="signature"><div><span>{who} (name)</span></div><div><span>Date</span></div>'
                   "<div><span>Signature</span></div></div>" for who in ("Calibrated by", "Approved by"))


def details_html(result: CalibrationResult) -> str:
    d = result.diagnostics
    ref = d.refinement or {}
    noise = d.noise or {}
    tsr = start_vs_refined(d)
    start = "two-step" if d.two_step_vs_refined or not d.start else f"{d.start.get('method', '?')} start"
    rows = [
        ["method", _e(result.method)],
        ["variance factor (chi&sup2;/dof)", _n(result.variance_factor, 3)],
        ["refinement", f"{ref.get('iterations', '?')} iterations, converged: {ref.get('converged', '?')}"],
        ["information condition number", f"{ref.get('information_condition_number', float('nan')):.3g}"],
        ["orientations (stations)", str("?" if d.orientations is None else d.orientations)],
        [f"{start} vs refined", f"{_n(tsr.get('rotation_deg'))} deg, {_n(tsr.get('translation_mm'))} mm"],
        ["noise used (point / pose translation / pose rotation)",
         f"{_n(noise.get('point_noise_mm'))} mm / {_n(noise.get('pose_translation_noise_mm'))} mm / "
         f"{_n(noise.get('pose_rotation_noise_deg'))} deg"],
        ["residual max |e| / 95th percentile", f"{_n(result.residuals.max_abs_mm)} / {_n(result.residuals.p95_abs_mm)} mm"],
        ["provenance", 'the table under <a href="#identity">What was calibrated</a>'],
    ]
    return "<table>" + "".join(f'<tr><th>{k}</th><td class="text">{v}</td></tr>' for k, v in rows) + "</table>"


# --- the page frame ---------------------------------------------------------------------------------
def header_html(title: str, result: CalibrationResult, has_centres: bool, with_validation: bool,
                generated_at: str, has_profiles: bool = True) -> str:
    """The title, the line under it (mounting, transform, data, when and by what the
    report was made) and the links to the sections."""
    nav = ["verdict", "identity", "transform", *(["clock"] if result.timing is not None else []), "advice",
           "residuals", "sphere", "uncertainty",
           *(["robot"] if result.robot_error is not None else []), "stations", "flagged"]
    if with_validation:
        nav.append("validation")
    nav += ["details", "signature"]
    return "\n".join([
        f"<h1>{_e(title)}</h1>",
        f'<p class="sub">{_e(result.mounting)} &middot; {_e(result.transform_name)}'
        + (f" &middot; {result.residuals.n_profiles_used} profiles" if has_profiles else "")
        + (f" &middot; {result.residuals.n_centres_used} centre observations" if has_centres else "")
        + f" &middot; generated {generated_at} by spherecal {_e(__version__)}</p>",
        "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in nav) + "</nav>",
    ])


def residuals_intro_html(has_profiles: bool, has_centres: bool) -> str:
    """What a residual is, for the kinds of observation the data has."""
    return ("<p>"
            + ("A residual is the in-plane distance (mm) of a profile point from the circle where the laser plane "
               "cuts the fitted sphere. " if has_profiles else "")
            + ("A centre observation's residual has three components (mm): a sphere centre's x, y and z from where "
               "the fit puts the centre; a circle's centre y and z, and its radius against the circle the laser "
               "plane cuts from the fitted sphere." if has_centres else "")
            + "</p>")


def figure_html(key: str, figures: Mapping[str, tuple[str, str]]) -> str:
    """Figure ``key`` of ``figures`` ((PNG in base64, caption) by key) as an embedded
    image with its caption; nothing when the report has no such figure."""
    if key not in figures:
        return ""
    data, caption = figures[key]
    return (f'<figure id="fig-{key}"><img alt="{_e(key.replace("_", " "))}" '
            f'src="data:image/png;base64,{data}"><figcaption>{_e(caption)}</figcaption></figure>')


def footer_html() -> str:
    return (f"<footer>spherecal {_e(__version__)} &middot; conventions: docs/conventions.md &middot; "
            "this report: docs/results.md</footer>")


def document(title: str, body: str) -> str:
    """The whole page: ``body`` in the page template (report.html) with the style sheet
    (report.css) inlined."""
    template = Template(resources.files(__package__).joinpath("report.html").read_text(encoding="utf-8"))
    css = resources.files(__package__).joinpath("report.css").read_text(encoding="utf-8")
    return template.substitute(title=_e(title), css=css, body=body, version=_e(__version__))
