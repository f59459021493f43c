"""Acceptance figures: known answers, the 0.3 % outlier rule, uncertainties by Monte Carlo,
and the simulated cell with a true and a deliberately wrong calibration."""

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import InputError
from spherecal.core.mapping import frame_from_sensor_stack, map_profile_list, rt_from_poses
from spherecal.core.metrology import (
    MaximumPermissibleErrors,
    ShotNoise,
    acceptance_report,
    fit_plane,
    fit_sphere,
    flatness_error,
    probing_errors,
    probing_size_std_mm,
    sphere_spacing_error,
)
from spherecal.core.models import Pose
from spherecal.sim.cell import NoiseModel, standard_cell
from spherecal.sim.objects import BallBar, FlatPlate
from reference_sensor import reference_fov

CENTRE = np.array([100.0, -50.0, 300.0])


def _cap(n, radius, rng, max_polar_deg=70.0):
    """n points uniformly over a spherical cap around +z."""
    cos_max = np.cos(np.radians(max_polar_deg))
    ct = rng.uniform(cos_max, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    st = np.sqrt(1 - ct**2)
    return np.column_stack([st * np.cos(phi), st * np.sin(phi), ct]) * radius


# known answers --------------------------------------------------------------------------
def test_sphere_fit_recovers_an_exact_cap():
    rng = np.random.default_rng(0)
    pts = CENTRE + _cap(500, 12.5, rng)
    res = probing_errors(pts, certified_diameter_mm=25.0)
    np.testing.assert_allclose(res.fit.centre_mm, CENTRE, atol=1e-9)
    assert res.fit.radius_mm == pytest.approx(12.5, abs=1e-9)
    assert res.probing_form_error_mm < 1e-9 and abs(res.probing_size_error_mm) < 1e-9
    assert (res.fit.n_points_used, res.fit.n_points_dropped) == (500, 0)


def test_outliers_within_the_allowance_are_dropped_and_beyond_it_are_not():
    rng = np.random.default_rng(1)
    sigma = 0.005
    n = 2000  # allowance: floor(0.3 % of 2000) = 6 points
    pts = CENTRE + _cap(n, 10.0, rng) * (1 + rng.normal(0, sigma, (n, 1)) / 10.0)
    bad = pts.copy()
    bad[:4] += [0.0, 0.0, 1.0]  # 4 gross outliers (they lie outside the sphere)
    fit = fit_sphere(bad)
    assert 4 <= fit.n_points_dropped <= 6 and fit.n_points_used == n - fit.n_points_dropped
    assert fit.residual_range_mm < 8 * sigma
    assert fit.radius_mm == pytest.approx(10.0, abs=5 * fit.radius_std_mm + 1e-4)
    # 20 outliers (1 %): only 6 may go, so the form error shows them
    worse = pts.copy()
    worse[:20] += [0.0, 0.0, 1.0]
    fit = fit_sphere(worse)
    assert fit.n_points_dropped == 6
    assert fit.residual_range_mm > 0.5
    # without a threshold the whole allowance is dropped, even from clean data
    assert fit_sphere(pts, outlier_threshold_sigma=None).n_points_dropped == 6
    assert fit_sphere(pts, max_outlier_fraction=0.0).n_points_dropped == 0


def test_reported_sphere_uncertainty_matches_monte_carlo():
    rng = np.random.default_rng(2)
    sigma, runs = 0.01, 200
    radii, centres_z, stds = [], [], []
    for _ in range(runs):
        pts = CENTRE + _cap(150, 12.5, rng) + rng.normal(0, sigma, (150, 3))
        f = fit_sphere(pts, max_outlier_fraction=0.0)
        radii.append(f.radius_mm)
        centres_z.append(f.centre_mm[2])
        stds.append((f.radius_std_mm, f.centre_std_mm[2]))
    mean_std = np.mean(stds, axis=0)
    # the spread of a 200-sample standard deviation is about 5 %; allow 20 %
    assert np.std(radii) == pytest.approx(mean_std[0], rel=0.2)
    assert np.std(centres_z) == pytest.approx(mean_std[1], rel=0.2)
    assert abs(np.mean(radii) - 12.5) < 4 * mean_std[0] / np.sqrt(runs)


def test_plane_fit_and_flatness_known_answer():
    R = geo.matrix_from_rotvec([0.2, -0.4, 0.1])
    u = np.linspace(-50, 50, 10)
    U, V = np.meshgrid(u, u, indexing="ij")
    checker = np.where((np.arange(10)[:, None] + np.arange(10)[None, :]) % 2 == 0, 0.02, -0.02)
    local = np.column_stack([U.ravel(), V.ravel(), checker.ravel()])
    pts = local @ R.T + [10.0, 20.0, 30.0]
    res = flatness_error(pts, max_outlier_fraction=0.0)
    assert res.flatness_error_mm == pytest.approx(0.04, abs=1e-12)
    assert abs(np.dot(res.fit.normal, R[:, 2])) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(res.fit.point_mm, [10.0, 20.0, 30.0], atol=1e-12)


def test_bad_input_is_reported():
    with pytest.raises(InputError, match=r"sphere at P7: expected an \(N, 3\) array"):
        probing_errors(np.zeros((10, 2)), 25.0, position="P7")
    with pytest.raises(InputError, match="sphere: 3 finite points, at least 5 are needed"):
        fit_sphere(np.r_[np.eye(3), np.full((2, 3), np.nan)])
    with pytest.raises(InputError, match="collinear and do not define a plane"):
        fit_plane(np.outer(np.arange(10.0), [1.0, 2.0, 3.0]))
    with pytest.raises(InputError, match="certified_distance_mm must be positive"):
        sphere_spacing_error(np.zeros((5, 3)), np.zeros((5, 3)), 0.0)
    with pytest.raises(InputError, match="do not determine a sphere"):
        fit_sphere(np.column_stack([np.random.default_rng(0).uniform(size=(20, 2)), np.zeros(20)]))


def test_acceptance_report_takes_the_worst_position_and_judges_it():
    rng = np.random.default_rng(3)
    sphere = CENTRE + _cap(300, 12.5, rng)
    p1 = probing_errors(sphere, 25.0, position="P1")
    p2 = probing_errors(sphere * 1.0004 - CENTRE * 0.0004, 25.0, position="P2")  # 0.01 mm larger
    flat = np.column_stack([rng.uniform(-9, 9, (50, 2)), np.zeros(50)])
    flat[0, 2] = 0.05
    f1 = flatness_error(flat, position="F1", max_outlier_fraction=0.0)
    mpe = MaximumPermissibleErrors(probing_form_mm=0.01, probing_size_mm=0.005, flatness_mm=0.1)
    rep = acceptance_report(mpe, probing=[p1, p2], flatness=[f1])
    by = {v.figure: v for v in rep.verdicts}
    assert by["P_S"].worst_position == "P2" and by["P_S"].max_error_mm == pytest.approx(0.01, abs=1e-9)
    assert by["P_S"].passed is False and by["P_F"].passed is True and by["F"].passed is True
    assert by["SD"].passed is None and by["SD"].n_positions == 0
    assert rep.passed is False
    assert acceptance_report(MaximumPermissibleErrors(probing_size_mm=0.02), probing=[p1, p2]).passed is True
    assert acceptance_report(MaximumPermissibleErrors(), probing=[p1]).passed is None


def _line_sweep(radius, line_mm, n_profiles=24, per_profile=200):
    """A pure-translation sweep of a laser line across a sphere at the origin, seen from
    +z: profile k lies in the plane x = x_k (|x_k| up to 0.9 r), its points on the
    circle there facing the sensor (z > 0) and within the line (|y| <= line_mm / 2).
    Returns the points and the profile of each."""
    pts, shot = [], []
    for k, x in enumerate(np.linspace(-0.9 * radius, 0.9 * radius, n_profiles)):
        rho = np.sqrt(radius**2 - x**2)
        half = np.arcsin(min(1.0, line_mm / 2 / rho))
        a = np.linspace(-half, half, per_profile)
        pts.append(np.column_stack([np.full(per_profile, x), rho * np.sin(a), rho * np.cos(a)]))
        shot.append(np.full(per_profile, k))
    return np.vstack(pts), np.concatenate(shot)


@pytest.mark.parametrize("line_mm", [26.0, 40.0])
def test_probing_size_uncertainty_matches_monte_carlo_with_shot_noise(line_mm):
    """Each shot's pose error moves all of its profile's points together. On a 19.1 mm
    sphere swept by a 26 mm line, 0.02 mm of pose noise moves the fitted diameter by
    0.020 mm (1 sigma), twice what it does when the line spans the sphere (0.009 mm),
    and many times what the fit's own uncertainty (independent points) says. The
    predicted spread of P_S matches 300 simulated sweeps, without bias."""
    rng = np.random.default_rng(4)
    ideal, shot = _line_sweep(19.1, line_mm)
    noise = ShotNoise(point_noise_mm=0.01, shot_translation_noise_mm=0.02, shot_rotation_noise_deg=0.002)
    origins = np.column_stack([np.linspace(-17, 17, 24), np.full(24, 5.0), np.full(24, 190.0)])  # the flange
    sizes = []
    for _ in range(300):
        w = np.radians(rng.normal(0, noise.shot_rotation_noise_deg, (24, 3)))
        moved = ideal + rng.normal(0, 0.02, (24, 3))[shot] + np.cross(w[shot], ideal - origins[shot])
        pr = probing_errors(moved + rng.normal(0, 0.01, ideal.shape), 38.2, max_outlier_fraction=0.0)
        sizes.append(pr.probing_size_error_mm)
    predicted = probing_size_std_mm(ideal, pr.fit, shot, noise, origins)
    # the spread of a 300-sample standard deviation is about 4 %; allow 15 %
    assert np.std(sizes) == pytest.approx(predicted, rel=0.15)
    assert abs(np.mean(sizes)) < 4 * predicted / np.sqrt(300)  # no bias from the partial view
    assert predicted > 5 * 2 * pr.fit.radius_std_mm
    assert predicted == pytest.approx({26.0: 0.020, 40.0: 0.009}[line_mm], rel=0.1)
    with_shots = probing_errors(ideal, 38.2, shot_index=shot, noise=noise, shot_origin_mm=origins)
    assert with_shots.probing_size_std_mm == pytest.approx(predicted, rel=0.01) and with_shots.n_shots == 24


def test_p_s_fails_only_when_shown_beyond_its_mpe():
    """ISO 14253-1's rule for proving a specification is not met: P_S fails when it
    exceeds the MPE by more than its expanded uncertainty U = 2 u from the noise; within
    that band it passes, and the verdict carries U. A P_S without an uncertainty is
    judged by the MPE alone."""
    rng = np.random.default_rng(5)
    base = probing_errors(CENTRE + _cap(300, 19.1, rng), 38.2, position="P1")

    def p_s(value, std=None, position="P1"):
        return base.model_copy(update={"probing_size_error_mm": value, "probing_size_std_mm": std,
                                       "position": position})

    mpe = MaximumPermissibleErrors(probing_size_mm=0.06)

    def judged(*results):
        return {v.figure: v for v in acceptance_report(mpe, probing=list(results)).verdicts}["P_S"]

    within = judged(p_s(-0.0726, 0.026))
    assert within.passed is True and within.uncertainty_mm == pytest.approx(0.052)
    assert judged(p_s(-0.0726)).passed is False and judged(p_s(-0.0726)).uncertainty_mm is None
    beyond = judged(p_s(0.05, 0.026, "P1"), p_s(-0.12, 0.026, "P2"))
    assert beyond.passed is False and beyond.worst_position == "P2"
    # the position shown beyond its MPE is the worst, though another's value is larger
    mixed = judged(p_s(0.11, 0.04, "P1"), p_s(0.10, 0.01, "P2"))
    assert mixed.passed is False and mixed.worst_position == "P2" and mixed.max_error_mm == 0.10


def test_probing_size_uncertainty_bad_input():
    fit = fit_sphere(CENTRE + _cap(50, 10.0, np.random.default_rng(6)))
    pts = CENTRE + _cap(50, 10.0, np.random.default_rng(6))
    with pytest.raises(InputError, match=r"shot_index \(49,\) must be"):
        probing_size_std_mm(pts, fit, np.zeros(49, dtype=int), ShotNoise())
    with pytest.raises(InputError, match="shot_origin_mm \\(2, 3\\) needs a row"):
        probing_size_std_mm(pts, fit, np.arange(50) % 5, ShotNoise(shot_rotation_noise_deg=0.01), np.zeros((2, 3)))


# the simulated cell ---------------------------------------------------------------------
SIGMA = 0.01
R_A = np.eye(3)  # sensor orientation relative to base in the first sweep
R_B = geo.matrix_from_rotvec([0.5, 0.0, 0.0])  # and in the second: 29 degrees about base x


@pytest.fixture(scope="module")
def scans():
    """Eye-in-hand cell with a ball bar and a plate; point noise only (independent points),
    so the fits' uncertainties explain the spread. Each scan is a pure-translation sweep."""
    cell = standard_cell("eye_in_hand", seed=7, noise=NoiseModel(point_noise_mm=SIGMA,
                                                                 pose_translation_noise_mm=0.0), fov=reference_fov())
    bar = cell.add_object(BallBar([900.0, -300.0, 300.0], [900.0, -50.0, 300.0], 12.5))
    plate = cell.add_object(FlatPlate(Pose.from_rt(geo.matrix_from_rotvec([0.1, 0.05, 0.0]), [700.0, 300.0, 250.0]), 200.0, 150.0))

    def sweep(target, R, half):
        reported, profiles = cell.scan(cell.sweep_poses(target, "base", R, half, 40))
        return rt_from_poses(reported), profiles

    return {
        "cell": cell,
        "bar": bar,
        "plate": plate,
        "sphere": sweep(cell.sphere_centre_mm, R_A, 18.0),
        "ball_a": sweep(bar.sphere_a.centre_mm, R_A, 11.0),
        "ball_b": sweep(bar.sphere_b.centre_mm, R_B, 11.0),
        "plate_a": sweep(plate.frame_from_plate.translation, R_A, 30.0),
        "plate_b": sweep(plate.frame_from_plate.translation, R_B, 30.0),
    }


def _to_base(scan, flange_from_sensor):
    (Rb, tb), profiles = scan
    R, t = frame_from_sensor_stack("eye_in_hand", Rb, tb, flange_from_sensor)
    return map_profile_list(R, t, profiles)[0]


def _figures(scans, X):
    cell, bar = scans["cell"], scans["bar"]
    probing = probing_errors(_to_base(scans["sphere"], X), 2 * cell.sphere_radius_mm)
    spacing = sphere_spacing_error(_to_base(scans["ball_a"], X), _to_base(scans["ball_b"], X), bar.certified_distance_mm)
    flat = flatness_error(np.vstack([_to_base(scans["plate_a"], X), _to_base(scans["plate_b"], X)]))
    return probing, spacing, flat


def test_true_calibration_figures_are_what_the_noise_explains(scans):
    probing, spacing, flat = _figures(scans, scans["cell"].true_transform)
    fit = probing.fit
    assert fit.n_points_used > 10000 and fit.n_points_dropped <= 0.003 * (fit.n_points_used + fit.n_points_dropped)
    # size and spacing: within 4 standard uncertainties of the fits (point noise only)
    assert abs(probing.probing_size_error_mm) < 4 * 2 * fit.radius_std_mm
    assert abs(spacing.sphere_spacing_error_mm) < 4 * spacing.distance_std_mm
    assert spacing.distance_std_mm < 0.002
    # form and flatness: the range of ~N Gaussian residuals after dropping 0.3 % is about
    # 2 * 2.97 sigma = 5.9 sigma (the radial share of in-plane noise is at most sigma)
    assert 3 * SIGMA < probing.probing_form_error_mm < 7 * SIGMA
    assert 5 * SIGMA < flat.flatness_error_mm < 7 * SIGMA
    assert flat.fit.rms_residual_mm == pytest.approx(SIGMA, rel=0.1)


def test_offset_error_moves_sd_and_f_by_the_predicted_amount(scans):
    X = scans["cell"].true_transform
    # every point of a sweep shifts by R0 dt (R0: that sweep's base_from_flange rotation);
    # sweeps a and b differ in R0 by M. Pick dt (0.42 mm) that shows in both SD and F.
    R0_a = scans["ball_a"][0][0][0]
    R0_b = scans["ball_b"][0][0][0]
    M = R0_b - R0_a
    bar_dir = scans["bar"].sphere_b.centre_mm - scans["bar"].sphere_a.centre_mm
    dt = sum(0.3 * v / np.linalg.norm(v) for v in (M.T @ scans["plate"].normal, M.T @ bar_dir))
    wrong = Pose.from_rt(X.rotation_matrix, X.translation + dt)
    p0, s0, f0 = _figures(scans, X)
    p1, s1, f1 = _figures(scans, wrong)
    centres = np.subtract(s0.fit_b.centre_mm, s0.fit_a.centre_mm)
    predicted_sd = np.linalg.norm(centres + (R0_b - R0_a) @ dt) - np.linalg.norm(centres)
    assert abs(predicted_sd) > 0.05
    assert s1.sphere_spacing_error_mm - s0.sphere_spacing_error_mm == pytest.approx(predicted_sd, abs=1e-6)
    # a rigid shift of a single sweep leaves the sphere's form and size alone
    assert p1.probing_form_error_mm == pytest.approx(p0.probing_form_error_mm, abs=1e-6)
    assert p1.probing_size_error_mm == pytest.approx(p0.probing_size_error_mm, abs=1e-6)
    # the two plate sweeps separate along the normal by n . (R0_b - R0_a) dt: a step
    n = scans["plate"].normal
    step = abs(n @ ((scans["plate_b"][0][0][0] - scans["plate_a"][0][0][0]) @ dt))
    assert step > 0.1
    # two noise bands offset by the step: the range grows by about the step. Compared
    # without outlier dropping: the 3-sigma rule would judge the two bands differently.
    def flat(X):
        pts = np.vstack([_to_base(scans["plate_a"], X), _to_base(scans["plate_b"], X)])
        return flatness_error(pts, max_outlier_fraction=0.0).flatness_error_mm

    f0, f1 = flat(X), flat(wrong)
    assert f0 + 0.8 * step < f1 < f0 + 1.1 * step


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rotation_error_shows_in_form_as_predicted(scans, axis):
    """A rotation error delta about sensor y or z shears the swept sphere (x gains delta*z
    or -delta*y): the cloud becomes an ellipsoid with semi-axes r(1 +- delta/2), so P_F
    grows by up to about r*delta. About sensor x (the laser plane's normal) a
    pure-translation sweep is only rotated rigidly: P_F and P_S do not see it."""
    X = scans["cell"].true_transform
    delta = np.radians(1.0)
    rv = np.zeros(3)
    rv[axis] = delta
    wrong = Pose.from_rt(X.rotation_matrix @ geo.matrix_from_rotvec(rv), X.translation)
    r = scans["cell"].sphere_radius_mm
    p0 = probing_errors(_to_base(scans["sphere"], X), 2 * r)
    p1 = probing_errors(_to_base(scans["sphere"], wrong), 2 * r)
    growth = p1.probing_form_error_mm - p0.probing_form_error_mm
    if axis == 0:
        assert abs(growth) < 1e-6 and abs(p1.probing_size_error_mm - p0.probing_size_error_mm) < 1e-6
    else:
        assert 0.5 * r * delta < growth < 1.1 * r * delta
        # the shear keeps the volume: the size moves much less than the form
        assert abs(p1.probing_size_error_mm - p0.probing_size_error_mm) < 0.2 * r * delta
