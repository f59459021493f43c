"""The calibration's result, verdict and simulated truth as the terminal prints them."""

from __future__ import annotations

import math

import numpy as np

from spherecal.core import geometry as geo
from spherecal.core.models import CalibrationResult, Dataset, Pose
from spherecal.estimation import Solution
from spherecal.estimation.pipeline import POINT_ERROR_PARTS
from spherecal.io.exporters import CALIBRATED_URDF_NAME
from spherecal.report.assess import (Verdict, advice, implausible_disagreement, is_absurd,
                                     station_disagreement_text, verdict)
from spherecal.report.export import MM_DECIMALS, QUAT_DECIMALS, fixed


def summary(solution: Solution, graded: Verdict | None = None, *, verbose: bool = False) -> str:
    """The result as the terminal gives it, what it means first: the error to expect of a
    point measured at a new pose (:func:`point_error_lines`), the verdict (``graded``, else
    computed from the result) with the reason that decides it and the first thing to do,
    the transform in one line (:func:`transform_line`), a recording's clock relation and
    the observations left out. ``verbose`` (``-v``): every amber and red reason and piece
    of advice, then :func:`details` (the parameter tables and the estimator's terms, which
    the report and result.json hold too)."""
    r = solution.result
    graded = graded or verdict(r)
    # a data error named (a quaternion order, a radius, a mounting): its fix is the verdict's
    # reason; the figures and advice of the data as read are not the robot's, nor to act on
    named = any(level == "red" and text.startswith("likely cause") for level, text in graded.reasons)
    lines = [*point_error_lines(r, data_error=named), format_verdict(graded, everything=verbose)]
    if graded.level in ("red", "amber"):  # what to do, as the report gives it (its headline points here)
        todo = [a for a in advice(r) if a.level in ("red", "amber")]
        # with a data error named, no advice to add data: the data as read are not to be built on
        shown = todo if verbose else [a for a in todo if not (named and a.key in ADD_DATA_ADVICE)][:1]
        lines.extend(f"  advice: {a.title}: {a.text}" for a in shown)
        if len(todo) > len(shown):
            lines.append(f"  advice: {len(todo) - len(shown)} more: {MORE}")
    lines.append(transform_line(r))
    lines.extend(sensor_frame_lines(r))
    if r.timing is not None:
        lines.extend(timing_lines(r.timing))
        lines.extend(_flagged_profile_lines(r.flagged))
    else:
        for f in r.flagged[:MAX_FLAG_LINES]:
            lines.append(f"flagged observation {f.index} (station {f.station}): {f.reason}")
        if len(r.flagged) > MAX_FLAG_LINES:
            lines.append(f"... and {len(r.flagged) - MAX_FLAG_LINES} more flagged observations (result.json, 'flagged')")
    if verbose:
        lines += ["details (the report and result.json hold them too):", details(solution)]
    return "\n".join(lines)


#: Advice that asks for more data (stations, tilts, profiles): not shown in the terminal
#: when the verdict names a data error (its fix comes first).
ADD_DATA_ADVICE = frozenset({"rotation_uncertain", "rotation_axis_x", "rotation_axis_y", "rotation_axis_z",
                             "translation_uncertain"})
#: Where the reasons, advice and details the terminal leaves out are.
MORE = "with -v, and in the report"


def point_error_lines(result: CalibrationResult, data_error: bool = False) -> list[str]:
    """What the result means for a point measured by the calibrated system at a new pose
    like the calibration's (k = 2): with the robot as it is; for a kinematic calibration
    on the controller's nominal arm model first, then through spherecal's calibrated arm
    model, where alone its accuracy holds. Empty without a robot error model. With
    ``data_error`` (the verdict names one), or data that fit nothing, the figure is said
    to be the data's as they stand, not the robot's."""
    err = result.robot_error
    if err is None:
        return []
    if data_error or is_absurd(result) or implausible_disagreement(result):
        # the misfit of a data error (a radius, a mounting, a quaternion order) fills the
        # robot's error terms: the figure is not the robot's, and the verdict names the cause
        return [f"a point measured at a new pose: expected error {err.point_error_k2_mm:.3f} mm (k = 2) with the data "
                "as read: not the robot's error; see the likely cause below"]
    dominant = POINT_ERROR_PARTS.get(err.dominant, err.dominant)
    if not _arm_calibrated(err):
        return [f"a point measured at a new pose, with the robot as it is: expected error {err.point_error_k2_mm:.3f} mm "
                f"(k = 2), mostly from {dominant} (robot error model: {_MODEL_NAMES.get(err.model, err.model)})"]
    nominal = err.point_error_nominal_arm_k2_mm
    if nominal is None:
        first = (f"a point measured at a new pose, on the controller's nominal arm model ({ALONE}): more than through "
                 "the calibrated model (this result does not say how much)")
    else:
        arm_rms = math.sqrt(max((nominal / 2) ** 2 - (err.point_error_k2_mm / 2) ** 2, 0.0))
        why = ", mostly from the arm's geometric error" if arm_rms > err.point_error_k2_mm / 2 else ""
        first = (f"a point measured at a new pose, on the controller's nominal arm model ({ALONE}): expected error "
                 f"{nominal:.3f} mm (k = 2){why}")
    return [first, f"  through spherecal's calibrated arm model ({CALIBRATED_URDF_NAME}): expected error "
                   f"{err.point_error_k2_mm:.3f} mm (k = 2), mostly from {dominant}; this accuracy holds only where "
                   "poses go through that model"]


#: The robot error model a result was solved with, as the terminal names it (robot_error_model
#: "auto" chooses one; -v and the report say why).
_MODEL_NAMES = {"kinematic": "the arm's geometry, kinematic", "station": "per station",
                "kinematic+station": "the arm's geometry and per station, kinematic+station",
                "none": "pose noise only, none"}


#: How a kinematic calibration's transform is used on the controller's nominal model.
ALONE = "the exported transform without the calibrated model"


def _arm_calibrated(err) -> bool:
    return any(p.identified for p in err.kinematic_parameters or [])


def transform_line(result: CalibrationResult) -> str:
    """The transform in one line, its direction named: translation (mm) and quaternion
    (w, x, y, z), with the exports' decimals."""
    a, b = result.transform_name.split("_from_")
    X = result.transform
    return (f"{result.transform_name} (maps points in {b} to {a}): translation_mm = "
            f"[{', '.join(fixed(v, MM_DECIMALS) for v in X.translation_mm)}], quaternion_wxyz = "
            f"[{', '.join(fixed(v, QUAT_DECIMALS) for v in X.quaternion_wxyz)}]")


def sensor_frame_lines(result: CalibrationResult) -> list[str]:
    """When the calibrated sensor frame is not the frame the data's clouds came in
    (``result.data_frames``: a ROS 2 bag's clouds with the laser line along x): that it is
    not, the rotation between them, and the transform to the clouds' frame, which is what
    to publish for it; else nothing."""
    frames = result.data_frames
    if frames is None or frames.cloud_is_sensor:
        return []
    a, _ = result.transform_name.split("_from_")
    X = result.transform @ frames.sensor_from_cloud
    cloud = f"'{frames.cloud_frame_id}'" if frames.cloud_frame_id else "(not named)"
    return [f"the calibrated sensor frame is NOT the clouds' frame {cloud}: sensor_from_cloud = "
            f"{frames.sensor_from_cloud_text or 'not the identity'}; to the clouds' frame (what the ROS exports "
            f"publish for it): {a}_from_cloud: translation_mm = "
            f"[{', '.join(fixed(v, MM_DECIMALS) for v in X.translation_mm)}], quaternion_wxyz = "
            f"[{', '.join(fixed(v, QUAT_DECIMALS) for v in X.quaternion_wxyz)}]"]


def details(solution: Solution) -> str:
    """What ``-v`` adds after the summary: the transform in both directions with its
    1-sigma and U (k = 2), the residuals, and the robot error model's terms (which model
    and why, the uncertainty relative to the robot's own frame, the point error's parts,
    a kinematic calibration's identified parameters)."""
    r = solution.result
    X = r.transform
    inv = X.inverse()
    a, b = r.transform_name.split("_from_")
    lines = [
        f"{r.transform_name} (maps points in {b} to {a}):",
        f"  translation_mm  = [{', '.join(f'{v:.4f}' for v in X.translation_mm)}]",
        f"  quaternion_wxyz = [{', '.join(f'{v:.8f}' for v in X.quaternion_wxyz)}]",
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


def timing_lines(timing) -> list[str]:
    """A recording's clock relation (docs/conventions.md, "Time"), as the terminal and the
    report give it: the model, the offset (robot clock minus sensor clock) and the drift
    with their 1-sigma, whether the data identify it, and poses that were not measured."""
    drift = (f"drift {timing.drift_ppm:.3f} +/- {timing.drift_std_ppm:.3f} ppm" if timing.drift_estimated
             else f"drift held at {timing.drift_ppm:.3f} ppm (not estimated: a recording too short to show it, or both "
             "streams stamped by one clock)")
    return [
        f"clock relation: t_robot = t_sensor + offset + drift (t_sensor - {timing.t_sensor0_s:.6f} s):",
        f"  offset {timing.offset_ms:.4f} +/- {timing.offset_std_ms:.4f} ms (robot clock minus sensor clock"
        + (f", {timing.offset_ms / 1e3:.7f} s: the clocks count from different epochs" if abs(timing.offset_ms) > 1e6
           else "") + f"); {drift}",
        f"  {'identified' if timing.identifiable else 'NOT identified'}: {timing.identifiability}",
    ] + ([f"  robot poses NOT MEASURED: {timing.poses_assumed}"] if timing.poses_assumed else [])


def _robot_error_lines(robot_error) -> list[str]:
    """The robot error model's lines of :func:`details`: which model and why, the
    uncertainty relative to the robot's own frame, the expected error of a point at a new
    pose with its parts, and a kinematic calibration's prediction and identified parameters."""
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
        lines.append(f"robot error: the {robot_error.model} model (docs/estimation.md, \"Robot error\")")
        lines.append(
            f"  std relative to the robot's own frame: rotation {rot} deg; translation {trans} mm (the std above "
            f"adds the robot's assumed accuracy {robot_error.common_translation_mm:g} mm, "
            f"{robot_error.common_rotation_deg:g} deg per axis)"
        )
    lines.append(f"  expanded U (k = 2) relative to the robot's own frame: rotation {rot2} deg; translation "
                 f"{trans2} mm")
    parts = "; ".join(f"{POINT_ERROR_PARTS.get(k, k)} {v:.4f} mm" for k, v in robot_error.point_error_parts_rms_mm.items())
    through = f" through the calibrated model ({CALIBRATED_URDF_NAME})" if parameters and _arm_calibrated(robot_error) else ""
    lines.append(f"  a point measured at a new pose{through}: expected error {robot_error.point_error_k2_mm:.3f} mm "
                 f"(k = 2); its parts (RMS 3-D, k = 1): {parts}")
    if parameters is not None and _arm_calibrated(robot_error):
        pred = robot_error.station_prediction
        if pred is not None:
            lines.append(
                f"  measured: each station predicted from the others through the calibrated arm and the transform: "
                f"{pred.rms_mm:.4f} mm RMS ({pred.rms_mm / pred.expected_rms_mm:.2f} x what the noise explains; "
                f"worst {pred.worst_station} {pred.per_station_mm[pred.worst_station]:.4f} mm). This is what the "
                "verdict grades; the transform's std relative to the robot's frame above depends on how the arm's "
                "identified geometry and the transform share the error, and holds only with that calibrated model")
        lines.append("  identified geometric parameters (estimate +/- 1-sigma; the others held at their nominal values):")
        lines.extend(f"    {p.name} {p.value:+.4f} +/- {p.std:.4f} {p.unit}" for p in parameters if p.identified)
    else:
        lines.append(f"  the robot's error differs between stations by {station_disagreement_text(robot_error)}")
    return lines


def format_verdict(v: Verdict, everything: bool = True) -> str:
    """The verdict as the terminal prints it (the report shows the same): its level and
    headline, and the reasons for a red or amber one (what is red first). Not
    ``everything``: the reason that decides it alone (:func:`deciding_reason`), and how
    many more there are."""
    lines = [f"verdict: {v.level.upper()}: {v.headline}"]
    if v.level in ("red", "amber"):
        ordered = [(level, text) for level in ("red", "amber") for lvl, text in v.reasons if lvl == level]
        shown = ordered if everything else [deciding_reason(v)]
        lines.extend(f"  {level}: {text}" for level, text in shown)
        if len(ordered) > len(shown):
            n = len(ordered) - len(shown)
            lines.append(f"  ({n} more amber or red check{'s' if n > 1 else ''}: {MORE})")
    return "\n".join(lines)


def deciding_reason(v: Verdict) -> tuple[str, str]:
    """The one reason a red or amber verdict stands on: the likely cause named, when one
    was found; else the first reason of the verdict's level."""
    for lvl, text in v.reasons:
        if lvl == v.level and text.startswith("likely cause: "):  # (not the generic "likely causes: ...")
            return lvl, text
    return next((lvl, text) for lvl, text in v.reasons if lvl == v.level)


def truth_errors(solution: Solution, dataset: Dataset) -> dict | None:
    """For simulated data (the dataset's provenance holds the cell's ``true_transform``):
    the result's error against it, ``rotation_error_deg`` (the angle between the two
    rotations) and ``translation_error_mm``, the true transform (``true_translation_mm``,
    ``true_quaternion_wxyz``, w first) and, for a recording with a true clock,
    ``clock_offset_error_ms``, its ``_sd`` and ``true_clock_offset_ms`` (and
    ``drift_error_ppm``, ``true_drift_ppm``); None for other data."""
    prov = dataset.provenance
    if "true_transform" not in prov:
        return None
    true = Pose.model_validate(prov["true_transform"])
    X = solution.result.transform
    out = {"rotation_error_deg": geo.rotation_angle_deg(true.rotation_matrix, X.rotation_matrix),
           "translation_error_mm": float(np.linalg.norm(true.translation - X.translation)),
           "true_translation_mm": list(true.translation_mm), "true_quaternion_wxyz": list(true.quaternion_wxyz)}
    timing = solution.result.timing
    if timing is not None and "true_offset_s" in prov:
        true_ms = 1e3 * float(prov["true_offset_s"])
        e_off = timing.offset_ms - true_ms
        out.update(clock_offset_error_ms=e_off, clock_offset_error_sd=e_off / max(timing.offset_std_ms, 1e-12),
                   true_clock_offset_ms=true_ms)
        if "true_drift" in prov:
            true_ppm = 1e6 * float(prov["true_drift"])
            out.update(drift_error_ppm=timing.drift_ppm - true_ppm, true_drift_ppm=true_ppm)
    return out


def truth_check(solution: Solution, dataset: Dataset) -> str | None:
    """For simulated data: the error against the cell's true transform
    (:func:`truth_errors`), as the terminal prints it."""
    e = truth_errors(solution, dataset)
    if e is None:
        return None
    text = f"simulated truth: error {e['rotation_error_deg']:.4f} deg, {e['translation_error_mm']:.4f} mm"
    if "clock_offset_error_ms" in e:
        text += (f"; clock offset error {e['clock_offset_error_ms']:+.4f} ms ({e['clock_offset_error_sd']:+.1f} sd, "
                 f"true {e['true_clock_offset_ms']:.4f} ms)")
        if "drift_error_ppm" in e:
            text += f", drift error {e['drift_error_ppm']:+.3f} ppm (true {e['true_drift_ppm']:.3f} ppm)"
    return text
