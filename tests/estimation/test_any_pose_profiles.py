"""Raw profiles and circles at orientations of their own (an ordinary hand-eye log): the
side of the laser plane of each sphere centre decided from a nominal transform a few
degrees and millimetres off, or from the circles alone; refused when they do not decide
it. Known answers from the simulated cell in both mountings."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.core.models import Circle, Pose
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.linear_start import MIN_SIDE_FREE_ROWS, side_free_sides, sides_and_offset
from spherecal.estimation.problem import build_problem
from spherecal.sim import NoiseModel, simulate_general_dataset, standard_cell
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
EXACT = NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0, pose_rotation_noise_deg=0.0)
#: chi^2 with 6 degrees of freedom exceeded with probability 1e-4
CHI2_6_1E4 = 27.86


def off_by(X: Pose, deg: float, mm: float, seed: int = 0) -> Pose:
    """``X`` turned by ``deg`` about a random axis and moved ``mm`` along a random direction."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=3), rng.normal(size=3)
    R = geo.matrix_from_rotvec(np.radians(deg) * a / np.linalg.norm(a)) @ X.rotation_matrix
    return Pose.from_rt(R, X.translation + mm * b / np.linalg.norm(b))


def check_known_answer(res, cell, rot_deg=0.1, trans_mm=0.1):
    X = cell.true_transform
    w = geo.rotvec_from_matrix(res.transform.rotation_matrix @ X.rotation_matrix.T)
    e = np.concatenate([w, res.transform.translation - X.translation])
    chi2 = float(e @ np.linalg.solve(np.array(res.covariance)[:6, :6], e))
    rot, trans = float(np.degrees(np.linalg.norm(w))), float(np.linalg.norm(e[3:]))
    assert rot < rot_deg and trans < trans_mm and chi2 < CHI2_6_1E4, (rot, trans, chi2)


@pytest.mark.parametrize("deg, mm", [(5.0, 10.0), (15.0, 30.0)])
def test_profiles_at_their_own_orientations_solve_from_a_rough_nominal(mounting, deg, mm):
    """Forty profiles, each at its own orientation, and a nominal transform 5 deg and 10
    mm off (and 15 deg and 30 mm: the basin is wider than a CAD or hand-measured
    nominal needs): the known answer within the stated uncertainty, no profile left out."""
    cell = standard_cell(mounting, seed=1, noise=NOISE, fov=reference_fov())
    ds = simulate_general_dataset(cell, 40, kind="profile", plan_seed=1)
    res = solve(ds, CalibrationOptions(nominal_transform=off_by(cell.true_transform, deg, mm))).result
    check_known_answer(res, cell)
    start = res.diagnostics.start
    assert start["method"] == "linear" and start["sides_from"] == "nominal" and start["sides_decided"] == 40
    assert res.flagged == [] and res.residuals.n_profiles_used == 40


@pytest.mark.parametrize("kind", ["profile", "circle"])
def test_profiles_and_circles_at_their_own_orientations_solve_without_a_nominal(mounting, kind):
    """Without a nominal the circles alone decide the sides (their side-free equations
    fix one solution, and one choice of the sides fits decisively better)."""
    cell = standard_cell(mounting, seed=2, noise=NOISE, fov=reference_fov())
    ds = simulate_general_dataset(cell, 40, kind=kind, plan_seed=2, centre_noise_mm=0.02)
    res = solve(ds).result
    check_known_answer(res, cell)
    start = res.diagnostics.start
    assert start["sides_from"] == "circles alone" and start["side_free_gap"] < 0.1 and start["margin_chi2"] > 1e3
    assert res.flagged == []


def one_distance_from_the_laser_plane(n: int, x_mm: float = 5.0):
    """Exact circles of rows at orientations of their own, the robot having put the
    sphere centre ``x_mm`` in front of the laser plane in every row: the circles are those
    of the sphere ``x_mm`` behind it with the translation moved by 2 x_mm along the
    plane's normal, so nothing but a nominal tells the two apart."""
    cell = standard_cell("eye_in_hand", seed=5, noise=EXACT, fov=reference_fov())
    ds = simulate_general_dataset(cell, n, kind="sphere_centre", centre_noise_mm=0.0, plan_seed=5)
    X, r = cell.true_transform, cell.sphere_radius_mm
    rows = []
    for o in ds.observations:
        C = np.array([x_mm, *o.sphere_centre_mm[1:]])
        F = o.base_from_flange  # move the flange so that the sphere centre is at C in the sensor frame
        shift = cell.sphere_centre_mm - F.apply(X.apply(C))
        F = Pose.from_rt(F.rotation_matrix, F.translation + shift)
        rows.append(o.model_copy(update={"sphere_centre_mm": None, "base_from_flange": F, "circle": Circle(
            centre_yz_mm=tuple(float(v) for v in C[1:]), radius_mm=float(np.sqrt(r * r - x_mm**2)))}))
    return ds.model_copy(update={"observations": rows}), cell


def test_circles_at_one_distance_from_the_laser_plane_are_refused_without_a_nominal_and_solved_with_one():
    ds, cell = one_distance_from_the_laser_plane(20)
    with pytest.raises(DegenerateDataError) as caught:
        solve(ds)
    said = str(caught.value)
    assert "Nor can the start from any orientations solve it: the circles do not fix one solution without a " \
           "nominal transform" in said, said
    assert "give a nominal transform" in said and "at other distances on both sides of the laser plane" in said
    # the two solutions lie 10 mm apart: a nominal 10 mm off cannot tell them apart, one 1 mm off can
    with pytest.raises(DegenerateDataError, match=r"two choices of the sides of the laser plane fit the circles "
                                                  r"alike, the translation 10\.00 mm apart .* too far to tell"):
        solve(ds, CalibrationOptions(nominal_transform=off_by(cell.true_transform, 5.0, 10.0)))
    res = solve(ds, CalibrationOptions(nominal_transform=off_by(cell.true_transform, 5.0, 1.0))).result
    check_known_answer(res, cell, 0.01, 0.01)
    assert res.diagnostics.start["twin"]["apart_mm"] == pytest.approx(10.0, abs=0.01)


def test_too_few_circle_rows_without_a_nominal_are_refused_with_the_count():
    cell = standard_cell("eye_in_hand", seed=2, noise=NOISE, fov=reference_fov())
    ds = simulate_general_dataset(cell, MIN_SIDE_FREE_ROWS - 1, kind="circle", plan_seed=2)
    with pytest.raises(DegenerateDataError, match=rf"{MIN_SIDE_FREE_ROWS - 1} circle row\(s\) at orientations of "
                                                  rf"their own: without a nominal transform the sides of the laser "
                                                  rf"plane need at least {MIN_SIDE_FREE_ROWS}"):
        solve(ds)
    res = solve(ds, CalibrationOptions(nominal_transform=off_by(cell.true_transform, 5.0, 10.0))).result
    check_known_answer(res, cell, 0.3, 0.3)


def test_the_side_free_equations_give_the_sides_of_exact_circles(mounting):
    cell = standard_cell(mounting, seed=3, noise=EXACT, fov=reference_fov())
    ds = simulate_general_dataset(cell, 15, kind="sphere_centre", centre_noise_mm=0.0, plan_seed=3)
    p = build_problem(ds)
    C = p.centre_meas
    x, figures = side_free_sides(p.R_sphere_from_mount, p.t_sphere_from_mount, C[:, 1:], np.abs(C[:, 0]))
    np.testing.assert_allclose(x, C[:, 0], atol=1e-6)
    assert figures["side_free_gap"] < 1e-6 and figures["margin_chi2"] > 1e3


def test_sides_and_offset_finds_the_offset_and_says_when_two_fit_alike():
    h = np.array([3.0, 7.0, 1.0, 12.0, 5.0])
    x = np.array([3.0, -7.0, 1.0, 12.0, -5.0])
    got, alpha, figures = sides_and_offset(x + 40.0, h)
    np.testing.assert_allclose(got, x)
    assert alpha == pytest.approx(40.0) and figures["margin_chi2"] > 1e3
    _, _, alike = sides_and_offset(np.full(5, 45.0), np.full(5, 5.0))  # +5 at 40 or -5 at 50
    assert alike["margin_chi2"] < 1.0 and {round(alike["offset_mm"]), round(alike["other_offset_mm"])} == {40, 50}


def test_a_profile_left_out_by_the_joint_fit_leaves_the_other_rows_at_their_own_orientations():
    """A pose 0.4 mm off (read at another moment): the joint fit leaves its profile out
    and solves the others; each row is a station of one, and none is left out for being
    a thin station."""
    cell = standard_cell("eye_in_hand", seed=1, noise=NOISE, fov=reference_fov())
    ds = simulate_general_dataset(cell, 40, kind="profile", plan_seed=1)
    obs = list(ds.observations)
    F = obs[7].base_from_flange
    obs[7] = obs[7].model_copy(update={"base_from_flange": Pose.from_rt(F.rotation_matrix,
                                                                        F.translation + [0.0, 0.4, 0.0])})
    res = solve(ds.model_copy(update={"observations": obs})).result
    assert [f.index for f in res.flagged] == [7], res.flagged
    assert "inconsistent with the other profiles" in res.flagged[0].reason
    check_known_answer(res, cell)
    assert res.residuals.n_profiles_used == 39
