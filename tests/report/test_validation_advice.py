"""A failed validation names its cause when the robot's own error, which the calibration's
verdict already named, explains it (then the remedy is the robot's calibration, not the
sensor's), says which figures are absolute and which relative, and still says not to use
a calibration whose own verdict did not name the robot."""

import pytest

from spherecal.core.models import KinematicParameter, RobotErrorSummary
from spherecal.estimation import solve
from spherecal.motion.validation import FIGURE_SCOPE
from spherecal.report.assess import robot_error_dominates, verdict
from spherecal.report.validation_advice import robot_cause, validation_verdict
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

#: The plain example's validation (arm geometric error, robot error model auto): the
#: absolute figures and the flat beyond their MPEs.
FIGURES = {
    "P_F": {"max error (mm)": 0.1464, "worst position": "P2", "MPE (mm)": 0.25, "passed": True, "scope": "relative"},
    "P_S": {"max error (mm)": 0.0193, "worst position": "P1", "MPE (mm)": 0.06, "passed": True, "scope": "relative"},
    "SD": {"max error (mm)": 0.1889, "worst position": "B3", "MPE (mm)": 0.1, "passed": False, "scope": "absolute"},
    "F": {"max error (mm)": 0.1582, "worst position": "F1", "MPE (mm)": 0.15, "passed": False, "scope": "relative"},
    "centre spread": {"max error (mm)": 0.2466, "worst position": None, "MPE (mm)": 0.1, "passed": False,
                      "scope": "absolute"},
}


@pytest.fixture(scope="module")
def clean_result():
    """A clean cell's result: GREEN, the robot's error not dominating."""
    return solve(simulate_dataset(standard_cell("eye_in_hand", seed=3, fov=reference_fov()),
                                  SweepPlan(profiles_per_station=6))).result


def _arm_error(identified: bool = False, point_error_k2_mm: float = 1.117) -> RobotErrorSummary:
    """The robot error of the plain example's calibration: the arm's geometry (kinematic
    model, marginalised), its station-to-station error 99 % of a point's."""
    params = [KinematicParameter(name=f"joint_{j}.zero_offset", unit="deg", value=0.0, std=0.02, identifiable=True,
                                 identified=identified) for j in range(1, 4)]
    return RobotErrorSummary(
        model="kinematic", kinematic_parameters=params, station_rotation_deg=0.0092, station_translation_mm=0.071,
        estimated=True, common_rotation_deg=0.0, common_translation_mm=0.0,
        std_rotation_deg_robot_frame=(0.02, 0.01, 0.02), std_translation_mm_robot_frame=(0.01, 0.03, 0.02),
        point_error_k2_mm=point_error_k2_mm,
        point_error_parts_rms_mm={"robot_station_to_station_mm": 0.557, "sensor_noise_mm": 0.03,
                                  "transform_mm": 0.05},
        dominant="robot_station_to_station_mm")


def _with(result, err):
    return result.model_copy(update={"robot_error": err})


def test_every_figure_has_a_scope():
    assert set(FIGURES) == set(FIGURE_SCOPE)
    assert {n for n, s in FIGURE_SCOPE.items() if s == "absolute"} == {"SD", "centre spread"}


def test_a_failure_the_arms_geometry_explains_names_the_cause_and_the_remedy(clean_result):
    result = _with(clean_result, _arm_error())
    assert robot_error_dominates(result)
    v, cause = validation_verdict(verdict(result), FIGURES, result)
    assert v.level == "red"  # the MPEs are not met: exit 5 all the same
    assert v.headline.startswith("Validation failed: SD 0.1889 mm exceeds its MPE 0.1 mm; F 0.1582 mm")
    assert "Likely cause: the arm's own geometry, as the calibration's verdict said" in v.headline
    assert "Do not use" not in v.headline
    reasons = {text.split(":", 1)[0]: text for _, text in v.reasons}
    assert "expected error 1.117 mm, k = 2" in reasons["likely cause"]
    assert "identify_kinematics = true" in reasons["remedy"] and "calibrated_model" in reasons["remedy"]
    assert "accept these figures" in reasons["remedy"]
    scope = [text for _, text in v.reasons if text.startswith("absolute figures")]
    assert scope == [("absolute figures (they include the robot's own error): SD and centre spread beyond their "
                      "MPEs; relative figures (independent of where the robot thinks it is): F beyond its MPE, "
                      "P_F and P_S within")]
    assert cause.failed_absolute == ("SD", "centre spread") and cause.failed_relative == ("F",)
    assert cause.as_dict()["remedy"] == cause.remedy


def test_a_green_calibration_that_fails_still_says_do_not_use(clean_result):
    assert verdict(clean_result).level == "green" and not robot_error_dominates(clean_result)
    v, cause = validation_verdict(verdict(clean_result), FIGURES, clean_result)
    assert cause is None and v.level == "red"
    assert "Do not use this calibration: it does not measure as accurately as required" in v.headline
    assert any(text.startswith("absolute figures (they include the robot's own error)") for _, text in v.reasons)


@pytest.mark.parametrize("err, why", [
    (_arm_error(point_error_k2_mm=0.2), "a figure (centre spread 0.2466 mm) beyond what the robot explains"),
    (_arm_error(identified=True), "the arm's geometry identified: measured through its calibrated model"),
])
def test_no_robot_cause_when_the_robot_does_not_explain_it(clean_result, err, why):
    result = _with(clean_result, err)
    assert robot_cause(result, FIGURES) is None, why
    v, _ = validation_verdict(verdict(result), FIGURES, result)
    assert "Do not use this calibration" in v.headline, why


def test_a_station_model_names_the_robots_accuracy(clean_result):
    err = _arm_error().model_copy(update={"model": "station", "kinematic_parameters": None})
    cause = robot_cause(_with(clean_result, err), FIGURES)
    assert cause.short == "the robot's own absolute accuracy" and "absolute-accuracy option" in cause.remedy


def test_a_passed_validation_names_no_cause(clean_result):
    result = _with(clean_result, _arm_error())
    passed = {k: {**row, "passed": True} for k, row in FIGURES.items()}
    v, cause = validation_verdict(verdict(result), passed, result)
    assert cause is None and v.headline.endswith("Validation passed: every judged figure within its MPE.")
