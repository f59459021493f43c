"""The calibration's result, verdict and simulated truth as the terminal prints them."""

from __future__ import annotations

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.models import Dataset, Pose
from spherecal.estimation import Solution
from spherecal.estimation.pipeline import POINT_ERROR_PARTS
from spherecal.io.exporters import CALIBRATED_URDF_NAME
from spherecal.report.assess import Verdict, advice, station_disagreement_text, verdict


def summary(solution: Solution, graded: Verdict | None = None) -> str:
    """The result in a few lines: both directions, xyz + ABB quaternion, uncertainties,
    and the verdict (``graded``, else computed from the result), with the reasons for a
    RED one."""
    r = solution.result
    X = r.transform
    inv = X.inverse()
    a, b = r.transform_name.split("_from_")
    q = ", ".join(f"{v:.8f}" for v in X.quaternion_wxyz)
    t = ", ".join(f"{v:.4f}" for v in X.translation_mm)
    lines = [
        f"{r.transform_name} (maps points in {b} to {a}):",
        f"  translation_mm  = [{t}]",
        f"  quaternion_wxyz = [{q}]",
        f"  std: rotation {', '.join(f'{v:.4f}' for v in r.std_rotation_deg)} deg about {a} x, y, z; "
        f"translation {', '.join(f'{v:.4f}' for v in r.std_translation_mm)} mm",
        f"  expanded U (k = 2): rotation {', '.join(f'{2 * v:.4f}' for v in r.std_rotation_deg)} deg; "
        f"translation {', '.join(f'{2 * v:.4f}' for v in r.std_translation_mm)} mm",
        f"{b}_from_{a}: translation_mm = [{', '.join(f'{v:.4f}' for v in inv.translation_mm)}], "
        f"quaternion_wxyz = [{', '.join(f'{v:.8f}' for v in inv.quaternion_wxyz)}]",
        f"residuals: RMS {r.residuals.rms_mm:.4f} mm over {r.residuals.n_points_used} points of "
        f"{r.residuals.n_profiles_used} profiles; {r.residuals.n_points_rejected} stray points rejected"
        + (f"; {r.residuals.n_centres_used} centre observations, their residuals {r.residuals.centre_rms_mm:.4f} mm "
           f"RMS (3-D), {r.residuals.centre_max_mm:.4f} mm at most" if r.residuals.n_centres_used else ""),
    ]
    if r.robot_error is not None:
        lines.extend(_robot_error_lines(r.robot_error))
    if r.timing is not None:
        lines.extend(_timing_lines(r.timing))
    if r.timing is not None:
        lines.extend(_flagged_profile_lines(r.flagged))
    else:
        for f in r.flagged[:MAX_FLAG_LINES]:
            lines.append(f"flagged observation {f.index} (station {f.station}): {f.reason}")
        if len(r.flagged) > MAX_FLAG_LINES:
            lines.append(f"... and {len(r.flagged) - MAX_FLAG_LINES} more flagged observations (result.json, 'flagged')")
    graded = graded or verdict(r)
    lines.append(format_verdict(graded))
    if graded.level in ("red", "amber"):  # what to do, as the report gives it (its headline points here)
        todo = [a for a in advice(r) if a.level in ("red", "amber")]
        lines.extend(f"  advice: {a.title}: {a.text}" for a in todo[:4])
        if len(todo) > 4:
            lines.append(f"  advice: {len(todo) - 4} more in the report")
    return "\n".join(lines)


#: Flagged observations listed one per line; the rest are counted (all are in result.json).
MAX_FLAG_LINES = 12


def _flagged_profile_lines(flagged) -> list[str]:
    """A recording's flagged profiles, counted by their reason's kind (the words before
    its first colon or figure), one example of each: thousands of profiles leave dozens at
    the sphere's rim, which a list would bury the result under."""
    if not flagged:
        return []
    kinds: dict[str, list] = {}
    for f in flagged:
        head = f.reason.split(":")[0]
        head = head.split("(")[0].strip()
        kinds.setdefault(head, []).append(f)
    lines = [f"{len(flagged)} profiles left out (all in result.json, 'flagged'):"]
    for head, members in sorted(kinds.items(), key=lambda kv: -len(kv[1])):
        f = members[0]
        lines.append(f"  {len(members)} x {head}; e.g. profile {f.index} (station {f.station}): {f.reason}")
    return lines


def _timing_lines(timing) -> list[str]:
    """A recording's clock relation (docs/conventions.md, "Time")."""
    drift = (f"drift {timing.drift_ppm:.3f} +/- {timing.drift_std_ppm:.3f} ppm" if timing.drift_estimated
             else f"drift held at {timing.drift_ppm:.3f} ppm (not estimated: a recording too short to show it, or both "
             "streams stamped by one clock)")
    return [
        f"clock relation: t_robot = t_sensor + offset + drift (t_sensor - {timing.t_sensor0_s:.6f} s):",
        f"  offset {timing.offset_ms:.4f} +/- {timing.offset_std_ms:.4f} ms (robot clock minus sensor clock"
        + (f", {timing.offset_ms / 1e3:.7f} s: the clocks count from different epochs" if abs(timing.offset_ms) > 1e6
           else "") + f"); {drift}",
        f"  {'identified' if timing.identifiable else 'NOT identified'}: {timing.identifiability}",
    ]


def _robot_error_lines(robot_error) -> list[str]:
    """The robot error model's lines of :func:`summary`: which model, the uncertainty
    relative to the robot's own frame, and the expected error of a point at a new pose."""
    lines = []
    rot = ", ".join(f"{v:.4f}" for v in robot_error.std_rotation_deg_robot_frame)
    trans = ", ".join(f"{v:.4f}" for v in robot_error.std_translation_mm_robot_frame)
    rot2 = ", ".join(f"{2 * v:.4f}" for v in robot_error.std_rotation_deg_robot_frame)
    trans2 = ", ".join(f"{2 * v:.4f}" for v in robot_error.std_translation_mm_robot_frame)
    parameters = robot_error.kinematic_parameters
    if parameters is not None:
        n_seen = sum(p.identifiable for p in parameters)
        n_cal = sum(p.identified for p in parameters)
        how = (f"{n_cal} of its {len(parameters)} geometric parameters identified" if n_cal else
               f"{n_seen} of its {len(parameters)} geometric parameters seen by the data, all "
               f"marginalised (prior spread x {robot_error.kinematic_prior_scale:.2f})")
        lines.append(f"robot error: the arm's geometry (kinematic model), {how}")
        if robot_error.model_choice is not None:
            lines.append(f"  {robot_error.model_choice}")
        lines.append(f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the "
                     "std above adds the geometric errors no data from one sphere location can see)")
    elif robot_error.model_choice is not None:
        lines.append(f"robot error: {robot_error.model_choice}")
        lines.append(f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the "
                     "std above adds the geometric errors no data from one sphere location can see)")
    else:
        lines.append(
            f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the std above "
            f"adds the robot's assumed accuracy {robot_error.common_translation_mm:g} mm, "
            f"{robot_error.common_rotation_deg:g} deg per axis)"
        )
    lines.append(f"  expanded U (k = 2) relative to the robot's own frame: rotation {rot2} deg; translation "
                 f"{trans2} mm")
    dominant = POINT_ERROR_PARTS.get(robot_error.dominant, robot_error.dominant)
    if parameters is not None and any(p.identified for p in parameters):
        lines.append(
            f"a point measured at a new pose through the calibrated model ({CALIBRATED_URDF_NAME}): expected "
            f"error {robot_error.point_error_k2_mm:.3f} mm (k = 2), mostly from {dominant}"
        )
        pred = robot_error.station_prediction
        if pred is not None:
            lines.append(
                f"  measured: each station predicted from the others through the calibrated arm and the transform: "
                f"{pred.rms_mm:.4f} mm RMS ({pred.rms_mm / pred.expected_rms_mm:.2f} x what the noise explains; "
                f"worst {pred.worst_station} {pred.per_station_mm[pred.worst_station]:.4f} mm). This is what the "
                "verdict grades; the transform's std relative to the robot's frame above depends on how the arm's "
                "identified geometry and the transform share the error, and holds only with that calibrated model")
    else:
        lines.append(
            f"a point measured at a new pose: expected error {robot_error.point_error_k2_mm:.3f} mm (k = 2), mostly "
            f"from {dominant}; the robot's error differs between stations by {station_disagreement_text(robot_error)}"
        )
    return lines


def format_verdict(v: Verdict) -> str:
    """The verdict as the terminal prints it (the report shows the same): its level and
    headline, and the reasons for a red or amber one (what is red first)."""
    lines = [f"verdict: {v.level.upper()}: {v.headline}"]
    if v.level in ("red", "amber"):
        for level in ("red", "amber"):
            lines.extend(f"  {level}: {text}" for lvl, text in v.reasons if lvl == level)
    return "\n".join(lines)


def truth_check(solution: Solution, dataset: Dataset) -> str | None:
    """For simulated data: the error against the cell's true transform."""
    prov = dataset.provenance
    if "true_transform" not in prov:
        return None
    true = Pose.model_validate(prov["true_transform"])
    X = solution.result.transform
    rot = geo.rotation_angle_deg(true.rotation_matrix, X.rotation_matrix)
    dt = float(np.linalg.norm(true.translation - X.translation))
    text = f"simulated truth: error {rot:.4f} deg, {dt:.4f} mm"
    timing = solution.result.timing
    if timing is not None and "true_offset_s" in prov:
        e_off = timing.offset_ms - 1e3 * float(prov["true_offset_s"])
        text += (f"; clock offset error {e_off:+.4f} ms ({e_off / max(timing.offset_std_ms, 1e-12):+.1f} sd, true "
                 f"{1e3 * float(prov['true_offset_s']):.4f} ms)")
        if "true_drift" in prov:
            e_drift = timing.drift_ppm - 1e6 * float(prov["true_drift"])
            text += f", drift error {e_drift:+.3f} ppm (true {1e6 * float(prov['true_drift']):.3f} ppm)"
    return text
