"""The REML search of the robot-error scales (station offsets' spread, the kinematic
prior's factor) uses exact gradients and stops at rounding level: the scales, and the
transform through them, are a smooth function of the data. Exact, because a
finite-difference search stops anywhere within about 1e-7: Gauss-Newton around that
jitter does not settle, and a scale that falls to its floor stays there (5 of 40 centre
solves in a world with systematic robot error come back RED, "did not converge")."""

from __future__ import annotations

import numpy as np
import pytest
from reference_sensor import reference_fov

from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation import refine as rf


def _problem(rng, M=400, p=9, q=12):
    Jt = rng.normal(size=(M, p))
    Jd = rng.normal(size=(M, q)) * rng.uniform(0.2, 3.0, size=q)
    y = rng.normal(size=M) + Jd @ rng.normal(scale=0.3, size=q)
    return Jt, Jd, y


def _blocks(rng, M=400, p=9, q=12):
    Jt, Jd, y = _problem(rng, M, p, q)
    return Jt.T @ Jt, Jt.T @ Jd, Jd.T @ Jd, Jt.T @ y, Jd.T @ y, float(y @ y)


def _dense_neg2_reml(Jt, Jd, y, sd):
    """-2 REML from its definition, with the (M, M) marginal covariance V = I + J_d D^2 J_d^T:
    log det V + log det X^T V^-1 X + y^T P y."""
    V = np.eye(len(y)) + Jd @ np.diag(sd**2) @ Jd.T
    Vi = np.linalg.inv(V)
    XVX = Jt.T @ Vi @ Jt
    P = Vi - Vi @ Jt @ np.linalg.solve(XVX, Jt.T @ Vi)
    return np.linalg.slogdet(V)[1] + np.linalg.slogdet(XVX)[1] + y @ P @ y


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_value_is_the_reml_of_its_definition_and_its_derivatives_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    Jt, Jd, y = _problem(rng)
    blocks = Jt.T @ Jt, Jt.T @ Jd, Jd.T @ Jd, Jt.T @ y, Jd.T @ y, float(y @ y)
    group = rng.integers(0, 3, size=12)
    x = np.log(rng.uniform(0.05, 2.0, size=3))

    def f(x_):
        return rf._neg2_reml_derivatives(np.exp(x_)[group], group, 3, *blocks)

    value, grad, hess = f(x)
    assert value == pytest.approx(_dense_neg2_reml(Jt, Jd, y, np.exp(x)[group]), rel=1e-10)
    h = 1e-5
    for g in range(3):
        e = np.zeros(3)
        e[g] = h
        plus, minus = f(x + e), f(x - e)
        assert grad[g] == pytest.approx((plus[0] - minus[0]) / (2 * h), rel=1e-6, abs=1e-6)
        np.testing.assert_allclose(hess[:, g], (plus[1] - minus[1]) / (2 * h), rtol=1e-5, atol=1e-6)


def test_gradient_vanishes_as_a_scale_goes_to_zero():
    """Near its floor a scale's gradient is of the order of sigma^2, even where the data
    ask for the effect (here they hold one): why the search also starts from the first
    scales (a scale at its floor could not leave it from there alone)."""
    blocks = _blocks(np.random.default_rng(3))
    group = np.repeat([0, 1], 6)
    _, g_small, _ = rf._neg2_reml_derivatives(np.array([1e-6] * 6 + [0.5] * 6), group, 2, *blocks)
    _, g_big, _ = rf._neg2_reml_derivatives(np.array([0.5] * 12), group, 2, *blocks)
    assert g_small[0] < 0 and abs(g_small[0]) < 1e-6 * abs(g_big[0])


def test_station_model_results_do_not_depend_on_the_order_of_the_observations():
    """The same shots in the reverse order: the same transform and covariance to
    1e-10 (the finite-difference search gave 1.7e-7 and 1.2e-6 here)."""
    from spherecal.sim import NoiseModel, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    ds = simulate_dataset(standard_cell("eye_in_hand", seed=5, noise=noise, fov=reference_fov()),
                          SweepPlan(profiles_per_station=6))
    reverse = ds.model_copy(update={"observations": list(reversed(ds.observations))})
    opts = CalibrationOptions(robot_error_model="station")
    a, b = solve(ds, opts).result, solve(reverse, opts).result
    ta = np.array([*a.transform.translation_mm, *a.transform.quaternion_wxyz])
    tb = np.array([*b.transform.translation_mm, *b.transform.quaternion_wxyz])
    np.testing.assert_allclose(tb, ta, rtol=1e-10, atol=1e-12)
    ca, cb = np.array(a.covariance), np.array(b.covariance)
    np.testing.assert_allclose(cb, ca, atol=1e-10 * np.abs(ca).max())


@pytest.mark.parametrize("mounting, seed, way", [("eye_in_hand", 4, "spheres"), ("eye_to_hand", 0, "circles")])
def test_station_model_on_centres_converges_with_systematic_robot_error(mounting, seed, way):
    """Two of the five solves of ``bench_centres.py --robot-error-model station --world
    systematic`` that hit the iteration cap: they converge, and the answer is as near
    the truth as the arm's geometric error allows (0.5-2 mm at the flange)."""
    from spherecal.core import geometry as geo
    from spherecal.estimation.centres import circles_from_profiles
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    arm = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell(mounting, seed=seed, noise=noise, fov=reference_fov(), robot_error=RobotErrorModel(), arm=arm)
    profiles = simulate_dataset(cell, SweepPlan(profiles_per_station=8))
    ds = circles_from_profiles(profiles)
    if way == "spheres":  # each circle resolved to the sphere centre on the true side of the plane
        pose = {o.index: o.base_from_flange for o in profiles.observations}
        r = ds.sphere_radius_mm
        ds = ds.model_copy(update={"observations": [o.model_copy(update={"circle": None, "sphere_centre_mm": (
            float(np.copysign(np.sqrt(max(r * r - o.circle.radius_mm**2, 0.0)),
                              cell.sphere_centre_in_sensor(pose[o.index])[0])), *o.circle.centre_yz_mm)})
            for o in ds.observations]})
    sol = solve(ds, CalibrationOptions(robot_error_model="station"))
    assert sol.refined.converged
    X = cell.true_transform
    rot_err = geo.rotvec_from_matrix(sol.result.transform.rotation_matrix @ X.rotation_matrix.T)
    assert np.degrees(np.linalg.norm(rot_err)) < 0.3
    assert np.linalg.norm(np.asarray(sol.result.transform.translation) - X.translation) < 2.5


@pytest.mark.slow
def test_kinematic_model_covariance_does_not_depend_on_the_order_of_the_observations():
    """The transform's covariance with the arm's parameters marginalised, from the joint
    normal matrix: the same shots in reverse order agree to 1e-9 of its largest element
    (the difference of large terms it was computed as moved by 1.1e-7)."""
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import NoiseModel, RobotErrorModel, SweepPlan, simulate_dataset, standard_cell

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=6, noise=noise, robot_error=RobotErrorModel(), arm=kin, fov=reference_fov())
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=4))
    reverse = ds.model_copy(update={"observations": list(reversed(ds.observations))})
    opts = CalibrationOptions(robot_error_model="kinematic")
    a = np.array(solve(ds, opts, kinematics=kin).result.covariance)
    b = np.array(solve(reverse, opts, kinematics=kin).result.covariance)
    np.testing.assert_allclose(b, a, atol=1e-9 * np.abs(a).max())


def _variance_components(a, b):
    """-2 log-likelihood of independent variance components in log-scale x: sum over i
    of log(a_i + e^{2 x_i}) + b_i / (a_i + e^{2 x_i}), with its exact gradient and
    Hessian. Its minimum is at e^{2 x_i} = b_i - a_i where b_i > a_i, and at zero
    variance (the floor, flat like sigma^2) where b_i <= a_i."""
    a, b = np.asarray(a, float), np.asarray(b, float)

    def evaluate(x):
        v = np.exp(2.0 * x)
        s = a + v
        f = np.sum(np.log(s) + b / s)
        df_dv = 1.0 / s - b / s**2
        d2f_dv2 = -1.0 / s**2 + 2.0 * b / s**3
        grad = df_dv * 2.0 * v
        hess = np.diag(d2f_dv2 * (2.0 * v) ** 2 + df_dv * 4.0 * v)
        return f, grad, hess

    return evaluate


def test_search_reaches_an_interior_scale_and_a_floor_together_in_few_evaluations():
    """One scale's optimum inside the box, the other's at its floor (the common case of
    the station model: one kind of station offset is not in the data), from a start
    above both. The floor tried for both scales together overshoots the first, and the
    floor is flat: the search stopped there, at the wrong scales (it did from this start
    before the floors were also tried each alone). Tried alone, the second goes to its
    floor and the first is left to Newton's steps."""
    evaluate = _variance_components([1.0, 1.0], [1.5, 0.5])  # optimum: v = (0.5, 0)
    calls = []

    def counted(x):
        calls.append(np.array(x))
        return evaluate(x)

    lower, upper = np.log([1e-4, 1e-4]), np.log([100.0, 100.0])
    x, f = rf._reml_search(counted, np.log([1.5, 1.5]), lower, upper)
    assert x[1] == pytest.approx(lower[1])  # at its floor exactly
    assert np.exp(2.0 * x[0]) == pytest.approx(0.5, rel=1e-6)
    assert f == pytest.approx(evaluate(np.array([0.5 * np.log(0.5), lower[1]]))[0], abs=1e-12)
    assert len(calls) <= 12, f"{len(calls)} evaluations"
