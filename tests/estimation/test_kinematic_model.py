"""The arm's geometric error as the robot error model, and kinematic calibration from
the sphere. Known answers come from the simulator's true geometry."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import InputError
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.twostep import fit_sphere_fixed_radius
from spherecal.core.kinematics import chain_with_errors, corrected_flange_poses, error_parameter_names, flange_error_jacobian
from spherecal.core.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SimulatedArm, SweepPlan, simulate_dataset, standard_cell
from spherecal.core.urdf import read_urdf_chain
from spherecal.motion.validation import points_in_object_frame
from reference_sensor import reference_fov

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02)
OPTIONS = CalibrationOptions(pose_translation_noise_mm=0.02)


def _spread(n, seed, max_deg, turn_deg):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        a = max_deg * np.sqrt((k + 0.5) / n)
        out.append((float(d[0] * a), float(d[1] * a), float(rng.uniform(-turn_deg, turn_deg))))
    return out


#: A kinematic calibration plan (as examples/sim-kinematic-eye-in-hand.toml) and fresh stations.
KIN_PLAN = SweepPlan(profiles_per_station=6, tilts_deg=_spread(16, 7, 50, 90),
                     station_offsets_mm=[(0.0, 0.0), (8.0, -15.0), (-8.0, 10.0)])
FRESH = SweepPlan(profiles_per_station=6, tilts_deg=_spread(4, 99, 45, 90), station_offsets_mm=[(0.0, -5.0)])
#: The same for eye-to-hand, whose sphere turns on the flange in front of a fixed sensor (smaller turns).
KIN_PLAN_E2H = KIN_PLAN.model_copy(update={"tilts_deg": _spread(16, 7, 30, 40)})
FRESH_E2H = FRESH.model_copy(update={"tilts_deg": _spread(4, 99, 27, 40)})
PLANS = {"eye_in_hand": (KIN_PLAN, FRESH), "eye_to_hand": (KIN_PLAN_E2H, FRESH_E2H)}


@pytest.fixture(scope="module")
def kin():
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


def test_flange_error_jacobian_matches_finite_differences(kin):
    chain = kin.chain
    q = np.random.default_rng(3).uniform(-1.5, 1.5, (6, 6))
    J = flange_error_jacobian(chain, q)
    T0 = chain.flange_matrices(q)
    h = 1e-6
    for k in range(J.shape[2]):
        e = np.zeros(J.shape[2])
        e[k] = h
        T1 = chain_with_errors(chain, e).flange_matrices(q)
        w = np.array([geo.rotvec_from_matrix(a[:3, :3] @ b[:3, :3].T) for a, b in zip(T1, T0)]) / h
        tau = (T1[:, :3, 3] - T0[:, :3, 3]) / h
        assert np.allclose(np.hstack([w, tau]), J[:, :, k], atol=2e-3 * max(1.0, np.abs(J[:, :, k]).max())), \
            error_parameter_names(chain)[k]


def test_zero_errors_leave_the_chain_as_it_is(kin):
    q = np.random.default_rng(4).uniform(-1, 1, (5, 6))
    assert np.array_equal(chain_with_errors(kin.chain, np.zeros(36)).flange_matrices(q), kin.chain.flange_matrices(q))


def _fresh_centres(cell, kin, sol, kappa, fresh=FRESH):
    views = simulate_dataset(cell, fresh)
    by: dict[str, list] = {}
    for o in views.observations:
        by.setdefault(o.station, []).append(o)
    X = Pose.from_rt(sol.refined.R, sol.refined.t)
    model = chain_with_errors(kin.chain, kappa)
    out = []
    for obs in by.values():
        q = np.array([kin.model_joints_rad(o.joints_deg) for o in obs])
        poses = corrected_flange_poses(kin.chain, model, q, [o.base_from_flange for o in obs])
        pts = points_in_object_frame(cell.mounting, X, poses, [o.profile.points_mm for o in obs])
        out.append(fit_sphere_fixed_radius(pts, cell.sphere_radius_mm, sol.refined.centre))
    return np.array(out)


def _truth_in_identified_parameters(cell, kin, dataset, identified):
    """The simulated truth expressed exactly in the identified parameters: the transform,
    sphere centre and identified geometric errors (the others zero) that put the sphere
    centre, in the sensor frame, where the true arm, transform and sphere put it at every
    shot. Found by Levenberg-Marquardt on those sensor-frame centres from the true
    transform and sphere and no arm error; independent of the estimator, which fits
    profile points. Returns (R, t, centre, errors (36,)) and the largest residual (mm)."""
    from scipy.optimize import least_squares

    joints = [o.joints_deg for o in dataset.observations]
    q = np.array([kin.model_joints_rad(j) for j in joints])
    X, c = cell.true_transform, cell.sphere_centre_mm

    def centres(X_mat, centre, chain_matrices):
        A = chain_matrices if cell.mounting == "eye_in_hand" else np.linalg.inv(chain_matrices)
        return np.einsum("ij,nj->ni", np.linalg.inv(X_mat), np.einsum("nij,j->ni", np.linalg.inv(A), [*centre, 1.0]))[:, :3]

    truth = centres(X.as_matrix(), c, np.array([cell.arm.true_flange_pose(j).as_matrix() for j in joints]))
    ids = np.flatnonzero(identified)
    angle = np.array([n.split(".")[1] in ("zero_offset", "tilt_u", "tilt_v") for n in error_parameter_names(kin.chain)])
    scale = np.concatenate([[1e-3] * 3, [1.0] * 6, np.where(angle[ids], 1e-3, 1.0)])  # rad and mm of like effect

    def unpack(y):
        x = y * scale
        kappa = np.zeros(36)
        kappa[ids] = x[9:]
        return geo.matrix_from_rotvec(x[:3]) @ X.rotation_matrix, X.translation + x[3:6], c + x[6:9], kappa

    def residual(y):
        R, t, centre, kappa = unpack(y)
        return (centres(geo.matrix_from_rt(R, t), centre, chain_with_errors(kin.chain, kappa).flange_matrices(q))
                - truth).ravel()

    fit = least_squares(residual, np.zeros(9 + len(ids)), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return unpack(fit.x), float(np.abs(fit.fun).max())


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_noise_free_identification_recovers_the_true_geometry(kin, mounting):
    """Noise-free data: in the identifiable subspace the identified geometric errors,
    transform and sphere equal the truth expressed in the identified parameters
    (:func:`_truth_in_identified_parameters`, which reproduces the true sphere centres to
    1e-9 mm: the parameters left out are exactly absorbed) to 1e-6 rad and mm, with the
    estimator's default convergence tolerance; and the sphere seen from fresh stations
    lands where the calibration put it, to 1e-5 mm, where the nominal model misses by
    tenths of a millimetre."""
    plan, fresh = PLANS[mounting]
    cell = standard_cell(mounting, seed=3, noise=NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0),
                         robot_error=RobotErrorModel(), arm=kin, fov=reference_fov())
    ds = simulate_dataset(cell, plan.model_copy(update={"profiles_per_station": 4}))  # noise-free: 4 are plenty
    sol = solve(ds, CalibrationOptions(pose_translation_noise_mm=0.0, point_noise_mm=1e-4, identify_kinematics=True),
                kinematics=kin)
    ke = sol.refined.diagnostics["kinematic_effects"]
    identified = np.array(ke["identified"])
    assert 12 <= identified.sum() < 36
    absorbed = {"joint_1.x", "joint_1.y", "joint_1.z", "joint_6.zero_offset"}  # by the sphere or the transform
    assert absorbed <= {n for n, i in zip(ke["names"], identified) if not i}
    (R, t, centre, kappa), worst = _truth_in_identified_parameters(cell, kin, ds, identified)
    assert worst < 1e-9
    assert np.abs(kappa[identified]).max() > 0.1  # a real arm error to recover (mm)
    assert np.abs(np.asarray(sol.refined.kinematic_errors)[identified] - kappa[identified]).max() < 1e-6
    assert np.linalg.norm(geo.rotvec_from_matrix(sol.refined.R @ R.T)) < 1e-6
    assert np.abs(sol.refined.t - t).max() < 1e-6 and np.abs(sol.refined.centre - centre).max() < 1e-6
    after = _fresh_centres(cell, kin, sol, np.where(identified, sol.refined.kinematic_errors, 0.0), fresh)
    assert np.abs(after - sol.refined.centre).max() < 1e-5
    before = _fresh_centres(cell, kin, sol, np.zeros(36), fresh)
    assert np.abs(before - sol.refined.centre).max() > 0.05


def planned_config(tmp_path, mounting, profiles_per_station=5):
    """The example cell of ``mounting`` with identify_kinematics and no stations listed:
    the kinematic planner chooses them."""
    from spherecal.config import load_config

    text = (EXAMPLES / f"sim-{mounting.replace('_', '-')}.toml").read_text()
    text = re.sub(r"(?m)^profiles_per_station = .*$", f"profiles_per_station = {profiles_per_station}", text)
    text = re.sub(r"(?m)^output_dir = .*$", 'output_dir = "out"', text)
    if re.search(r"(?m)^\[calibration\]$", text):
        text = re.sub(r"(?m)^\[calibration\]$", "[calibration]\nidentify_kinematics = true", text)
    else:
        text += "\n[calibration]\nidentify_kinematics = true\n"
    path = tmp_path / f"{mounting}.toml"
    path.write_text(text)
    from spherecal.plugins.host import PluginHost
    from spherecal.app.cell import configured_for_sensor

    return configured_for_sensor(load_config(path), PluginHost())[0].config  # as a run: the sensor's standoff


def _joint_spans(kin, targets):
    """Range of each joint (deg) over the targets, as the robot takes them in order."""
    joints, seed = [], None
    for t in targets:
        seed = kin.joints_from_flange_pose(t.pose, seed)
        joints.append(seed)
    return np.ptp(joints, axis=0)


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_planned_stations_calibrate_the_arm(kin, mounting, tmp_path):
    """identify_kinematics with no stations given: the planner's 20 stations lie in the
    workspace and the arm's reach, spread the bending joints further than the default plan, pass
    the identifiability check, and calibrate the simulated arm (robot error on): the sphere
    seen from fresh stations, mapped through the identified model, scatters at most 0.05 mm
    RMS, a fraction of what the nominal model gives."""
    from spherecal.motion.acquisition import check_targets, plan_targets
    from spherecal.motion.kinematic_plan import MAX_IDENTIFICATION_CONDITION, check_plan_identifies_kinematics, \
        plan_kinematic_stations, uses_planner

    cfg = planned_config(tmp_path, mounting)
    assert uses_planner(cfg.acquisition, cfg.calibration)
    sections = (cfg.acquisition, cfg.calibration, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    plan = plan_kinematic_stations(*sections, kin)
    assert len(plan.sweep.tilts_deg) == 20 and plan.sweep.profiles_per_station == 5
    targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere, plan.sweep)
    assert check_targets(targets, cfg.acquisition) == []
    summary = check_plan_identifies_kinematics(targets, *sections, kin)
    assert "identifies 18 of 36 geometric parameters (per joint: 0, 4, 4, 4, 4, 2)" in summary
    assert float(re.search(r"condition number (\d+)", summary)[1]) < MAX_IDENTIFICATION_CONDITION / 2
    default_targets = plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)
    spans, default = _joint_spans(kin, targets), _joint_spans(kin, default_targets)
    bends = [0, 1, 2, 4]  # the IRB 2400's waist, shoulder, elbow and wrist bend (4 and 6 roll)
    assert np.all(spans[bends] > 1.5 * default[bends]) and spans[1] > 20 and spans[2] > 15, (spans, default)

    cell = standard_cell(mounting, seed=11, noise=NOISE, robot_error=RobotErrorModel(), arm=kin, fov=reference_fov())
    sol = solve(simulate_dataset(cell, plan.sweep), OPTIONS.model_copy(update={"identify_kinematics": True}),
                kinematics=kin)
    identified = np.array(sol.refined.diagnostics["kinematic_effects"]["identified"])
    fresh = PLANS[mounting][1]

    def scatter(kappa):
        c = _fresh_centres(cell, kin, sol, kappa, fresh)
        return float(np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=1))))

    after = scatter(np.where(identified, sol.refined.kinematic_errors, 0.0))
    before = scatter(np.zeros(36))
    assert after <= 0.05 and before > 2.5 * after, (after, before)


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_marginalised_arm_error_is_honest(kin, mounting):
    """Systematic arm error, default options with the arm's kinematics known: the
    kinematic model is used and the transform is within 4 reported standard deviations of
    the truth on every seed (accuracy against the two-step: benchmarks/bench_accuracy.py)."""
    for seed in range(3):
        cell = standard_cell(mounting, seed=seed, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                             fov=reference_fov())
        sol = solve(simulate_dataset(cell), OPTIONS, kinematics=kin)
        assert sol.result.robot_error.model == "kinematic"
        assert sol.result.robot_error.model_choice.startswith("auto: the data show the arm's geometric error")
        X = cell.true_transform
        e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
        sd = np.sqrt(np.diag(sol.refined.covariance)[:6])
        assert np.all(np.abs(e) < 4 * sd), (seed, e / sd)


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_an_exact_arm_gets_the_efficient_fit(kin, mounting):
    """An arm with no geometric error, default options: the data show none, so 'auto'
    takes the pose-noise-only fit, whose error is that of the noise (within 4 of its
    robot-frame standard deviations, hundredths of a mm: the kinematic model's fit is
    0.1-0.5 mm off here), and the geometry one sphere cannot see stays in the covariance
    against the true frames. Told 'kinematic', the model is kept whatever the evidence."""
    cell = standard_cell(mounting, seed=1, noise=NOISE, arm=kin, fov=reference_fov())
    ds = simulate_dataset(cell)
    sol = solve(ds, OPTIONS, kinematics=kin)
    robot_error = sol.result.robot_error
    assert robot_error.model == "none" and robot_error.kinematic_parameters is None
    assert robot_error.model_choice.startswith("auto: the data show no geometric error of the arm")
    assert sol.refined.diagnostics["kinematic_evidence"]["likelihood_ratio"] < 5.41
    X = cell.true_transform
    e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
    sd_robot = np.sqrt(np.diag(sol.refined.covariance_robot_frame)[:6])
    sd_true = np.sqrt(np.diag(sol.refined.covariance)[:6])
    assert np.all(np.abs(e) < 4 * sd_robot), e / sd_robot
    assert np.all(sd_true >= sd_robot) and sd_true[3:].max() > 3 * sd_robot[3:].max()
    stated = solve(ds, OPTIONS.model_copy(update={"robot_error_model": "kinematic"}), kinematics=kin)
    assert stated.result.robot_error.model == "kinematic" and stated.result.robot_error.model_choice is None


@pytest.mark.slow
def test_calibrated_urdf_reads_back_as_the_identified_model(kin, tmp_path):
    from spherecal.app.solving import write_calibrated_urdf

    cell = standard_cell("eye_in_hand", seed=5, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    sol = solve(simulate_dataset(cell, KIN_PLAN), OPTIONS.model_copy(update={"identify_kinematics": True}),
                kinematics=kin)
    path = write_calibrated_urdf(sol, kin, tmp_path)
    assert path.name == "robot_calibrated.urdf"
    ke = sol.refined.diagnostics["kinematic_effects"]
    model = chain_with_errors(kin.chain, np.where(ke["identified"], sol.refined.kinematic_errors, 0.0))
    back = read_urdf_chain(path, "base_link", "tool0")
    back = getattr(back, "chain", back)
    q = np.random.default_rng(1).uniform(-1, 1, (200, 6))
    assert np.abs(back.flange_matrices(q)[:, :3, 3] - model.flange_matrices(q)[:, :3, 3]).max() < 1e-9
    params = sol.result.robot_error.kinematic_parameters
    assert len(params) == 36 and sum(p.identified for p in params) == sum(ke["identified"])
    assert all(p.std > 0 for p in params if p.identified)
    # result.json reads back (validate and scan read it): the transform's and sphere's
    # covariance, the identified parameters with their spreads
    from spherecal.io import dataset as dataio

    dataio.write_result(tmp_path / "result.json", sol.result)
    back = dataio.read_result(tmp_path / "result.json")
    assert np.array(back.covariance).shape == (9, 9)
    assert np.allclose(back.covariance, sol.refined.covariance[:9, :9])
    assert back.robot_error.kinematic_parameters == params
    # without joints there is nothing to identify: a clear error
    ds = simulate_dataset(cell, KIN_PLAN)
    with pytest.raises(Exception, match="identify_kinematics needs joint readings"):
        solve(ds, OPTIONS.model_copy(update={"identify_kinematics": True}))


def _with_joints(ds, joints_of):
    obs = ds.observations
    return ds.model_copy(update={"observations": [o.model_copy(update={"joints_deg": joints_of(i, o)})
                                                  for i, o in enumerate(obs)]})


def test_joints_that_do_not_describe_the_poses_are_not_used(kin):
    """Each shot's joints against the pose reported with it, through the robot's model.
    Joints of another moment (every shot carrying the one before's) or in radians: the
    kinematic model would take the robot's error from the wrong arm and state an
    uncertainty 10 times too small, so `auto` does not use them, says why in the verdict
    (AMBER), and the transform is within its stated uncertainty of the truth; asked for
    by name, the kinematic model refuses them. One shot whose joints are off is left out."""
    cell = standard_cell("eye_in_hand", seed=1, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    ds = simulate_dataset(cell)
    obs = ds.observations
    faults = {"stale": lambda i, o: obs[i - 1].joints_deg if i else o.joints_deg,
              "radians": lambda i, o: tuple(np.radians(o.joints_deg))}
    X = cell.true_transform
    for name, joints_of in faults.items():
        sol = solve(_with_joints(ds, joints_of), OPTIONS, kinematics=kin)
        assert sol.result.robot_error.model == "station", name
        reason = sol.result.diagnostics.joints_vs_poses["reason"]
        assert reason.startswith(f"the joint readings do not match the reported flange poses: for {len(obs)} of "
                                 f"{len(obs)} shots the robot's model puts the flange"), reason
        from spherecal.report.assess import verdict

        v = verdict(sol.result)
        assert v.level != "green" and ("amber", reason) in v.reasons
        e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
        assert np.all(np.abs(e) < 4 * np.sqrt(np.diag(sol.refined.covariance)[:6])), (name, e)
        with pytest.raises(InputError, match="the joint readings do not match the reported flange poses"):
            solve(_with_joints(ds, joints_of), OPTIONS.model_copy(update={"robot_error_model": "kinematic"}),
                  kinematics=kin)
    one = solve(_with_joints(ds, lambda i, o: obs[i - 1].joints_deg if i == 13 else o.joints_deg), OPTIONS,
                kinematics=kin)
    assert one.result.robot_error.model == "kinematic"
    (flag,) = [f for f in one.result.flagged if f.index == obs[13].index]
    assert "from the pose given with them" in flag.reason and "joints read at another moment" in flag.reason
    # the joints as taken: nothing flagged for them
    clean = solve(ds, OPTIONS, kinematics=kin)
    assert clean.result.diagnostics.joints_vs_poses is None
    assert not [f for f in clean.result.flagged if "joints" in f.reason]
