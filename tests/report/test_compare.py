"""spherecal.report.compare: the difference between two calibrations, its significance, drift."""

import math

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.report.compare import (
    TransformEstimate,
    chi2_isf_6,
    chi2_sf_6,
    compare,
    covariance_from_std,
)
from spherecal.core.errors import ConfigError, InputError
from spherecal.estimation import calibrate
from spherecal.core.models import Pose
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

PLAN = SweepPlan(profiles_per_station=6)


def moved(pose: Pose, rotvec_rad, dt_mm) -> Pose:
    """``pose`` turned by ``rotvec_rad`` about its target frame's axes (left) and shifted."""
    return Pose.from_rt(geo.matrix_from_rotvec(rotvec_rad) @ pose.rotation_matrix, pose.translation + dt_mm)


@pytest.fixture(scope="module")
def result():
    return calibrate(simulate_dataset(standard_cell("eye_in_hand", seed=5, fov=reference_fov()), PLAN))


def test_a_known_rotation_and_translation_are_found(result):
    a = TransformEstimate.of_result(result, "A", "full")
    w = np.radians(0.2) * np.array([1.0, 2.0, 2.0]) / 3.0
    dt = np.array([0.3, -0.1, 0.2])
    b = TransformEstimate(moved(result.transform, w, dt), None, np.zeros((6, 6)), "B")
    c = compare(a, b)
    assert c.transform_name == "flange_from_sensor"  # B, given without a name, takes A's
    assert c.rotation_angle_deg == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_allclose(c.rotation_deg, np.degrees(w), atol=1e-9)
    np.testing.assert_allclose(c.translation_mm, dt, atol=1e-9)
    assert c.translation_length_mm == pytest.approx(np.linalg.norm(dt), abs=1e-9)
    # B has no covariance: the difference's sigma is A's own
    np.testing.assert_allclose(c.sigma[:3], result.std_rotation_deg, rtol=1e-9)
    np.testing.assert_allclose(c.sigma[3:], result.std_translation_mm, rtol=1e-9)
    assert c.beyond_threshold and c.significant and c.drift
    # the reverse comparison is the opposite difference
    back = compare(b.named("flange_from_sensor"), a)
    np.testing.assert_allclose(back.translation_mm, -dt, atol=1e-9)
    assert back.rotation_angle_deg == pytest.approx(0.2, abs=1e-9)


def test_the_robot_frame_uncertainty_leaves_out_the_robots_accuracy(result):
    """By default a result's uncertainty is relative to the robot's frame (what two
    calibrations on one robot can differ by); 'full' adds the robot's accuracy."""
    own = TransformEstimate.of_result(result, "A")
    full = TransformEstimate.of_result(result, "A", "full")
    sd = np.sqrt(np.diag(own.covariance))
    np.testing.assert_allclose(np.degrees(sd[:3]), result.robot_error.std_rotation_deg_robot_frame, rtol=1e-9)
    np.testing.assert_allclose(sd[3:], result.robot_error.std_translation_mm_robot_frame, rtol=1e-9)
    assert np.all(np.diag(full.covariance) > np.diag(own.covariance))
    with pytest.raises(ConfigError, match="expected one of robot-frame, full"):
        TransformEstimate.of_result(result, "A", "robot")


def test_the_mahalanobis_distance_of_a_difference_built_from_the_covariance(result):
    """A difference d = L u with (S_A + S_B) = L L^T has Mahalanobis distance |u|, and
    each component's sigma is sqrt of the summed variances."""
    a = TransformEstimate.of_result(result, "A")
    S = a.covariance
    b_cov = covariance_from_std(0.02, 0.01)
    L = np.linalg.cholesky(S + b_cov)
    u = np.array([1.0, -0.5, 0.8, 1.5, -2.0, 0.4])
    d = L @ u
    b = TransformEstimate(moved(result.transform, d[:3], d[3:]), "flange_from_sensor", b_cov, "B")
    c = compare(a, b)
    assert c.mahalanobis == pytest.approx(np.linalg.norm(u), rel=1e-6)
    assert c.p_value == pytest.approx(chi2_sf_6(float(u @ u)), rel=1e-5)
    sig = np.sqrt(np.diag(S + b_cov)) * np.array([math.degrees(1)] * 3 + [1] * 3)
    np.testing.assert_allclose(c.sigma, sig, rtol=1e-9)
    np.testing.assert_allclose(c.in_sigma, (d * np.array([math.degrees(1)] * 3 + [1] * 3)) / sig, rtol=1e-6)


def test_chi_square_6_against_known_quantiles():
    # chi-square, 6 degrees of freedom: 95 % point 12.592, 99 % point 16.812
    assert chi2_sf_6(12.5916) == pytest.approx(0.05, abs=1e-5)
    assert chi2_isf_6(0.01) == pytest.approx(16.8119, abs=1e-3)
    assert chi2_sf_6(0.0) == 1.0


def test_drift_needs_both_the_threshold_and_significance(result):
    a = TransformEstimate.of_result(result, "A")
    big_cov = covariance_from_std(5.0, 1.0)  # B known so poorly that 0.3 mm means nothing
    b = TransformEstimate(moved(result.transform, [0, 0, 0], [0.3, 0, 0]), None, big_cov, "B")
    c = compare(a, b)
    assert c.beyond_threshold and c.significant is False and not c.drift
    tiny = TransformEstimate(moved(result.transform, [0, 0, 0], [0.0, 0.0, 0.05]), None, np.zeros((6, 6)), "B")
    c = compare(a, tiny, threshold_mm=0.1)
    assert not c.beyond_threshold and not c.drift
    assert compare(a, tiny, threshold_mm=0.01).drift == bool(compare(a, tiny).significant)


def test_without_any_covariance_the_thresholds_decide(result):
    a = TransformEstimate(result.transform, "flange_from_sensor", np.zeros((6, 6)), "A")
    b = TransformEstimate(moved(result.transform, [0, 0, np.radians(0.06)], [0, 0, 0]), None, np.zeros((6, 6)), "B")
    c = compare(a, b)
    assert c.sigma is None and c.mahalanobis is None and c.significant is None
    assert c.drift  # 0.06 deg > 0.05 deg
    assert not compare(a, b, threshold_deg=0.1).drift


def test_different_transforms_are_refused(result):
    a = TransformEstimate.of_result(result, "jan/result.json")
    b = TransformEstimate(result.transform, "base_from_sensor", np.zeros((6, 6)), "feb/result.json")
    with pytest.raises(InputError, match=r"jan/result.json is flange_from_sensor \(eye_in_hand\) but "
                                         r"feb/result.json is base_from_sensor \(eye_to_hand\)"):
        compare(a, b)


def test_two_simulated_calibrations_with_a_known_difference():
    """Two cells whose true transforms differ by a known rotation and translation:
    the calibrations' difference is that one, within its own stated uncertainty, and
    drift; two calibrations of the same cell (other noise) are not."""
    cell_a = standard_cell("eye_in_hand", seed=11, fov=reference_fov())
    cell_b = standard_cell("eye_in_hand", seed=12, fov=reference_fov())
    w, dt = np.radians(0.15) * np.array([0.0, 0.6, 0.8]), np.array([0.4, -0.3, 0.0])
    cell_b.true_transform = moved(cell_a.true_transform, w, dt)
    cell_c = standard_cell("eye_in_hand", seed=13, fov=reference_fov())
    ra, rb, rc = (calibrate(simulate_dataset(cell, PLAN)) for cell in (cell_a, cell_b, cell_c))
    a, b, same = (TransformEstimate.of_result(r, n) for r, n in ((ra, "A"), (rb, "B"), (rc, "C")))
    c = compare(a, b)
    assert c.drift and c.significant
    err = np.concatenate([np.radians(c.rotation_deg) - w, np.subtract(c.translation_mm, dt)])
    # the difference found is the true one, to within 4 of its own sigma per component
    sig = np.asarray(c.sigma) * np.array([math.pi / 180] * 3 + [1] * 3)
    assert np.all(np.abs(err) < 4 * sig), (err, sig)
    c = compare(a, same)
    assert not c.drift and not c.significant and c.mahalanobis < math.sqrt(chi2_isf_6(0.01))


def _with_identified_arm(result):
    """``result`` as a kinematic calibration gives it: the arm's geometry identified."""
    from spherecal.core.models import KinematicParameter

    joint = KinematicParameter(name="joint_2.zero_offset", unit="deg", value=0.03, std=0.002, identifiable=True,
                               identified=True)
    return result.model_copy(update={"robot_error": result.robot_error.model_copy(
        update={"model": "kinematic", "kinematic_parameters": [joint]})})


def test_a_kinematic_calibration_is_not_compared_with_one_on_the_nominal_arm(result):
    """A transform found with the arm's geometry identified holds only through that
    calibrated arm model: its difference from one on the controller's nominal model is
    not drift, so the comparison is refused, naming which is which, rather than
    reporting a many-sigma 'drift'."""
    calibrated = _with_identified_arm(result)
    a = TransformEstimate.of_result(result, "A")
    b = TransformEstimate.of_result(calibrated, "B")
    assert (a.arm_model, b.arm_model) == ("nominal", "calibrated")
    with pytest.raises(InputError, match=r"B is relative to the arm geometry its own kinematic calibration identified"
                                         r".*A is relative to the controller's nominal arm model|A is relative to the "
                                         r"controller's nominal arm model.*B is relative"):
        compare(a, b)
    with pytest.raises(InputError, match="Compare like with like"):
        compare(b, TransformEstimate.of_result(calibrated, "C"))
    assert compare(a, TransformEstimate.of_result(result, "A again")).drift is False  # like with like still works
