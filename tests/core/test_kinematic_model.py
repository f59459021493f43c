"""The arm's geometric error as the robot error model, and kinematic calibration from
the sphere. Known answers come from the simulator's true geometry."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.twostep import fit_sphere_fixed_radius
from spherecal.kinematics import chain_with_errors, corrected_flange_poses, error_parameter_names, flange_error_jacobian
from spherecal.models import Pose
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SimulatedArm, SweepPlan, simulate_dataset, standard_cell
from spherecal.urdf import read_urdf_chain
from spherecal.validation import points_in_object_frame

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


def _fresh_centres(cell, kin, sol, kappa):
    views = simulate_dataset(cell, FRESH)
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


def test_noise_free_identification_reproduces_the_true_arm_at_fresh_poses(kin):
    """Noise-free data: the identified model and transform put the sphere of fresh
    stations (not used, other orientations) where the calibration put it, to 1e-5 mm; the
    nominal model misses by tenths of a millimetre."""
    cell = standard_cell("eye_in_hand", seed=3, noise=NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0),
                         robot_error=RobotErrorModel(), arm=kin)
    sol = solve(simulate_dataset(cell, KIN_PLAN), CalibrationOptions(pose_translation_noise_mm=0.0,
                                                                     point_noise_mm=1e-4, identify_kinematics=True),
                kinematics=kin)
    ke = sol.refined.diagnostics["kinematic_effects"]
    assert 12 <= sum(ke["identified"]) < 36
    names = [n for n, i in zip(ke["names"], ke["identified"]) if not i]
    assert {"joint_1.x", "joint_1.y", "joint_1.z", "joint_6.zero_offset"} <= set(names)  # absorbed (eye-in-hand)
    after = _fresh_centres(cell, kin, sol, np.where(ke["identified"], sol.refined.kinematic_errors, 0.0))
    assert np.abs(after - sol.refined.centre).max() < 1e-5
    before = _fresh_centres(cell, kin, sol, np.zeros(36))
    assert np.abs(before - sol.refined.centre).max() > 0.05


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_marginalised_arm_error_is_honest(kin, mounting):
    """Systematic arm error, default options with the arm's kinematics known: the
    kinematic model is used and the transform is within 4 reported standard deviations of
    the truth on every seed (accuracy against the two-step: benchmarks/bench_accuracy.py)."""
    for seed in range(3):
        cell = standard_cell(mounting, seed=seed, noise=NOISE, robot_error=RobotErrorModel(), arm=kin)
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
    cell = standard_cell(mounting, seed=1, noise=NOISE, arm=kin)
    ds = simulate_dataset(cell)
    sol = solve(ds, OPTIONS, kinematics=kin)
    re = sol.result.robot_error
    assert re.model == "none" and re.kinematic_parameters is None
    assert re.model_choice.startswith("auto: the data show no geometric error of the arm")
    assert sol.refined.diagnostics["kinematic_evidence"]["likelihood_ratio"] < 5.41
    X = cell.true_transform
    e = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
    sd_robot = np.sqrt(np.diag(sol.refined.covariance_robot_frame)[:6])
    sd_true = np.sqrt(np.diag(sol.refined.covariance)[:6])
    assert np.all(np.abs(e) < 4 * sd_robot), e / sd_robot
    assert np.all(sd_true >= sd_robot) and sd_true[3:].max() > 3 * sd_robot[3:].max()
    stated = solve(ds, OPTIONS.model_copy(update={"robot_error_model": "kinematic"}), kinematics=kin)
    assert stated.result.robot_error.model == "kinematic" and stated.result.robot_error.model_choice is None


def test_calibrated_urdf_reads_back_as_the_identified_model(kin, tmp_path):
    from spherecal.runner import write_calibrated_urdf

    cell = standard_cell("eye_in_hand", seed=5, noise=NOISE, robot_error=RobotErrorModel(), arm=kin)
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
    # without joints there is nothing to identify: a clear error
    ds = simulate_dataset(cell, KIN_PLAN)
    with pytest.raises(Exception, match="identify_kinematics needs joint readings"):
        solve(ds, OPTIONS.model_copy(update={"identify_kinematics": True}))
