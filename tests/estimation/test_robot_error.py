"""A robot with a real robot's systematic error: the simulated arm, and what the
estimator makes of it (station random effects, honest uncertainty, point error at new
poses, the verdict). Known answers come from the simulator's true geometry."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.prediction import point_error_budget
from spherecal.estimation.refine import NoiseAssumptions
from spherecal.estimation.twostep import fit_sphere_fixed_radius
from spherecal.core.kinematics import SerialChain
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.report.assess import Thresholds, advice, robot_error_dominates, verdict
from spherecal.sim import (
    NoiseModel, RobotErrorModel, SimulatedArm, SweepPlan, simulate_centre_dataset, simulate_dataset, standard_cell,
)
from spherecal.motion.validation import points_in_object_frame
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02)
OPTIONS = CalibrationOptions(pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.0)
EXACT = RobotErrorModel(joint_zero_offset_deg=(0, 0), link_length_mm=(0, 0), link_offset_mm=(0, 0), axis_tilt_deg=(0, 0))
NEW_VIEWS = SweepPlan(tilts_deg=[(15, 15, 0), (-20, 10, 0), (0, -25, 20), (25, 0, -30)],
                      station_offsets_mm=[(5.0, -10.0), (-5.0, 5.0)])


@pytest.fixture(scope="module")
def kin():
    """The IRB 2400's arm, as its plugin describes it through the host."""
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


def _solve(mounting, seed, kin, error=RobotErrorModel(), options=OPTIONS):
    cell = standard_cell(mounting, seed=seed, noise=NOISE, robot_error=error, arm=kin, fov=reference_fov())
    return cell, solve(simulate_dataset(cell), options)


def _errors(cell, R, t):
    X = cell.true_transform
    return geo.rotation_angle_deg(X.rotation_matrix, R), float(np.linalg.norm(X.translation - t))


# --- the chain and the simulated arm ----------------------------------------------------------
def test_the_plugins_chain_is_its_pinocchio_model(kin):
    rng = np.random.default_rng(0)
    q = rng.uniform(kin.lower_deg, kin.upper_deg, size=(300, 6))
    chain_T = kin.chain.flange_matrices(np.array([kin.model_joints_rad(v) for v in q]))
    pin_T = np.array([kin.flange_matrix_from_joints(v) for v in q])
    assert np.abs(chain_T - pin_T).max() < 1e-9


def test_chain_rejects_bad_geometry():
    with pytest.raises(ValueError, match="unit vectors"):
        SerialChain(np.eye(4)[None], np.array([[0.0, 0.0, 2.0]]), np.eye(4))
    with pytest.raises(ValueError, match="expected"):
        SerialChain(np.eye(4)[None], np.array([[0.0, 0.0, 1.0]]), np.eye(3))


def test_an_exact_arm_goes_where_it_reports(kin):
    arm = SimulatedArm(kin, EXACT, seed=1)
    q = np.array([10.0, 30.0, 20.0, -40.0, 50.0, 60.0])
    mm, deg = arm.flange_error(q)
    assert mm < 1e-9 and deg < 1e-9


def test_an_uncalibrated_arm_is_off_by_a_real_arms_error(kin):
    """Defaults: flange 0.5-2 mm and about 0.03-0.16 deg off the reported pose, the error
    changing slowly over the joints and fixed for one arm."""
    rng = np.random.default_rng(3)
    errs = []
    for seed in range(6):
        arm = SimulatedArm(kin, RobotErrorModel(), seed=seed)
        for _ in range(30):
            errs.append(arm.flange_error(rng.uniform(0.6 * kin.lower_deg, 0.6 * kin.upper_deg)))
        q = np.array([10.0, 30.0, 20.0, -40.0, 50.0, 60.0])
        a, b = arm.flange_error(q), arm.flange_error(q + 0.5)  # slowly: half a degree on every joint
        assert abs(a[0] - b[0]) < 0.1
        assert arm.flange_error(q) == SimulatedArm(kin, RobotErrorModel(), seed=seed).flange_error(q)
    e = np.array(errs)
    assert 0.3 < np.median(e[:, 0]) < 2.5 and e[:, 0].max() < 4.0
    assert 0.02 < np.median(e[:, 1]) < 0.2


def test_simulated_dataset_reports_the_nominal_pose_of_the_actual_joints(kin):
    cell = standard_cell("eye_in_hand", seed=2, noise=NoiseModel(point_noise_mm=0, pose_translation_noise_mm=0),
                         robot_error=RobotErrorModel(), arm=kin, fov=reference_fov())
    ds = simulate_dataset(cell)
    for o in ds.observations[:8]:
        nominal = kin.flange_pose_from_joints(o.joints_deg)
        assert np.allclose(o.base_from_flange.translation, nominal.translation, atol=1e-6)
        true = cell.arm.true_flange_pose(o.joints_deg)
        assert 0.3 < np.linalg.norm(true.translation - nominal.translation) < 4.0
    lo, hi = ds.provenance["flange_error_mm_range"]
    assert 0.3 < lo <= hi < 4.0


def test_robot_error_needs_an_arm():
    with pytest.raises(ValueError, match="needs an arm"):
        standard_cell("eye_in_hand", robot_error=RobotErrorModel(), fov=reference_fov())


def test_robot_error_model_rejects_bad_ranges():
    with pytest.raises(ValueError, match="joint_zero_offset_deg"):
        RobotErrorModel(joint_zero_offset_deg=(0.05, 0.02))


# --- the estimator under systematic robot error --------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_refinement_no_longer_pulls_the_robot_error_into_the_rotation(mounting, kin):
    """Without the station model the refined rotation is several times the two-step's
    error (the failure this model fixes); with it, about the two-step's, and the
    reported covariance covers the error (NEES of the six parameters near 6)."""
    ts, ref, old, nees = [], [], [], []
    for seed in range(6):
        cell, sol = _solve(mounting, seed, kin)
        ts.append(_errors(cell, sol.two_step.R, sol.two_step.t)[0])
        ref.append(_errors(cell, sol.refined.R, sol.refined.t)[0])
        X = cell.true_transform
        e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
        nees.append(float(e @ np.linalg.solve(sol.refined.covariance[:6, :6], e)))
        if mounting == "eye_in_hand":
            _, sol_old = _solve(mounting, seed, kin, options=OPTIONS.model_copy(update={"robot_error_model": "none"}))
            old.append(_errors(cell, sol_old.refined.R, sol_old.refined.t)[0])
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
    assert rms(ref) < 1.3 * rms(ts)
    assert np.mean(nees) < 20
    if old:
        assert rms(old) > 2.5 * rms(ref)


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_predicted_error_at_new_poses_matches_the_truth(mounting, kin):
    """Sphere centres fitted from sweeps at new orientations land where the prediction
    says (RMS over seeds and views, within a factor of 1.5)."""
    pred, meas = [], []
    for seed in range(6):
        cell, sol = _solve(mounting, seed, kin)
        ref = sol.refined
        nz = NoiseAssumptions(sol.result.diagnostics.noise["point_noise_mm"], 0.02, 0.0)
        pred.append(point_error_budget(sol.problem, ref, nz, shots_averaged=NEW_VIEWS.profiles_per_station)["rms_mm"])
        by: dict[str, list] = {}
        for o in simulate_dataset(cell, NEW_VIEWS).observations:
            by.setdefault(o.station, []).append(o)
        X = Pose.from_rt(ref.R, ref.t)
        for obs in by.values():
            q = points_in_object_frame(mounting, X, [o.base_from_flange for o in obs], [o.profile.points_mm for o in obs])
            c = fit_sphere_fixed_radius(q, cell.sphere_radius_mm, ref.centre)
            meas.append(float(np.linalg.norm(c - ref.centre)))
    ratio = np.sqrt(np.mean(np.square(pred))) / np.sqrt(np.mean(np.square(meas)))
    assert 1 / 1.5 < ratio < 1.5, ratio


@pytest.mark.slow
def test_verdict_tells_a_clean_cell_from_one_whose_robot_error_dominates(kin):
    for seed in range(3):
        _, clean = _solve("eye_in_hand", seed, kin, error=None)
        _, dirty = _solve("eye_in_hand", seed, kin)
        v_clean, v_dirty = verdict(clean.result), verdict(dirty.result)
        assert v_clean.level == "green" and "clean cell" in v_clean.headline
        assert not robot_error_dominates(clean.result)
        assert robot_error_dominates(dirty.result)
        assert "Robot error dominates" in v_dirty.headline and v_dirty.level == "amber"
        robot_error = dirty.result.robot_error
        assert robot_error.dominant == "robot_station_to_station_mm"
        assert clean.result.robot_error.point_error_k2_mm < robot_error.point_error_k2_mm


def test_given_station_error_is_used_not_estimated(kin):
    opt = OPTIONS.model_copy(update={"station_translation_error_mm": 0.2, "station_rotation_error_deg": 0.01})
    _, sol = _solve("eye_in_hand", 0, kin, options=opt)
    robot_error = sol.result.robot_error
    assert robot_error.station_translation_mm == pytest.approx(0.2)
    assert robot_error.station_rotation_deg == pytest.approx(0.01)
    assert robot_error.estimated is False


@pytest.mark.slow
def test_the_common_robot_error_only_widens_the_uncertainty(kin):
    """The error every station shares is a consider parameter: it changes the reported
    covariance, never the estimate."""
    _, a = _solve("eye_to_hand", 1, kin)
    _, b = _solve("eye_to_hand", 1, kin, options=OPTIONS.model_copy(update={"robot_accuracy_mm": 0.0,
                                                                            "robot_accuracy_deg": 0.0}))
    assert np.allclose(a.refined.R, b.refined.R, atol=1e-12) and np.allclose(a.refined.t, b.refined.t, atol=1e-9)
    assert min(a.result.std_translation_mm) > 0.7  # the assumed 0.75 mm per axis moves base_from_sensor whole
    assert max(b.result.std_translation_mm) < 0.3


# --- the advice ---------------------------------------------------------------------------------
def _xyzw_centre_table(mounting: str):
    """A sphere-centre table (no joints) of stations tilted 20 deg apart whose quaternions
    are written (x, y, z, w) and read w first."""
    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    cell = standard_cell(mounting, seed=1, noise=noise, fov=reference_fov())
    plan = SweepPlan(profiles_per_station=4, tilts_deg=[(0, 0, 0), (20, 0, 0), (0, 20, 0), (0, 0, 20)])
    ds = simulate_centre_dataset(cell, plan, kind="sphere_centre", centre_noise_mm=0.02)
    return ds.model_copy(update={"observations": [
        o.model_copy(update={"base_from_flange": o.base_from_flange.model_copy(update={
            "quaternion_wxyz": np.roll(np.asarray(o.base_from_flange.quaternion_wxyz), -1)})})
        for o in ds.observations]})


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_kinematic_calibration_is_never_advised_for_an_implausible_disagreement(mounting):
    """The advice to calibrate the robot's kinematics fits an arm whose stations disagree
    by what an arm's geometry can do (tenths of a millimetre to a few, hundredths of a
    degree to tenths). Stations of one table disagreeing by degrees (eye-in-hand: the
    5 deg bound of the fit) or by tens of millimetres (eye-to-hand: 19 mm) point at the
    data: the advice says so and what to check, never the robot's calibration, and a
    scale at its bound is given as the bound, in the advice and in the verdict's own line."""
    result = solve(_xyzw_centre_table(mounting), CalibrationOptions()).result
    err = result.robot_error
    assert err is not None and (err.station_rotation_deg > 1.0 or err.station_translation_mm > 10.0), err
    said = advice(result)
    text = " ".join(a.text for a in said)
    assert "calibrate the robot's kinematics" not in text and "robot_error_dominates" not in [a.key for a in said]
    data = [a for a in said if a.key == "stations_disagree_implausibly"]
    assert len(data) == 1 and data[0].level == "red" and "a data error" in data[0].title, said
    assert "the quaternions' order" in data[0].text and "the mounting" in data[0].text
    assert "radius" not in data[0].text  # sphere centres do not depend on it
    (robot,) = [text for _, text in verdict(result).reasons if text.startswith("a point measured at a new pose")]
    if mounting == "eye_in_hand":
        assert "0.000 mm and at least 5 deg per axis" in data[0].text, data[0].text
        assert "stations disagree by 0.000 mm and at least 5 deg per axis" in robot, robot
        assert "5.0000 deg" not in robot
    else:
        assert f"{err.station_translation_mm:.3f} mm and" in data[0].text


@pytest.mark.slow
def test_the_robot_error_advice_asks_for_what_the_model_uses(kin):
    """Robot error dominates; what the advice asks for depends on the model. The arm's
    geometry modelled from its joints (no common error assumed): calibrate that geometry
    with spherecal, and no 'robot accuracy better than the assumed 0 mm / 0 deg'. The
    station model with the robot's accuracy given as exact: nothing to better either.
    With the default accuracy assumed, it may be given."""
    cell = standard_cell("eye_in_hand", seed=0, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov(n_columns=160))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=6))
    options = CalibrationOptions(pose_translation_noise_mm=0.02)
    exact = options.model_copy(update={"robot_accuracy_mm": 0.0, "robot_accuracy_deg": 0.0})
    texts = {}
    for name, opt, k in [("kinematic", options, kin), ("station exact", exact, None), ("station", options, None)]:
        result = solve(ds, opt, kinematics=k).result
        assert robot_error_dominates(result), name
        texts[name] = [a.text for a in advice(result) if a.key == "robot_error_dominates"][0]
    assert "assumed 0 mm" not in texts["kinematic"] and "robot_accuracy" not in texts["kinematic"]
    assert "calibrate the arm's geometry with spherecal" in texts["kinematic"]
    assert "identify_kinematics = true" in texts["kinematic"]
    assert "robot_accuracy" not in texts["station exact"] and "assumed 0 mm" not in texts["station exact"]
    assert "calibrate the robot's kinematics" in texts["station exact"]
    assert "if it is better than the assumed 0.75 mm / 0.06 deg" in texts["station"]


def test_the_verdict_and_the_advice_name_one_cause_the_arms_geometry(kin):
    """Eye-to-hand, the arm off its nominal geometry, its error modelled from the joints
    and integrated out (the eye-to-hand example's model). The stations' differences show
    a few hundredths of a millimetre of that error; most of it every station shares. The
    headline, the reasons and the advice name one cause, the arm's geometry, with one
    figure and one remedy (calibrating the arm). The two-step start leaves the arm's
    error out and parts from the result by about its size (0.62 mm at this seed, 1.04 mm
    in the example; the note's limit is lowered to 0.3 mm to see it here): the advice
    says that is the same error, and does not blame bad observations."""
    cell = standard_cell("eye_to_hand", seed=0, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    result = solve(simulate_dataset(cell), OPTIONS, kinematics=kin).result
    th = Thresholds(start_disagreement_mm=0.3)
    err, tsr = result.robot_error, result.diagnostics.two_step_vs_refined
    assert err.model == "kinematic" and robot_error_dominates(result, th)
    assert err.station_translation_mm < 0.1 < err.point_error_parts_rms_mm["robot_station_to_station_mm"]
    assert 0.3 < tsr["translation_mm"] < err.point_error_k2_mm
    v, said = verdict(result, th), advice(result, th)
    expected = f"{err.point_error_k2_mm:.3f} mm"
    assert v.level == "amber" and "the arm's geometric error, not the calibration" in v.headline
    assert expected in v.headline and "calibrating the arm" in v.headline
    assert "stations disagree by more than the noise" not in v.headline
    assert not [r for lvl, r in v.reasons if lvl != "green" and "stations disagree by" in r]
    assert [a.key for a in said] == ["robot_error_dominates"], [a.key for a in said]
    text = said[0].text
    assert expected in text and "calibrate the arm's geometry with spherecal" in text
    assert f"{tsr['translation_mm']:.3f} mm: that is this error too, not bad data" in text
    assert "bad observations" not in " ".join(a.text for a in said)
