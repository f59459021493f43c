"""The station model's uncertainty in a world with systematic robot error (the arm's
geometry off its nominal model, pose-only data): the scales of the station effects are
estimates, and their uncertainty is in the covariance; in eye-to-hand the robot's common
rotation passes whole into the transform's rotation and into its uncertainty.

Known answers from the simulator with the true transform: seeds of the accuracy
benchmark's worlds (benchmarks/bench_accuracy.py, plan A) on which the covariance at the
estimated scales alone claimed far too much (NEES 25 and 27 against 6)."""

from __future__ import annotations

import numpy as np
import pytest
from reference_sensor import reference_fov

from spherecal.core import geometry as geo
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.refine import (
    _neg2_reml_derivatives,
    _SCALE_BOUNDS,
    _reml_batch,
)
from spherecal.plugins.host import PluginHost
from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell


def _blocks(rng, p=9, K=4):
    q = 6 * K
    J_t = rng.normal(size=(200, p))
    J_d = rng.normal(size=(200, q)) * 50.0
    y = rng.normal(size=200)
    return (J_t.T @ J_t, J_t.T @ J_d, J_d.T @ J_d, J_t.T @ y, J_d.T @ y, float(y @ y)), p, q


def test_the_batched_reml_is_the_single_evaluation_and_the_gls_of_the_joint_system():
    rng = np.random.default_rng(5)
    blocks, p, q = _blocks(rng)
    A_tt, A_td, A_dd, b_t, b_d, _ = blocks
    sds = np.abs(rng.normal(size=(5, q))) * np.array([1e-4, 1e-2, 1.0, 1e-7, 3.0])[:, None]
    values, steps, covs = _reml_batch(sds, blocks)
    for sd, value, step, cov in zip(sds, values, steps, covs):
        assert value == pytest.approx(_neg2_reml_derivatives(sd, np.zeros(q, dtype=int), 1, *blocks)[0], rel=1e-10)
        L = np.diag(sd)
        N = np.block([[A_tt, A_td @ L], [L @ A_td.T, L @ A_dd @ L + np.eye(q)]])
        Ninv = np.linalg.inv(N)
        assert np.allclose(cov, Ninv[:p, :p], rtol=1e-8, atol=1e-14)
        assert np.allclose(step, (Ninv @ np.concatenate([b_t, L @ b_d]))[:p], rtol=1e-8, atol=1e-12)


def test_the_block_path_of_the_batched_reml_is_the_dense_one_on_station_blocks():
    # station offsets only: each shot touches its own station's six columns, A_dd is
    # block-diagonal, and factorising its blocks alone must give the dense path's numbers
    rng = np.random.default_rng(8)
    p, K, n = 9, 5, 60
    station = np.repeat(np.arange(K), n // K)
    J_t = rng.normal(size=(n, p))
    J_d = np.zeros((n, 6 * K))
    for k in range(K):
        J_d[station == k, 6 * k:6 * k + 6] = rng.normal(size=(n // K, 6)) * 40.0
    y = rng.normal(size=n)
    blocks = (J_t.T @ J_t, J_t.T @ J_d, J_d.T @ J_d, J_t.T @ y, J_d.T @ y, float(y @ y))
    sds = np.abs(rng.normal(size=(7, 6 * K))) * np.array([1e-5, 1e-3, 1e-1, 1.0, 1e-7, 5.0, 30.0])[:, None]
    dense = _reml_batch(sds, blocks)
    by_block = _reml_batch(sds, blocks, 6)
    for a, b in zip(dense, by_block):
        assert np.allclose(a, b, rtol=1e-9, atol=1e-13)


@pytest.fixture(scope="module")
def arm():
    return PluginHost().arm_kinematics({"type": "abb_irb2400"})


def _solve_systematic(mounting: str, seed: int, arm):
    cell = standard_cell(mounting, seed=seed, noise=NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02),
                         sphere_radius_mm=19.1, robot_error=RobotErrorModel(), arm=arm, fov=reference_fov())
    opts = CalibrationOptions(pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002,
                              robot_error_model="station")
    sol = solve(simulate_dataset(cell, SweepPlan()), opts, kinematics=arm)
    X = cell.true_transform
    err = np.concatenate([geo.rotvec_from_matrix(sol.refined.R @ X.rotation_matrix.T), sol.refined.t - X.translation])
    cov = sol.refined.covariance[:6, :6]
    return sol, err, cov, opts


def test_a_station_scale_on_its_floor_no_longer_claims_the_transform_known(arm):
    sol, err, cov, _ = _solve_systematic("eye_in_hand", 2, arm)
    assert sol.refined.station_effect_scales[1] <= 1.01 * _SCALE_BOUNDS[1][0]  # REML: no station-to-station error
    nees = float(err @ np.linalg.solve(cov, err))
    assert nees < 13.0  # 25.0 at the estimated scales alone


def test_in_eye_to_hand_the_robots_common_rotation_is_in_the_transforms_uncertainty(arm):
    sol, err, cov, opts = _solve_systematic("eye_to_hand", 13, arm)
    sd_deg = np.degrees(np.sqrt(np.diag(cov)[:3]))
    assert (sd_deg >= opts.robot_accuracy_deg).all()  # it turns the transform whole (0.021 deg about z before)
    z = err / np.sqrt(np.diag(cov))
    assert np.abs(z).max() < 3.0  # -4.1 about z before
    assert float(err @ np.linalg.solve(cov, err)) < 12.0  # 27.2 before
