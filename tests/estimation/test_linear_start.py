"""The closed-form start from sphere centres at any orientations (estimation.linear_start)
and the solve built on it: known answers from the simulated cell in both mountings, what
the data need said up front, and the comparison with the two-step on station data."""

from __future__ import annotations

import re

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.any_poses import beside_the_linear_start
from spherecal.estimation.linear_start import MIN_ROWS, centres_start
from spherecal.estimation.problem import build_problem
from spherecal.sim import NoiseModel, SweepPlan, simulate_centre_dataset, simulate_general_dataset, standard_cell
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
EXACT = NoiseModel(point_noise_mm=0.0, pose_translation_noise_mm=0.0, pose_rotation_noise_deg=0.0)
#: chi^2 with 6 degrees of freedom exceeded with probability 1e-4
CHI2_6_1E4 = 27.86


def general_table(mounting: str, noise=NOISE, n: int = 30, seed: int = 3, centre_noise_mm: float = 0.02):
    cell = standard_cell(mounting, seed=seed, noise=noise, fov=reference_fov())
    ds = simulate_general_dataset(cell, n, kind="sphere_centre", centre_noise_mm=centre_noise_mm, plan_seed=seed)
    return ds, cell


def start_of(ds):
    p = build_problem(ds)
    return centres_start(p.R_sphere_from_mount, p.t_sphere_from_mount, p.centre_meas)


def errors(R, t, cell):
    X = cell.true_transform
    return geo.rotation_angle_deg(R, X.rotation_matrix), float(np.linalg.norm(t - X.translation))


def chi2_of(result, cell) -> float:
    X = cell.true_transform
    w = geo.rotvec_from_matrix(result.transform.rotation_matrix @ X.rotation_matrix.T)
    e = np.concatenate([w, result.transform.translation - X.translation])
    return float(e @ np.linalg.solve(np.array(result.covariance)[:6, :6], e))


# --- the start itself ----------------------------------------------------------------------------
def test_exact_centres_at_any_orientations_give_the_exact_transform(mounting):
    """Both mountings are one equation: from exact centres the start is the truth (to
    rounding), the sphere centre too."""
    ds, cell = general_table(mounting, EXACT, n=12, centre_noise_mm=0.0)
    start = start_of(ds)
    rot, trans = errors(start.R, start.t, cell)
    assert rot < 1e-8 and trans < 1e-7, (rot, trans)
    assert np.allclose(start.centre, cell.sphere_centre_mm, atol=1e-7)
    assert start.diagnostics["rms_mm"] < 1e-8


def test_noisy_centres_give_a_start_near_the_truth(mounting):
    ds, cell = general_table(mounting)
    start = start_of(ds)
    rot, trans = errors(start.R, start.t, cell)
    assert rot < 0.1 and trans < 0.2, (rot, trans)
    assert start.diagnostics["rows"] == 30 and 0.01 < start.diagnostics["rms_mm"] < 0.1


def test_fewer_than_five_rows_are_refused_with_the_count():
    ds, _ = general_table("eye_in_hand", n=4)
    with pytest.raises(DegenerateDataError, match=rf"4 row\(s\) with a sphere centre: the start from any "
                                                  rf"orientations needs at least {MIN_ROWS} \(15 unknowns"):
        start_of(ds)


def test_centres_along_one_line_of_the_sensor_frame_leave_the_rotation_undetermined():
    """The robot's orientations alone give only where the sphere sits on the flange: the
    rotation needs the centre at places of the sensor frame spanning a plane."""
    ds, _ = general_table("eye_in_hand", EXACT, n=10, centre_noise_mm=0.0)
    p = build_problem(ds)
    C = p.centre_meas.copy()
    C[:, 1:] = C[0, 1:]  # every centre on one line along the sensor's x
    with pytest.raises(DegenerateDataError, match=r"the sphere centre is along one line \(about \[-?1\.0, -?0\.0, "
                                                  r"-?0\.0\]\) of the sensor frame in every row .* the rotation is "
                                                  r"not determined.*add rows with the sphere elsewhere"):
        centres_start(p.R_sphere_from_mount, p.t_sphere_from_mount, C)
    C[:, 0] = C[0, 0]
    with pytest.raises(DegenerateDataError, match="the sphere centre is at one place of the sensor frame"):
        centres_start(p.R_sphere_from_mount, p.t_sphere_from_mount, C)


def test_centres_in_one_plane_of_the_sensor_frame_are_enough():
    """Sphere centres all at one distance from the laser plane (in one plane of the sensor
    frame) still determine the rotation: its third column is the cross product."""
    ds, cell = general_table("eye_in_hand", EXACT, n=10, centre_noise_mm=0.0)
    p = build_problem(ds)
    R_A, t_A, X = p.R_sphere_from_mount, p.t_sphere_from_mount, cell.true_transform
    C = p.centre_meas.copy()
    C[:, 0] = 5.0  # move each shot's sphere so that its centre is 5 mm in front of the laser plane
    centres = np.einsum("nij,nj->ni", R_A, C @ X.rotation_matrix.T + X.translation) + t_A
    t_A = t_A + (cell.sphere_centre_mm - centres)  # the robot put it there
    start = centres_start(R_A, t_A, C)
    rot, trans = errors(start.R, start.t, cell)
    assert rot < 1e-8 and trans < 1e-7 and start.diagnostics["centre_spread_mm"][2] < 1e-9


def test_orientations_about_one_axis_leave_a_translation_component_free_and_say_what_to_add():
    ds, _ = general_table("eye_in_hand", EXACT, n=10, centre_noise_mm=0.0)
    p = build_problem(ds)
    axis = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    R_A = geo.matrix_from_rotvec(np.outer(np.linspace(-0.3, 0.3, 10), axis)) @ p.R_sphere_from_mount[0]
    with pytest.raises(DegenerateDataError, match=r"the rows' orientations differ only by rotations about one axis "
                                                  r"\(about \[-?0\.3\d*, -?0\.2\d*, -?0\.9\d*\] in the sphere frame.*"
                                                  r"add rows rotated about a second axis"):
        centres_start(R_A, p.t_sphere_from_mount, p.centre_meas)
    with pytest.raises(DegenerateDataError, match=r"all 10 rows are at about one orientation .* add rows at other "
                                                  r"orientations, tilted about two different axes"):
        centres_start(np.broadcast_to(R_A[0], R_A.shape), p.t_sphere_from_mount, p.centre_meas)


# --- the solve ------------------------------------------------------------------------------------
@pytest.mark.parametrize("labels", ["own", "one"])
def test_a_table_of_centres_each_at_its_own_orientation_is_solved(mounting, labels):
    """Thirty sphere centres, each row its own orientation (tilts up to 20 deg), each row
    its own station or all under one label: refused before, now the transform within its
    stated uncertainty; the result says which start it took and names no row."""
    ds, cell = general_table(mounting)
    if labels == "one":
        ds = ds.model_copy(update={"observations": [o.model_copy(update={"station": "S1"}) for o in ds.observations]})
    res = solve(ds).result
    rot, trans = errors(res.transform.rotation_matrix, res.transform.translation, cell)
    assert rot < 0.1 and trans < 0.1, (rot, trans)
    assert chi2_of(res, cell) < CHI2_6_1E4
    assert np.linalg.norm(np.subtract(res.sphere_centre_mm, cell.sphere_centre_mm)) < 0.2
    assert res.flagged == [] and res.residuals.n_centres_used == 30
    start = res.diagnostics.start
    assert start["method"] == "linear" and start["rows"] == 30 and res.method.startswith("closed-form linear start")
    assert res.two_step_transform is None and res.diagnostics.two_step is None
    assert start["vs_refined"]["rotation_deg"] < 0.05


@pytest.mark.parametrize("component", [1, 2])
def test_a_row_with_a_typo_among_rows_at_their_own_orientations_is_named_with_its_size(component):
    """A sign flipped in one sphere centre's y (2.5 mm off) or z (27 mm off): the row is
    left out and named with the size of its error in mm (by the start when gross, else by
    the joint fit's chi^2), and the rest give the known answer."""
    ds, cell = general_table("eye_in_hand")
    obs = list(ds.observations)
    centre = list(obs[11].sphere_centre_mm)
    off = 2 * abs(centre[component])
    centre[component] = -centre[component]
    obs[11] = obs[11].model_copy(update={"sphere_centre_mm": tuple(centre)})
    res = solve(ds.model_copy(update={"observations": obs})).result
    assert [f.index for f in res.flagged] == [11], res.flagged
    size = float(re.search(r"its sphere centre is (\d+\.\d+) mm (?:off where the start from any orientations puts "
                           r"it|from where the fit puts it)", res.flagged[0].reason).group(1))
    assert abs(size - off) < 0.3 * off, (size, off, res.flagged[0].reason)
    rot, trans = errors(res.transform.rotation_matrix, res.transform.translation, cell)
    assert rot < 0.1 and trans < 0.1


def test_on_station_data_both_starts_apply_and_agree_within_the_stated_uncertainty(mounting):
    """Station data: the two-step starts the fit, as before; the start from any
    orientations, from the same centres, lies within the result's stated uncertainty."""
    cell = standard_cell(mounting, seed=7, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), centre_noise_mm=0.02)
    res = solve(ds, CalibrationOptions(robot_error_model="none")).result
    start = res.diagnostics.start
    assert start["method"] == "two-step" and res.two_step_transform is not None
    linear = start["linear"]
    assert linear["agree"] and linear["linear_vs_refined"]["chi2_6dof"] < CHI2_6_1E4, linear
    assert linear["linear_vs_two_step"]["rotation_deg"] < 0.3 and linear["linear_rows"] == len(ds.observations)


class _Solution:
    def __init__(self, R, t, scale=1.0):
        self.R, self.t, self.pose_noise_scale = R, np.asarray(t, float), scale
        self.covariance = np.diag([1e-8] * 3 + [1e-4] * 3)


class _Start:
    def __init__(self, R, t):
        self.R, self.t, self.centre, self.diagnostics = R, np.asarray(t, float), np.zeros(3), {"rows": 20}


@pytest.mark.parametrize("linear_fits_better", [True, False])
def test_starts_that_disagree_are_both_refined_and_the_better_fit_kept(linear_fits_better):
    """When the linear start lies beyond the stated uncertainty of the two-step's
    result, the fit is refined from it too and the solution with the lower -2
    log-likelihood is kept, at both solutions' noise."""
    R0, R1 = np.eye(3), geo.matrix_from_rotvec([0.0, 0.0, np.radians(2.0)])
    ts, ref, other = _Start(R0, [0, 0, 0]), _Solution(R0, [0, 0, 0]), _Solution(R1, [1, 0, 0], 2.0)
    costs = {id(ref): 100.0, id(other): 50.0 if linear_fits_better else 150.0}
    kept, compared = beside_the_linear_start(None, ts, ref, _Start(R1, [1, 0, 0]), lambda clean, start: other,
                                             lambda r, scale: costs[id(r)], lambda msg: None)
    assert not compared["agree"] and compared["refined_from_linear"]["rotation_deg"] == pytest.approx(2.0)
    assert kept is (other if linear_fits_better else ref)
    assert compared["chosen"] == ("linear" if linear_fits_better else "two-step")


def test_a_linear_start_far_from_the_result_is_advised_on_as_the_two_step_is():
    """The advice that a start and the refinement disagree reads the linear start's
    distance when the fit started from it (the two-step's figures are then absent)."""
    from spherecal.report.assess import advice

    ds, _ = general_table("eye_in_hand")
    res = solve(ds).result
    assert not [a for a in advice(res) if a.key == "start_disagrees"]
    start = {**res.diagnostics.start, "vs_refined": {"rotation_deg": 0.8, "translation_mm": 0.1}}
    far = res.model_copy(update={"diagnostics": res.diagnostics.model_copy(update={"start": start})})
    said = [a for a in advice(far) if a.key == "start_disagrees"]
    assert len(said) == 1 and said[0].title == "Linear start and refinement disagree", said


def test_the_file_formats_say_what_each_start_needs():
    """docs/file-formats.md states the figures the code checks: the start from any
    orientations' minimum rows, the default rows of a station of profiles."""
    from pathlib import Path

    from spherecal.estimation import CalibrationOptions

    doc = (Path(__file__).resolve().parents[2] / "docs" / "file-formats.md").read_text(encoding="utf-8")
    needs = doc[doc.index("### What the data need"):]
    assert f"At least **{MIN_ROWS} rows**" in needs
    assert f"`min_profiles_per_station` ({CalibrationOptions().min_profiles_per_station} by default)" in needs
    assert "rotations about at least two different axes" in needs and "span a plane" in needs
