"""Is this calibration good, and what to do when it is not.

:func:`verdict` grades a :class:`~spherecal.core.models.CalibrationResult` green, amber or
red; :func:`advice` turns its diagnostics into things to do. Both read only the result,
so they work on a result file as well as on a fresh solution. The limits are
:class:`Thresholds` (mm and degrees); the defaults suit an IRB 2400-sized robot with a
line sensor of about 0.01 mm noise.

Why the residual RMS is not compared with the sensor noise alone: the robot's pose
error moves a whole profile at once, so even a perfect calibration leaves residuals of
about ``sqrt(point_noise^2 + robot_repeatability^2)``. That is the *expected RMS*.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from spherecal.config import POINT_DISTANCE_MM  # noqa: F401 (the report's default, imported from here)
from spherecal.estimation.refine.reml import STATION_SCALE_CEILING_DEG, STATION_SCALE_CEILING_MM
from spherecal.estimation.robust import median
from spherecal.core.models import CalibrationResult, StationPrediction
from spherecal.report import advice_wording as wording

Level = Literal["green", "amber", "red"]
_RANK = {"green": 0, "amber": 1, "red": 2}
_AXES = ("x", "y", "z")


class Thresholds(BaseModel):
    """Limits of the verdict and of the advice. Lengths in mm, angles in degrees."""

    model_config = ConfigDict(defer_build=True, frozen=True, extra="forbid")

    robot_repeatability_mm: float = Field(
        0.05, gt=0, description="pose repeatability of the robot, mm (IRB 2400: about 0.03-0.06)"
    )
    residual_ratio_amber: float = Field(1.5, gt=0, description="residual RMS / expected RMS above this: amber")
    residual_ratio_red: float = Field(3.0, gt=0, description="residual RMS / expected RMS above this: red")
    residual_ratio_absurd: float = Field(
        20.0, gt=0, description="residual RMS / expected RMS above this: the data do not fit the model at all (red, "
        "with the likely causes named)"
    )
    rotation_std_amber_deg: float = Field(0.05, gt=0, description="largest rotation 1-sigma above this: amber, deg")
    rotation_std_red_deg: float = Field(0.15, gt=0, description="largest rotation 1-sigma above this: red, deg")
    translation_std_amber_mm: float = Field(0.1, gt=0, description="largest translation 1-sigma above this: amber, mm")
    translation_std_red_mm: float = Field(0.3, gt=0, description="largest translation 1-sigma above this: red, mm")
    flagged_fraction_amber: float = Field(
        0.1, ge=0, le=1, description="share of observations flagged above this: amber"
    )
    station_inconsistency_factor: float = Field(
        3.0, gt=1, description="a station whose consistency RMS exceeds this many times the median of the stations"
    )
    station_inconsistency_floor_mm: float = Field(
        0.05, ge=0, description="... and this many mm is called inconsistent"
    )
    axis_imbalance_factor: float = Field(
        2.5, gt=1, description="a rotation axis whose 1-sigma exceeds this many times the best axis is weak"
    )
    stray_fraction_info: float = Field(0.002, ge=0, le=1, description="share of points rejected as strays worth a note")
    nominal_rotation_amber_deg: float = Field(
        10.0, gt=0, description="the result this far from the nominal transform given (a rough one): amber, deg")
    nominal_rotation_red_deg: float = Field(45.0, gt=0, description="... and this far: red, deg")
    nominal_translation_amber_mm: float = Field(50.0, gt=0, description="the same for the translation: amber, mm")
    nominal_translation_red_mm: float = Field(200.0, gt=0, description="... and red, mm")
    pose_noise_factor: float = Field(
        2.0, gt=1, description="estimated pose noise above this many times the repeatability is worth advice"
    )
    start_disagreement_deg: float = Field(0.5, gt=0, description="two-step vs refined rotation worth a note, deg")
    start_disagreement_mm: float = Field(1.0, gt=0, description="two-step vs refined translation worth a note, mm")
    robot_error_share_amber: float = Field(
        0.5, gt=0, le=1, description="the robot's systematic error above this share of the point error's variance: "
        "amber, 'robot error dominates'"
    )
    robot_error_floor_mm: float = Field(
        0.03, ge=0, description="... when it is also above this RMS, mm (below it the robot is as good as clean)"
    )
    prediction_amber_mm: float = Field(
        0.1, gt=0, description="kinematic calibration: the sphere at each station, predicted through the calibrated "
        "arm and transform by the fit of the other stations, misses where the station sees it by more than this "
        "(RMS 3-D over the stations): amber, mm")
    prediction_red_mm: float = Field(0.3, gt=0, description="... and by more than this: red, mm")
    prediction_ratio_amber: float = Field(
        1.5, gt=0, description="... or by more than this many times what the noise and the fit's uncertainty "
        "explain: amber (the arm's error is not what its geometric model holds)")
    prediction_ratio_red: float = Field(3.0, gt=0, description="... and this many times: red")


@dataclass
class Verdict:
    """Grade of a result: ``level`` (green/amber/red), a one-line ``headline`` and the
    ``reasons`` behind the grade (one per check, each with its own level)."""

    level: Level
    headline: str
    reasons: list[tuple[Level, str]] = field(default_factory=list)


@dataclass
class Advice:
    """One thing to look at: ``key`` names the trigger (stable, for tests and tools),
    ``level`` how much it matters, ``title`` and ``text`` what to do."""

    key: str
    level: Level
    title: str
    text: str


def _worse(a: Level, b: Level) -> Level:
    return a if _RANK[a] >= _RANK[b] else b


def expected_rms_mm(result: CalibrationResult, thresholds: Thresholds | None = None) -> float:
    """``sqrt(point_noise^2 + robot_repeatability^2)`` (see the module docstring)."""
    th = thresholds or Thresholds()
    point = float((result.diagnostics.noise or {}).get("point_noise_mm", 0.0) or 0.0)
    return math.hypot(point, th.robot_repeatability_mm)


def _n_observations(result: CalibrationResult) -> int:
    return result.residuals.n_profiles_used + result.residuals.n_centres_used + len(result.flagged)


def verdict(result: CalibrationResult, thresholds: Thresholds | None = None) -> Verdict:
    """Grade ``result``: the worst of the residual check (RMS against the expected RMS),
    the uncertainty checks (largest rotation and translation 1-sigma; for a kinematic
    calibration the prediction of a point at a new pose instead, :func:`_uncertainty_reasons`),
    the share of flagged observations and the convergence of the refinement."""
    th = thresholds or Thresholds()
    reasons: list[tuple[Level, str]] = []

    exp = expected_rms_mm(result, th)
    rms = result.residuals.rms_mm
    ratio = rms / exp
    lvl: Level = "red" if ratio > th.residual_ratio_red else "amber" if ratio > th.residual_ratio_amber else "green"
    reasons.append((lvl, f"residual RMS {rms:.4f} mm is {ratio:.2f} x the expected {exp:.4f} mm "
                         f"(point noise and robot repeatability {th.robot_repeatability_mm} mm)"))
    absurd = is_absurd(result, th)
    ref = centre_noise_reference_mm(result, th)
    if absurd and ref is not None and ref < exp:
        within = float(result.diagnostics.noise["centre_noise_within_stations_mm"])
        reasons.append(("red", f"the centre observations lie {rms:.4f} mm RMS from the fit, {absurd_ratio(result, th):.3g} x "
                               f"the {ref:.4f} mm they should (their noise within stations, where the robot only "
                               f"translated, {within:.4f} mm, and robot repeatability {th.robot_repeatability_mm} mm): "
                               "the noise estimated from the fit took in a misfit"))
    if absurd:
        reasons.append(("red", ABSURD_CAUSES))

    err = result.robot_error
    reasons += _uncertainty_reasons(result, th)

    robot_dominates = robot_error_dominates(result, th)
    if err is not None:
        parts = err.point_error_parts_rms_mm
        robot = parts.get("robot_station_to_station_mm", 0.0)
        share = robot**2 / max(sum(v**2 for v in parts.values()), 1e-300)
        lvl = "amber" if robot_dominates else "green"
        reasons.append((lvl, f"a point measured at a new pose: expected error {err.point_error_k2_mm:.3f} mm (k = 2); "
                             f"the robot's systematic error is {share:.0%} of it ({robot:.3f} mm RMS; "
                             f"{robot_error_evidence(err)})"))

    n_flag = len(result.flagged)
    if n_flag:
        share = n_flag / max(_n_observations(result), 1)
        lvl = "amber" if share > th.flagged_fraction_amber else "green"
        reasons.append((lvl, f"{n_flag} of {_n_observations(result)} observations flagged and left out ({share:.0%})"))

    nominal = result.diagnostics.nominal_transform or {}
    if nominal:
        angle, dist = float(nominal.get("rotation_deg", 0.0)), float(nominal.get("translation_mm", 0.0))
        if angle > th.nominal_rotation_amber_deg or dist > th.nominal_translation_amber_mm:
            lvl = ("red" if angle > th.nominal_rotation_red_deg or dist > th.nominal_translation_red_mm else "amber")
            text = (f"the result is {angle:.1f} deg and {dist:.1f} mm from the nominal transform given (amber above "
                    f"{th.nominal_rotation_amber_deg:g} deg or {th.nominal_translation_amber_mm:g} mm)")
            if nominal.get("likely_cause"):  # (estimation.pipeline.with_nominal_comparison names it)
                text += f": {nominal['likely_cause']}"
            reasons.append((lvl, text))

    timing = result.timing
    if timing is not None and not is_absurd(result, th):  # (a fit of nothing says nothing of the time)
        # a clock offset the sweeps cannot tell from the sphere's position: the transform's
        # uncertainty carries it, the advice says what to record
        reasons.append(("green" if timing.identifiable else "amber", f"clock relation: {timing.identifiability}"))
    if timing is not None and timing.poses_assumed:
        # (said, not graded: the data cannot show the arm's path error; the user must weigh it)
        reasons.append(("green", f"robot poses not measured: {timing.poses_assumed}"))

    twin = result.diagnostics.mirror_twin or {}
    if twin.get("excluded") is False:  # a result the data cannot tell from its twin: the user must choose
        reasons.append(("amber", str(twin.get("text", "a mirror twin of the result cannot be excluded"))))

    joints = result.diagnostics.joints_vs_poses or {}
    if joints.get("used") is False:  # the joints did not describe the poses: the robot's error model is the poorer one
        reasons.append(("amber", str(joints.get("reason", "the joint readings were not used"))))

    refinement = result.diagnostics.refinement or {}
    if refinement.get("converged") is False:
        reasons.append(("red", f"the refinement did not converge in {refinement.get('iterations')} iterations"))

    level: Level = "green"
    for lv, _ in reasons:
        level = _worse(level, lv)
    headline = {
        "green": "Good: a clean cell; residuals as expected and the transform well determined.",
        "amber": "Usable with care: see the checks and the advice below.",
        "red": "Do not use yet: see the checks and the advice below.",
    }[level]
    if level == "green" and station_prediction(result) is not None:
        headline = ("Good: residuals as expected, and a point at a new pose placed through the calibrated arm as "
                    "well as the noise allows.")
    if absurd:
        headline = ("Wrong: the data do not fit the model at all (residuals "
                    f"{absurd_ratio(result, th):.3g} x the expected); a setting or the data are wrong, not the noise.")
    if robot_dominates and level != "red":
        headline = ("Robot error dominates: the arm's geometric error, not the calibration, limits this result: a "
                    f"point measured at a new pose is expected {err.point_error_k2_mm:.3f} mm off (k = 2); calibrating "
                    "the arm is the remedy (see the advice)."
                    if arm_error_marginalised(err) else
                    "Robot error dominates: the stations disagree by more than the noise explains, so the robot's "
                    "own geometric error limits this result (see the advice).")
    return Verdict(level, headline, reasons)


def with_validation(ver: Verdict, figures: Mapping[str, Mapping], cause: str | None = None) -> Verdict:
    """The verdict of a calibration together with its validation: ``figures`` is the
    validation's table (``ValidationOutcome.table()``: per figure ``max error (mm)``,
    ``worst position``, ``MPE (mm)``, ``passed``, and ``U (mm, k = 2)`` where known). A
    figure beyond its MPE makes the verdict red (the calibration does not measure as
    accurately as required), whatever the calibration's own grade; passing figures add
    their reasons and keep the grade. A figure beyond its MPE by less than its
    uncertainty from the noise passed (it is not shown to exceed the MPE) and the
    headline says so. ``cause``: what the failure's headline says after the failing
    figures instead of "Do not use this calibration" (a cause named,
    :mod:`spherecal.report.validation_advice`)."""
    reasons = list(ver.reasons)
    failed, within_u = [], []
    for name, row in figures.items():
        value, mpe, passed = row.get("max error (mm)"), row.get("MPE (mm)"), row.get("passed")
        where = f" at {row['worst position']}" if row.get("worst position") else ""
        if passed is None:
            reasons.append(("green", f"validation: {name} {value:.4f} mm{where} (no MPE: not judged)"))
        elif passed and row.get("U (mm, k = 2)") is not None and abs(value) > mpe:
            # beyond the MPE by less than its own uncertainty from the noise: not shown to exceed it
            text = (f"{name} {value:.4f} mm{where} lies beyond its MPE {mpe:g} mm by less than its uncertainty from "
                    f"the noise (U {row['U (mm, k = 2)']:.4f} mm, k = 2): not shown to exceed it")
            reasons.append(("green", f"validation: {text}"))
            within_u.append(text)
        elif passed:
            reasons.append(("green", f"validation: {name} {value:.4f} mm{where}, within its MPE {mpe:g} mm"))
        else:
            reasons.append(("red", f"validation: {name} {value:.4f} mm{where} exceeds its MPE {mpe:g} mm"))
            failed.append(f"{name} {value:.4f} mm exceeds its MPE {mpe:g} mm")
    if failed:
        then = cause or ("Do not use this calibration: it does not measure as accurately as required (see the "
                         "validation tables).")
        return Verdict("red", f"Validation failed: {'; '.join(failed)}. {then}", reasons)
    if not figures:
        return Verdict(ver.level, ver.headline, reasons)
    if within_u:
        return Verdict(ver.level, f"{ver.headline} Validation passed: every other judged figure within its MPE; "
                       f"{'; '.join(within_u)}.", reasons)
    return Verdict(ver.level, f"{ver.headline} Validation passed: every judged figure within its MPE.", reasons)


#: What makes a solution absurd, most likely first (named in the verdict of one).
ABSURD_CAUSES = (
    "likely causes: the dataset's mounting is wrong (eye-in-hand data labelled eye-to-hand or the reverse); "
    "poses in metres or radians instead of mm and degrees; poses paired with other shots' profiles; "
    "a sphere radius far from the real one"
)


def centre_noise_reference_mm(result: CalibrationResult, thresholds: Thresholds | None = None) -> float | None:
    """For a result of centre observations only whose noise was estimated (from the joint
    fit's residuals, so the residual check compares the residuals with themselves): the
    noise they should show, independent of the fit, ``sqrt(within^2 + robot_repeatability^2)``
    with ``within`` the noise the centres show within their stations
    (``diagnostics.noise.centre_noise_within_stations_mm``, from the pure-translation
    rule). None otherwise (the point noise of the profiles, or the given covariances,
    anchor the expected RMS)."""
    th = thresholds or Thresholds()
    noise = result.diagnostics.noise or {}
    within = noise.get("centre_noise_within_stations_mm")
    if result.residuals.n_profiles_used or noise.get("centre_noise_mm") is None or within is None:
        return None
    return math.hypot(float(within), th.robot_repeatability_mm)


def absurd_ratio(result: CalibrationResult, thresholds: Thresholds | None = None) -> float:
    """The residual RMS over the noise that should explain it: the expected RMS
    (:func:`expected_rms_mm`) or, for centres with estimated noise, the noise they show
    within their stations (:func:`centre_noise_reference_mm`), whichever is smaller
    (the larger ratio)."""
    th = thresholds or Thresholds()
    rms = result.residuals.rms_mm
    ref = centre_noise_reference_mm(result, th)
    exp = expected_rms_mm(result, th)
    return rms / (exp if ref is None else min(exp, ref))


def is_absurd(result: CalibrationResult, thresholds: Thresholds | None = None) -> bool:
    """True when the residual RMS is so many times the noise that should explain it
    (:func:`absurd_ratio`, above ``residual_ratio_absurd``) that no noise explains it, or
    is not a finite number: a wrong setting or wrong data."""
    th = thresholds or Thresholds()
    rms = result.residuals.rms_mm
    return not math.isfinite(rms) or absurd_ratio(result, th) > th.residual_ratio_absurd


def _uncertainty_reasons(result: CalibrationResult, th: Thresholds) -> list[tuple[Level, str]]:
    """The checks of what the calibration determines. Relative to the robot's own frame
    (the error the robot shares over every station is its accuracy, reported apart, not
    graded here): the largest rotation and translation 1-sigma; or, for a kinematic
    calibration (the arm's geometry identified), the prediction of a point at a new pose
    through the calibrated arm and the transform together (:func:`station_prediction`),
    with the transform's own 1-sigmas given but not graded: they depend on how the
    transform and the arm's parameters share what the data determine together."""
    err = result.robot_error
    std_rot, std_tr = calibration_std(result)
    rel = " relative to the robot's frame" if err else ""
    rot, tr = max(std_rot), max(std_tr)
    pred = station_prediction(result)
    if pred is not None:
        return [*_prediction_reasons(pred, th), (
            "green", f"the transform alone{rel}: largest rotation uncertainty {rot:.4f} deg, translation {tr:.4f} mm "
                     "(1-sigma): not graded, gauge-dependent: with the arm's geometry identified, the transform "
                     "trades with the arm's parameters and the data determine the two together (a point placed "
                     "through both is known far better than either alone); use the transform with the calibrated "
                     "arm model")]
    lvl: Level = "red" if rot > th.rotation_std_red_deg else "amber" if rot > th.rotation_std_amber_deg else "green"
    out: list[tuple[Level, str]] = [(lvl, f"largest rotation uncertainty{rel} {rot:.4f} deg (1-sigma; amber above "
                                          f"{th.rotation_std_amber_deg}, red above {th.rotation_std_red_deg})")]
    lvl = "red" if tr > th.translation_std_red_mm else "amber" if tr > th.translation_std_amber_mm else "green"
    out.append((lvl, f"largest translation uncertainty{rel} {tr:.4f} mm (1-sigma; amber above "
                     f"{th.translation_std_amber_mm}, red above {th.translation_std_red_mm})"))
    return out


def station_prediction(result: CalibrationResult) -> StationPrediction | None:
    """The measured error of a point at a new pose of a kinematic calibration (each
    station predicted by the fit of the others), when the arm's geometry was identified
    and the result carries it; else None."""
    err = result.robot_error
    if err is None or err.station_prediction is None or not err.kinematic_parameters:
        return None
    if not any(p.identified for p in err.kinematic_parameters):
        return None
    return err.station_prediction


def _prediction_reasons(pred: StationPrediction, th: Thresholds) -> list[tuple[Level, str]]:
    """The verdict's lines on a kinematic calibration's prediction at new poses: its size,
    and whether the noise and the fit's uncertainty explain it."""
    rms, exp = pred.rms_mm, pred.expected_rms_mm
    if pred.unpredictable_stations:
        return [("red", "a point at a new pose, through the calibrated arm: station(s) "
                        f"{', '.join(pred.unpredictable_stations)} cannot be predicted from the other stations "
                        "(without one of them the data do not determine the arm's geometry): the plan does not "
                        "identify it; add stations that spread the joints")]
    worst = pred.per_station_mm[pred.worst_station]
    lvl: Level = "red" if rms > th.prediction_red_mm else "amber" if rms > th.prediction_amber_mm else "green"
    out: list[tuple[Level, str]] = [(lvl, (
        f"a point at a new pose, through the calibrated arm and the transform: the sphere at each station, predicted "
        f"from the other stations, lies {rms:.4f} mm RMS from where that station sees it (worst {worst:.4f} mm at "
        f"station {pred.worst_station}; amber above {th.prediction_amber_mm:g}, red above {th.prediction_red_mm:g} mm)"
    ))]
    ratio = rms / exp if exp > 0 else math.inf
    lvl = "red" if ratio > th.prediction_ratio_red else "amber" if ratio > th.prediction_ratio_amber else "green"
    out.append((lvl, f"the stations' prediction errors are {ratio:.2f} x the {exp:.4f} mm RMS the noise and the fit's "
                     f"uncertainty explain (amber above {th.prediction_ratio_amber:g} x, red above "
                     f"{th.prediction_ratio_red:g} x)"
                     + ("" if lvl == "green" else ": the arm's error is not all geometric (the calibrated model does "
                        "not hold it), or some stations' data are wrong")))
    return out


def calibration_std(result: CalibrationResult) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """1-sigma of the rotation (deg) and translation (mm) that the calibration itself
    determines: relative to the robot's own frame when the result has a robot error
    model (the error the robot shares over every station is its accuracy, not the
    calibration's), else the reported ones."""
    err = result.robot_error
    if err is None:
        return tuple(result.std_rotation_deg), tuple(result.std_translation_mm)
    return tuple(err.std_rotation_deg_robot_frame), tuple(err.std_translation_mm_robot_frame)


def robot_error_dominates(result: CalibrationResult, thresholds: Thresholds | None = None) -> bool:
    """True when the robot's systematic (station-to-station) error is the larger share of
    the expected point error and above the floor: the cell is not clean."""
    th = thresholds or Thresholds()
    err = result.robot_error
    if err is None:
        return False
    parts = err.point_error_parts_rms_mm
    robot = parts.get("robot_station_to_station_mm", 0.0)
    share = robot**2 / max(sum(v**2 for v in parts.values()), 1e-300)
    return share > th.robot_error_share_amber and robot > th.robot_error_floor_mm


def inconsistent_stations(result: CalibrationResult, thresholds: Thresholds | None = None) -> dict[str, float]:
    """Stations whose consistency RMS (mm) stands out: above ``factor`` x the median over
    stations and above the floor. ``{label: rms_mm}``."""
    th = thresholds or Thresholds()
    cons = result.diagnostics.station_consistency or {}
    if len(cons) < 2:
        return {}
    rms = {label: float(v["rms_mm"]) for label, v in cons.items()}
    typical = float(median(list(rms.values())))
    return {
        label: v for label, v in rms.items()
        if v > th.station_inconsistency_factor * typical and v > th.station_inconsistency_floor_mm
    }


def advice(result: CalibrationResult, thresholds: Thresholds | None = None) -> list[Advice]:
    """What to do, from the diagnostics of ``result``; worst first. An empty list means
    nothing calls for action."""
    th = thresholds or Thresholds()
    bad_stations = inconsistent_stations(result, th)
    out = [*_robot_error_advice(result, th), *_residual_advice(result, th, bad_stations),
           *_station_advice(result, bad_stations), *_uncertainty_advice(result, th), *_flagged_advice(result, th),
           *_stray_point_advice(result, th), *_estimator_advice(result, th)]
    out.sort(key=lambda adv: -_RANK[adv.level])
    return out


#: A station-to-station disagreement above either of these is more than any arm's geometry
#: makes (an uncalibrated industrial arm: tenths of a millimetre to a few, hundredths of a
#: degree to tenths): a data error, not the robot (deg, mm).
IMPLAUSIBLE_STATION_DEG = 0.5
IMPLAUSIBLE_STATION_MM = 5.0
#: What makes stations disagree by more than an arm can, most common first; the radius
#: only where profiles were fitted with it (sphere centres do not depend on it).
_DATA_ERROR_CHECKS = (
    "the quaternions' order (spherecal reads base_from_flange w first, as ABB writes it; SciPy and ROS write it "
    "last)", "the mounting (eye_in_hand or eye_to_hand)", "the poses' units (mm and degrees, not metres or radians)",
    "every pose read in one frame (tool0, wobj0)", "each observation paired with its own pose",
)
_RADIUS_CHECK = "the sphere radius (in mm, the radius and not the diameter)"


def data_error_checks(result: CalibrationResult) -> str:
    """What to check when the stations disagree by more than an arm can, as a phrase."""
    checks = list(_DATA_ERROR_CHECKS)
    if result.residuals.n_profiles_used:
        checks.insert(2, _RADIUS_CHECK)
    return ", ".join(checks[:-1]) + " and " + checks[-1]


def _at_ceiling(value: float, ceiling: float) -> bool:
    return value >= ceiling * (1.0 - 1e-6)


def station_disagreement_text(err) -> str:
    """How much the stations disagree, ``"0.048 mm and 0.0244 deg per axis"``; a scale at
    the ceiling the fit puts on it is a bound, not a measurement: ``"at least 5 deg"``."""
    mm, deg = err.station_translation_mm, err.station_rotation_deg
    mm_text = f"at least {mm:g} mm" if _at_ceiling(mm, STATION_SCALE_CEILING_MM) else f"{mm:.3f} mm"
    deg_text = f"at least {deg:g} deg" if _at_ceiling(deg, STATION_SCALE_CEILING_DEG) else f"{deg:.4f} deg"
    return f"{mm_text} and {deg_text} per axis"


def arm_error_marginalised(err) -> bool:
    """True when the robot's error was modelled as the arm's geometry from its joints and
    none of its parameters identified (integrated out, as an uncalibrated arm's)."""
    params = err.kinematic_parameters if err is not None else None
    return bool(params) and not any(p.identified for p in params)


def robot_error_evidence(err) -> str:
    """Where the robot's systematic error shows, as a phrase. The station model: how much
    the stations disagree. The arm's geometry integrated out: how little of that error
    the stations' differences show; most of it every station shares, which one sphere
    location cannot measure."""
    if not arm_error_marginalised(err):
        return f"stations disagree by {station_disagreement_text(err)}"
    return (f"the arm's geometry: the stations' differences show {station_disagreement_text(err)} of it, the rest "
            "every station shares and one sphere location cannot measure")


def start_disagreement_explained(result: CalibrationResult, thresholds: Thresholds | None = None) -> bool:
    """True when the fit's start (the two-step's, or the start from any orientations)
    differs from the refined result by no more than the robot's error that dominates
    explains: the start leaves that error out, the
    refinement allows for it, so they part by about its size (a translation within the
    expected error of a point at a new pose, no rotation beyond the note's limit)."""
    th = thresholds or Thresholds()
    tsr = start_vs_refined(result.diagnostics)
    err = result.robot_error
    return (err is not None and robot_error_dominates(result, th) and not is_absurd(result, th)
            and tsr.get("rotation_deg", 0.0) <= th.start_disagreement_deg
            and tsr.get("translation_mm", 0.0) <= err.point_error_k2_mm)


def implausible_disagreement(result: CalibrationResult) -> bool:
    """True when the stations disagree, as the data show it, by more than any arm's
    geometry makes (:data:`IMPLAUSIBLE_STATION_DEG`, :data:`IMPLAUSIBLE_STATION_MM`):
    the per-station effects took in a data error. Scales given in the options
    (``station_*_error``, not estimated) are the user's, not evidence."""
    err = result.robot_error
    if err is None or (err.model == "station" and not err.estimated):
        return False
    return err.station_rotation_deg > IMPLAUSIBLE_STATION_DEG or err.station_translation_mm > IMPLAUSIBLE_STATION_MM


def _robot_error_advice(result: CalibrationResult, th: Thresholds) -> list[Advice]:
    """The robot's own geometric error, when it limits the calibration; stations that
    disagree by more than any arm can, as the data error they are. None for an absurd
    result without such a disagreement: its misfit is not the robot's (the residual
    advice says what to check)."""
    err = result.robot_error
    if err is None:
        return []
    if implausible_disagreement(result):
        return [Advice(
            "stations_disagree_implausibly", "red",
            "The stations disagree by more than any arm's geometry: a data error",
            f"The stations disagree by {station_disagreement_text(err)}. An arm's geometry makes its stations "
            "disagree by tenths of a millimetre to a few, hundredths of a degree to tenths; more than "
            f"{IMPLAUSIBLE_STATION_MM:g} mm or {IMPLAUSIBLE_STATION_DEG:g} deg is a data error, not the robot, and "
            f"calibrating the robot will not remove it. Check {data_error_checks(result)}.",
        )]
    if is_absurd(result, th) or not robot_error_dominates(result, th):
        return []
    params = err.kinematic_parameters or []
    if any(p.identified for p in params):
        todo = ("measure through the calibrated model (robot_calibrated.urdf) and add stations spread over the "
                "joints the cell works in (more of the arm's parameters identified)")
    elif params and result.timing is not None:  # a recording: a kinematic calibration is taken stop-and-go
        todo = wording.recording_arm_calibration(sum(p.identifiable for p in params), len(params))
    elif params:  # the arm's error modelled from its joints, not identified: spherecal can calibrate it
        seen = sum(p.identifiable for p in params)
        todo = ("calibrate the arm's geometry with spherecal and measure through the calibrated model ([calibration] "
                "identify_kinematics = true: the planner chooses stations spread over the arm's joints and checks "
                f"that they identify it; these data see {seen} of its {len(params)} geometric parameters)")
    else:
        todo = "calibrate the robot's kinematics (or use its absolute-accuracy option)"
    todo += "; keep the stations' orientations close to those the cell will work in"
    if err.model == "station" and (err.common_translation_mm > 0 or err.common_rotation_deg > 0):
        todo += (". Give the robot's known accuracy (calibration.robot_accuracy_mm / robot_accuracy_deg) if it is "
                 f"better than the assumed {err.common_translation_mm:g} mm / {err.common_rotation_deg:g} deg: it "
                 "sets the uncertainty against the true frames")
    if arm_error_marginalised(err):
        robot = err.point_error_parts_rms_mm.get("robot_station_to_station_mm", 0.0)
        seen = ("The robot's flange is not where its controller says, by an amount that changes with the joints: the "
                f"arm's geometric error moves a measured point by about {robot:.3f} mm RMS at these poses. The "
                f"stations' differences show {station_disagreement_text(err)} of it; the rest every station shares, "
                "and one sphere location cannot measure it.")
    else:
        seen = (f"The stations disagree by about {station_disagreement_text(err)}, more than the noise explains: the "
                "robot's flange is not where its controller says, by an amount that changes with the joints.")
    tsr = start_vs_refined(result.diagnostics)
    which = "two-step" if result.diagnostics.two_step_vs_refined else "linear"
    start = (f" The {which} start, which leaves this error out, differs from the result by "
             f"{tsr.get('rotation_deg', 0.0):.3f} deg and {tsr.get('translation_mm', 0.0):.3f} mm: that is this error "
             "too, not bad data." if start_disagreement_explained(result, th) and _start_disagrees(tsr, th) else "")
    return [Advice(
        "robot_error_dominates", "amber", "The robot's own geometric error limits this calibration",
        f"{seen} The result allows for it (its uncertainty includes it) and is as good as this robot allows; expect "
        f"{err.point_error_k2_mm:.3f} mm (k = 2) for a point measured at a new pose like these.{start} To do better: "
        f"{todo}.",
    )]


def _residual_advice(result: CalibrationResult, th: Thresholds, bad_stations: dict[str, float]) -> list[Advice]:
    """Residuals larger than expected at every station alike, and robot poses that scatter."""
    out: list[Advice] = []
    noise = result.diagnostics.noise or {}
    exp = expected_rms_mm(result, th)
    ratio = result.residuals.rms_mm / exp
    pose_t = noise.get("pose_translation_noise_mm")
    groups = (result.diagnostics.station_orientation or {}).get("largest_orientation_group")
    err = result.robot_error
    if (err is not None and err.model == "none" and groups == 1 and not bad_stations
            and (ratio > th.residual_ratio_amber or (pose_t or 0.0) > th.robot_repeatability_mm)):
        # every row at its own orientation, no joints: the arm's error, which changes with the
        # pose, has no model to go into but the pose noise and the residuals
        return [Advice(
            "robot_error_as_pose_noise", "amber", "The robot's own error shows as pose noise",
            f"Every row is at its own orientation and the poses carry no joints, so the robot's geometric error, "
            "which changes with the pose (0.3-1.2 mm on an uncalibrated arm), cannot be told from pose noise: it "
            f"shows as residuals ({result.residuals.rms_mm:.4f} mm RMS, {ratio:.1f} x the expected) and a pose "
            f"noise of about {pose_t or 0.0:.3f} mm per axis. Record the joints with the poses and give the robot "
            "type (solve --robot TYPE) for the kinematic model, or take several shots at each orientation (stations). "
            f"A wrong sphere radius looks alike: check it (now {result.sphere_radius_mm:.4f} mm).",
        )]
    if ratio > th.residual_ratio_amber and not bad_stations:
        lvl: Level = "red" if ratio > th.residual_ratio_red else "amber"
        out.append(Advice(
            "residual_rms_high", lvl, "Residuals larger than expected",
            f"The residual RMS is {result.residuals.rms_mm:.4f} mm, {ratio:.1f} x the expected {exp:.4f} mm, "
            "and every station is affected alike. Check the sphere radius in the dataset against the "
            f"certificate (now {result.sphere_radius_mm:.4f} mm; in mm, not in metres nor a diameter), "
            "or let the calibration estimate the radius ([calibration] fit_radius = true; solve --fit-radius) to see "
            "what radius the data prefer; check the sensor exposure "
            "(a saturated or too dark line biases the points) and that the sphere is clean and matte.",
        ))
    if pose_t is not None and pose_t > th.pose_noise_factor * th.robot_repeatability_mm and result.timing is not None:
        # a recording: its noise per profile widened for the residuals' correlation in time; no robot to stop
        correlation = (result.diagnostics.refinement or {}).get("time_correlation") or {}
        out.append(Advice(*wording.recording_pose_noise(
            pose_t, float(correlation.get("integrated_autocorrelation_shots", 1.0)), th.robot_repeatability_mm,
            th.pose_noise_factor)))
    elif pose_t is not None and pose_t > th.pose_noise_factor * th.robot_repeatability_mm:
        out.append(Advice(
            "pose_noise_high", "amber", "Robot poses scatter more than the robot repeats",
            f"The data show a robot pose noise of about {pose_t:.3f} mm per axis, more than "
            f"{th.pose_noise_factor:g} x the repeatability {th.robot_repeatability_mm} mm. Read poses only "
            "after the robot has stopped (fine point, WaitRob \\InPos), ask the controller for at least 6 "
            "decimals of the quaternion (3 decimals is about 0.1 deg), read them with tool0 and wobj0, and let "
            "the robot warm up. A wrong sphere radius looks the same: check it too.",
        ))
    return out


def _station_advice(result: CalibrationResult, bad_stations: dict[str, float]) -> list[Advice]:
    """Stations whose sphere centre does not move as the robot says it moved."""
    out: list[Advice] = []
    cons = result.diagnostics.station_consistency or {}
    if bad_stations:
        typical = float(median([float(v["rms_mm"]) for v in cons.values()]))
        listing = ", ".join(f"{k} ({v:.3f} mm)" for k, v in sorted(bad_stations.items()))
        out.append(Advice(
            "station_inconsistent", "amber", "Station(s) inconsistent with the robot's moves",
            f"Within station(s) {listing} the sphere centre seen by the sensor does not move as the robot "
            f"says it moved (typical station: {typical:.3f} mm). " + (wording.RECORDING_STATION_CAUSE if result.timing
            is not None else "The likely cause is a pose read before the robot settled (use a fine point and WaitRob "
            "\\InPos before reading), or a reading paired with the wrong profile. Re-acquire that station, or drop it "
            "if the others suffice."),
        ))
    return out


def _uncertainty_advice(result: CalibrationResult, th: Thresholds) -> list[Advice]:
    """A rotation axis, every rotation axis or the translation poorly determined."""
    if station_prediction(result) is not None:
        return _prediction_advice(station_prediction(result), th)
    out: list[Advice] = []
    a = result.transform_name.split("_from_")[0]
    # uncertainty per rotation axis: one weak axis calls for a tilt about it; all axes
    # alike call for more data (and smaller residuals) overall
    std_r = list(calibration_std(result)[0])
    best = min(std_r)
    weak = [k for k, s in enumerate(std_r)
            if s > th.axis_imbalance_factor * best and s > 0.2 * th.rotation_std_amber_deg]
    for k in weak:
        out.append(Advice(
            f"rotation_axis_{_AXES[k]}", "red" if std_r[k] > th.rotation_std_red_deg else "amber",
            f"Rotation about the {a} {_AXES[k]} axis poorly determined",
            f"Its 1-sigma is {std_r[k]:.4f} deg, {std_r[k] / best:.1f} x the best axis ({best:.4f} deg). Add a "
            f"station tilted by 20-30 deg about the {a}'s {_AXES[k]} axis, with a sweep across the sphere as for "
            "the others.",
        ))
    if not weak and max(std_r) > th.rotation_std_amber_deg:
        out.append(Advice(
            "rotation_uncertain", "red" if max(std_r) > th.rotation_std_red_deg else "amber",
            "Rotation poorly determined about every axis",
            f"The rotation 1-sigmas are {', '.join(f'{s:.4f}' for s in std_r)} deg about the {a} x, y, z axes. "
            "They grow with the residuals: fix large residuals first (see above). Otherwise make the sweeps "
            "longer and wider (the rotation comes from the robot's moves within a station) and add profiles.",
        ))
    std_t = max(calibration_std(result)[1])
    if std_t > th.translation_std_amber_mm:
        out.append(Advice(
            "translation_uncertain", "red" if std_t > th.translation_std_red_mm else "amber",
            "Translation poorly determined",
            f"The largest translation 1-sigma is {std_t:.4f} mm. The translation comes from changes of "
            "orientation: add stations with larger tilts (20-45 deg) about different axes, and more profiles "
            "per sweep.",
        ))
    return out


def _prediction_advice(pred: StationPrediction, th: Thresholds) -> list[Advice]:
    """A kinematic calibration that predicts new poses worse than it should: the plan does
    not identify the arm's geometry, or the arm's error is not geometric."""
    rms, exp = pred.rms_mm, pred.expected_rms_mm
    ratio = rms / exp if exp > 0 else math.inf
    lost = bool(pred.unpredictable_stations)
    if not lost and rms <= th.prediction_amber_mm and ratio <= th.prediction_ratio_amber:
        return []
    level: Level = "red" if lost or rms > th.prediction_red_mm or ratio > th.prediction_ratio_red else "amber"
    worst = pred.per_station_mm.get(pred.worst_station, math.inf)
    if lost or exp > 2 * th.prediction_amber_mm or (rms > 3 * max(pred.in_sample_rms_mm, 1e-9)
                                                     and ratio <= th.prediction_ratio_amber):
        cause = ("The stations do not determine the arm's geometry: each is fitted well by the others' model "
                 f"({pred.in_sample_rms_mm:.4f} mm RMS with it included) but predicted poorly without it. Add stations "
                 "that spread the joints (leave acquisition.sweep.tilts_deg out and let the kinematic planner choose "
                 "them; its check says whether a plan identifies the arm).")
    else:
        cause = (f"That is {ratio:.1f} x what the noise and the fit's uncertainty explain: the arm's error is not all "
                 "geometric (gravity sag, thermal drift between stations, backlash), or some stations' poses or "
                 f"joints are wrong. Look at station {pred.worst_station} first; re-acquire with the arm warm and the "
                 "poses read after it settled.")
    return [Advice(
        "prediction_poor", level, "Points at new poses are predicted poorly through the calibrated arm",
        (f"Station(s) {', '.join(pred.unpredictable_stations)} cannot be predicted from the others at all. " if lost
         else f"Each station predicted from the others misses where it sees the sphere by {rms:.4f} mm RMS (worst "
              f"{worst:.4f} mm at station {pred.worst_station}). ") + cause)]


def _flagged_advice(result: CalibrationResult, th: Thresholds) -> list[Advice]:
    """The observations left out, grouped by their likely cause."""
    out: list[Advice] = []
    if result.flagged:
        groups: dict[str, list] = {}
        for f in result.flagged:
            groups.setdefault(wording.flag_cause(f.reason, result.timing is not None), []).append(f)
        parts = []
        for (cause, todo), flags in groups.items():
            which = ", ".join(f"{f.index} (station {f.station})" for f in flags)
            parts.append(f"Observation(s) {which}: likely {cause}; {todo}.")
        share = len(result.flagged) / max(_n_observations(result), 1)
        out.append(Advice(
            "flagged", "amber" if share > th.flagged_fraction_amber else "green",
            f"{len(result.flagged)} observation(s) left out",
            " ".join(parts) + " The result was computed without them.",
        ))
    return out


def _stray_point_advice(result: CalibrationResult, th: Thresholds) -> list[Advice]:
    """Points off the sphere, left out."""
    out: list[Advice] = []
    n_rej = result.residuals.n_points_rejected
    n_all = n_rej + result.residuals.n_points_used
    if n_all and n_rej / n_all > th.stray_fraction_info:
        out.append(Advice(
            "stray_points", "green", "Stray points rejected",
            f"{n_rej} of {n_all} points ({n_rej / n_all:.1%}) lay off the sphere and were left out "
            "(reflections, the sphere's edge, the stand or background). A few are normal; many suggest a too "
            "long exposure, a shiny or dirty sphere, or something else in the field of view.",
        ))
    return out


def start_vs_refined(diag) -> Mapping:
    """How far the fit's start (the two-step's, else the start from any orientations) is
    from the refined result: ``rotation_deg``, ``translation_mm`` ({} when not known)."""
    return diag.two_step_vs_refined or (diag.start or {}).get("vs_refined") or {}


def _start_disagrees(tsr: Mapping, th: Thresholds) -> bool:
    return tsr.get("rotation_deg", 0) > th.start_disagreement_deg or tsr.get("translation_mm", 0) > th.start_disagreement_mm


def _estimator_advice(result: CalibrationResult, th: Thresholds) -> list[Advice]:
    """The two-step start far from the refined result, or a refinement that did not converge."""
    out: list[Advice] = []
    diag = result.diagnostics
    tsr = start_vs_refined(diag)
    which = "Two-step" if diag.two_step_vs_refined else "Linear"
    # the robot's error explains a start the refinement left (the robot error advice says so): not the data's fault
    if _start_disagrees(tsr, th) and not start_disagreement_explained(result, th):
        out.append(Advice(
            "start_disagrees", "amber", f"{which} start and refinement disagree",
            f"They differ by {tsr.get('rotation_deg', 0):.3f} deg and {tsr.get('translation_mm', 0):.3f} mm. "
            "With good data they agree to a few hundredths; a large difference points at bad observations "
            "that were not caught, or at too little rotation between stations.",
        ))
    if (diag.refinement or {}).get("converged") is False:
        out.append(Advice(
            "not_converged", "red", "Refinement did not converge",
            "The estimate may be wrong. Check the dataset (units in mm, one orientation per station) and add "
            "stations with different tilts.",
        ))
    return out
