"""Calibration from centre observations (circles fitted on board, sphere centres already
resolved), alone or beside profiles: known answers from the simulated cell in both
mounting modes, the paper's minimal procedure, the checks of hand-typed tables."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.io.dataset import read_dataset, write_dataset
from spherecal.core.errors import DatasetFileError, DegenerateDataError
from spherecal.estimation import CalibrationOptions, solve
from spherecal.estimation.centres import circles_from_profiles
from spherecal.core.models import Circle, Dataset, Pose
from spherecal.sim import NoiseModel, SweepPlan, simulate_centre_dataset, simulate_dataset, standard_cell
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
#: chi^2 with 6 degrees of freedom exceeded with probability 1e-4
CHI2_6_1E4 = 27.86


def transform_error(result, cell):
    """(rotation angle deg, translation mm, chi^2 of the 6-dof error against the result's covariance)."""
    X = cell.true_transform
    w = geo.rotvec_from_matrix(result.transform.rotation_matrix @ X.rotation_matrix.T)
    e = np.concatenate([w, result.transform.translation - X.translation])
    chi2 = float(e @ np.linalg.solve(np.array(result.covariance)[:6, :6], e))
    return float(np.degrees(np.linalg.norm(w))), float(np.linalg.norm(e[3:])), chi2


def assert_known_answer(result, cell, rot_deg=0.15, trans_mm=0.2, centre_mm=0.5):
    rot, trans, chi2 = transform_error(result, cell)
    assert rot < rot_deg and trans < trans_mm, (rot, trans)
    assert chi2 < CHI2_6_1E4, f"error {rot:.4f} deg, {trans:.4f} mm is not within the stated covariance (chi2 {chi2:.1f})"
    assert np.linalg.norm(np.subtract(result.sphere_centre_mm, cell.sphere_centre_mm)) < centre_mm


def sphere_centres_from_fits(dataset: Dataset, cell) -> Dataset:
    """Circles fitted to simulated profiles, resolved to sphere centres with the side of
    the laser plane a sensor that resolves it would report (here: the truth's)."""
    circles = circles_from_profiles(dataset)
    r = dataset.sphere_radius_mm
    truth = {o.index: o for o in dataset.observations}
    out = []
    for o in circles.observations:
        c = o.circle
        # the reported pose is off the true one by the pose noise only: the side is the true side
        true_x = cell.sphere_centre_in_sensor(truth[o.index].base_from_flange)[0]
        x = np.copysign(np.sqrt(max(r * r - c.radius_mm**2, 0.0)), true_x)
        out.append(o.model_copy(update={"circle": None, "sphere_centre_mm": (float(x), *c.centre_yz_mm)}))
    return circles.model_copy(update={"observations": out})


# --- known answers ---------------------------------------------------------------------------------
def test_fitted_circles_of_simulated_profiles_give_the_known_answer(mounting):
    cell = standard_cell(mounting, seed=4, noise=NOISE, fov=reference_fov())
    profiles = simulate_dataset(cell, SweepPlan(profiles_per_station=6))
    circles = circles_from_profiles(profiles)
    assert all(o.kind == "circle" for o in circles.observations) and len(circles.observations) >= 20
    res = solve(circles, CalibrationOptions(robot_error_model="none")).result
    assert_known_answer(res, cell)
    assert res.residuals.n_centres_used == len(circles.observations) and res.residuals.n_profiles_used == 0
    assert res.residuals.n_points_used == 0 and not res.flagged
    # the same shots resolved to sphere centres
    spheres = sphere_centres_from_fits(profiles, cell)
    res2 = solve(spheres, CalibrationOptions(robot_error_model="none")).result
    assert_known_answer(res2, cell)


@pytest.mark.parametrize("kind", ["sphere_centre", "circle"])
@pytest.mark.parametrize("given", [False, True], ids=["estimated-noise", "given-noise"])
def test_centres_from_the_true_geometry_plus_noise_give_the_known_answer(mounting, kind, given):
    cell = standard_cell(mounting, seed=7, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind, centre_noise_mm=0.03,
                                 give_covariance=given)
    sol = solve(ds, CalibrationOptions(robot_error_model="none"))
    res = sol.result
    assert_known_answer(res, cell)
    est = res.diagnostics.noise["centre_noise_mm"]
    if given:
        assert est is None
    else:  # the variance component finds the centres' noise (pose noise apart)
        assert 0.02 < est < 0.045, est
    # the pure-translation consistency per station, on centres
    cons = res.diagnostics.station_consistency
    assert set(cons) == {"S1", "S2", "S3", "S4"} and max(c["rms_mm"] for c in cons.values()) < 0.2


def test_centres_cleaner_than_the_stated_pose_noise_converge_green(mounting):
    """Circles consistent with the reported poses to 0.01 mm, the pose noise stated at 0.02
    mm: the centres' estimated noise goes to its floor and their covariance is all pose
    noise, which moves with the parameters. The refinement converges (not a crawl of 50
    iterations ending RED) and the clean cell is GREEN, with the known answer, but for the
    twin with y and z swapped that circles alone cannot exclude (amber, no nominal given)."""
    from spherecal.estimation.pipeline import CIRCLE_TWIN
    from spherecal.report.assess import verdict

    cell = standard_cell(mounting, seed=1, noise=NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.0,
                                                           pose_rotation_noise_deg=0.0), fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=10), kind="circle", centre_noise_mm=0.01)
    sol = solve(ds)
    assert sol.refined.converged, f"not converged in {sol.refined.iterations} iterations"
    assert_known_answer(sol.result, cell, rot_deg=0.05, trans_mm=0.1, centre_mm=0.1)
    ver = verdict(sol.result)
    assert [text for level, text in ver.reasons if level != "green"] == [CIRCLE_TWIN], ver


def test_the_station_robot_error_model_on_centres():
    """The station random effect works on centre rows as on profiles (its default 'auto')."""
    cell = standard_cell("eye_in_hand", seed=11, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind="sphere_centre", centre_noise_mm=0.02)
    res = solve(ds).result
    assert res.robot_error is not None and res.robot_error.model == "station"
    assert_known_answer(res, cell)


def test_the_kinematic_robot_error_model_on_centres(mounting):
    """An arm whose geometry differs from its nominal model (joints recorded): the
    kinematic model acts on centre rows as on profiles, and its covariance stays honest."""
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import RobotErrorModel

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell(mounting, seed=12, noise=NOISE, robot_error=RobotErrorModel(), arm=kin, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind="sphere_centre", centre_noise_mm=0.01)
    assert all(o.joints_deg is not None for o in ds.observations)
    res = solve(ds, CalibrationOptions(robot_error_model="kinematic"), kinematics=kin).result
    assert res.robot_error.model == "kinematic" and res.robot_error.kinematic_parameters
    # the arm's error is 0.5-2 mm at the flange: what one sphere cannot see moves the transform or the sphere
    assert_known_answer(res, cell, rot_deg=0.3, trans_mm=3.0, centre_mm=3.0)


# --- the paper's minimal procedure ----------------------------------------------------------------
def minimal(ds: Dataset) -> Dataset:
    """One station of four pure translations (rotation), three stations of two shots
    (translation): the paper's procedure."""
    keep = [o for o in ds.observations if o.station == "S1" or (o.index % 4) in (0, 3)]
    return ds.model_copy(update={"observations": keep})


@pytest.mark.parametrize("kind", ["sphere_centre", "circle"])
def test_the_papers_minimal_procedure_solves(mounting, kind):
    cell = standard_cell(mounting, seed=3, noise=NOISE, fov=reference_fov())
    full = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind=kind, centre_noise_mm=0.01)
    assert len(full.observations) == 16
    ds = minimal(full)
    assert [sum(o.station == s for o in ds.observations) for s in ("S1", "S2", "S3", "S4")] == [4, 2, 2, 2]
    res = solve(ds, CalibrationOptions(robot_error_model="none")).result
    assert not res.flagged and res.residuals.n_centres_used == 10
    assert_known_answer(res, cell, rot_deg=0.3, trans_mm=0.5)


def test_three_non_collinear_translations_fix_the_rotation_and_collinear_ones_do_not():
    cell = standard_cell("eye_in_hand", seed=3, noise=NOISE, fov=reference_fov())
    ds = minimal(simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind="sphere_centre",
                                         centre_noise_mm=0.01))
    three = [o for o in ds.observations if o.index != 3]  # S1: three shots, not on one line
    res = solve(ds.model_copy(update={"observations": three}), CalibrationOptions(robot_error_model="none")).result
    assert_known_answer(res, cell, rot_deg=0.3, trans_mm=0.5)
    # every station of two shots: each move on one line and all parallel in the sensor, so no station's
    # moves fix the rotation; the stations' sweeps at different places of the field of view do (the start
    # from any orientations)
    pairs = [o for o in ds.observations if (o.index % 4) in (0, 3)]
    res = solve(ds.model_copy(update={"observations": pairs}), CalibrationOptions(robot_error_model="none")).result
    assert res.diagnostics.start["method"] == "linear" and res.two_step_transform is None
    assert_known_answer(res, cell, rot_deg=0.3, trans_mm=0.5)
    # every sweep at one place of the field of view: the centres lie along one line of the sensor frame
    one_place = SweepPlan(profiles_per_station=4, station_offsets_mm=[(0.0, 0.0)], lateral_amplitude_mm=0.0)
    ds = minimal(simulate_centre_dataset(cell, one_place, kind="sphere_centre", centre_noise_mm=0.01))
    pairs = [o for o in ds.observations if (o.index % 4) in (0, 3)]
    with pytest.raises(DegenerateDataError) as caught:
        solve(ds.model_copy(update={"observations": pairs}), CalibrationOptions(robot_error_model="none"))
    said = str(caught.value)
    assert "all along one line: the rotation is not determined" in said, said
    assert re.search(r"Nor can the start from any orientations solve it: the sphere centre is along one line "
                     r"\(about \[.*\]\) of the sensor frame in every row", said), said
    assert "add rows with the sphere elsewhere in the field of view" in said, said


def test_a_circle_station_needs_two_shots_a_sphere_centre_station_one():
    cell = standard_cell("eye_in_hand", seed=3, noise=NOISE, fov=reference_fov())
    opts = CalibrationOptions(robot_error_model="none")
    for kind, kept in (("circle", False), ("sphere_centre", True)):
        ds = minimal(simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind=kind, centre_noise_mm=0.01))
        lone = [o for o in ds.observations if o.index != 7]  # S2 keeps one shot, observation 4
        res = solve(ds.model_copy(update={"observations": lone}), opts).result
        flagged = {f.index: f.reason for f in res.flagged}
        if kept:
            assert not flagged and res.residuals.n_centres_used == 9
        else:
            assert list(flagged) == [4] and "station S2 has only 1 usable observations" in flagged[4]
            assert "(needs 2)" in flagged[4] and "side of the laser plane" in flagged[4]


# --- mixed files ---------------------------------------------------------------------------------------
def test_a_file_mixing_profiles_circles_and_sphere_centres(tmp_path, mounting):
    cell = standard_cell(mounting, seed=5, noise=NOISE, fov=reference_fov())
    profiles = simulate_dataset(cell, SweepPlan(profiles_per_station=6))
    circles = {o.index: o for o in circles_from_profiles(profiles).observations}
    spheres = {o.index: o for o in sphere_centres_from_fits(profiles, cell).observations}
    mixed = [o if o.station in ("S1", "S2") else circles.get(o.index) if o.station == "S3" else spheres.get(o.index)
             for o in profiles.observations]
    ds = profiles.model_copy(update={"observations": [o for o in mixed if o is not None]})
    path = tmp_path / "mixed.dataset.jsonl"
    write_dataset(path, ds)
    back = read_dataset(path)
    assert {o.kind for o in back.observations} == {"profile", "circle", "sphere_centre"}
    res = solve(back, CalibrationOptions(robot_error_model="none")).result
    assert_known_answer(res, cell)
    n_prof = sum(o.kind == "profile" for o in back.observations)
    assert res.residuals.n_profiles_used == n_prof and res.residuals.n_centres_used == len(back.observations) - n_prof
    assert res.residuals.n_points_used > 1000


# --- typed tables: typos are caught and the row is named ------------------------------------------
def table(seed=21, kind="sphere_centre") -> tuple[Dataset, object]:
    cell = standard_cell("eye_in_hand", seed=seed, noise=NOISE, fov=reference_fov())
    return simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind, centre_noise_mm=0.01), cell


def with_row(ds: Dataset, index: int, **update) -> Dataset:
    obs = [o.model_copy(update=update) if o.index == index else o for o in ds.observations]
    return ds.model_copy(update={"observations": obs})


def flagged_reasons(ds: Dataset) -> tuple[dict[int, str], object]:
    res = solve(ds, CalibrationOptions(robot_error_model="none")).result
    return {f.index: f.reason for f in res.flagged}, res


def test_a_translation_in_metres_among_millimetres_is_named():
    ds, cell = table()
    pose = ds.observations[8].base_from_flange
    bad = with_row(ds, 8, base_from_flange=Pose(translation_mm=tuple(np.divide(pose.translation_mm, 1000)),
                                                 quaternion_wxyz=pose.quaternion_wxyz))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [8] and "metres among millimetres" in flags[8] and "base_from_flange.translation_mm" in flags[8]
    assert_known_answer(res, cell)
    # a sphere centre typed in metres
    c = ds.observations[13].sphere_centre_mm
    flags, _ = flagged_reasons(with_row(ds, 13, sphere_centre_mm=tuple(np.divide(c, 1000))))
    assert list(flags) == [13] and "sphere_centre_mm" in flags[13] and "metres among millimetres" in flags[13]
    # a circle typed in metres
    circles, cell = table(kind="circle")
    c = circles.observations[13].circle
    flags, res = flagged_reasons(with_row(circles, 13, circle=Circle(centre_yz_mm=tuple(np.divide(c.centre_yz_mm, 1000)),
                                                                     radius_mm=c.radius_mm / 1000)))
    assert list(flags) == [13] and "circle" in flags[13] and "metres among millimetres" in flags[13]
    assert_known_answer(res, cell)


def test_a_sign_flip_in_one_component_of_a_circle_is_named_with_its_size():
    ds, cell = table(kind="circle")
    c = ds.observations[9].circle
    bad = with_row(ds, 9, circle=Circle(centre_yz_mm=(c.centre_yz_mm[0], -c.centre_yz_mm[1]), radius_mm=c.radius_mm))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [9], flags
    assert error_size_mm(flags[9]) == pytest.approx(2 * abs(c.centre_yz_mm[1]), rel=0.2)
    assert_known_answer(res, cell)


@pytest.mark.parametrize("where", ["pose", "centre"])
def test_a_sign_flip_in_one_component_is_named_with_its_size(where):
    ds, cell = table()
    o = ds.observations[9]
    if where == "pose":
        t = list(o.base_from_flange.translation_mm)
        t[1] = -t[1]  # y: ~150 mm in this cell
        bad = with_row(ds, 9, base_from_flange=Pose(translation_mm=tuple(t),
                                                    quaternion_wxyz=o.base_from_flange.quaternion_wxyz))
    else:
        c = list(o.sphere_centre_mm)
        c[2] = -c[2]  # z: about -20 mm in the sensor frame
        bad = with_row(ds, 9, sphere_centre_mm=tuple(c))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [9], flags
    assert "did not move in the sensor frame by the distance the robot moved" in flags[9]
    expected = 2 * abs(o.base_from_flange.translation_mm[1]) if where == "pose" else 2 * abs(o.sphere_centre_mm[2])
    assert error_size_mm(flags[9]) == pytest.approx(expected, rel=0.2)  # the whole jump
    assert_known_answer(res, cell)


@pytest.mark.parametrize("kind", ["sphere_centre", "circle"])
@pytest.mark.parametrize("row", [5, 23])  # the last rows of stations S1 and S4
def test_a_sign_flip_in_the_last_row_of_a_station_is_named_not_its_neighbour(mounting, kind, row):
    """A typo mostly across the robot's moves changes only the distance to the row it was
    moved along; a station's last row has one such neighbour. The two disagree with each
    other only: the solution of the others must tell which is wrong, never a tie broken
    by row order (which flagged the clean neighbour and left the typo to a later check)."""
    cell = standard_cell(mounting, seed=21, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind, centre_noise_mm=0.01)
    o = ds.observations[row]
    later = [x.station for x in ds.observations[row + 1:]]
    assert o.station == ds.observations[row - 1].station and o.station not in later  # the last row of its station
    if kind == "sphere_centre":
        c = list(o.sphere_centre_mm)
        c[1] = -c[1]
        bad, expected = with_row(ds, row, sphere_centre_mm=tuple(c)), 2 * abs(o.sphere_centre_mm[1])
    else:
        c = o.circle
        bad = with_row(ds, row, circle=Circle(centre_yz_mm=(-c.centre_yz_mm[0], c.centre_yz_mm[1]), radius_mm=c.radius_mm))
        expected = 2 * abs(c.centre_yz_mm[0])
    assert expected > 3.0  # a gross typo, for the pure-translation check
    flags, res = flagged_reasons(bad)
    assert list(flags) == [row], flags  # no clean row dropped
    assert "the typo is in this row" in flags[row] and "profiles" not in flags[row]
    assert error_size_mm(flags[row]) == pytest.approx(expected, rel=0.02), flags[row]
    assert res.residuals.n_centres_used == len(ds.observations) - 1
    assert_known_answer(res, cell)


def test_a_centre_off_where_the_robot_motion_puts_it_is_not_called_a_profile():
    """Below the pure-translation check's tolerance the two-step's check catches an
    offset centre; its flag speaks of observations and of a typo, not of profiles."""
    ds, cell = table()
    c = list(ds.observations[9].sphere_centre_mm)
    c[0] += 0.6
    flags, res = flagged_reasons(with_row(ds, 9, sphere_centre_mm=tuple(c)))
    assert list(flags) == [9], flags
    assert "off where the robot motion puts it" in flags[9], flags[9]
    assert "inconsistent with the other observations" in flags[9] and "profiles" not in flags[9]
    assert "a typo in the row" in flags[9]
    assert error_size_mm(flags[9]) == pytest.approx(0.6, rel=0.2)
    assert_known_answer(res, cell)


def error_size_mm(reason: str) -> float:
    """The size of a row's error a flag gives (mm): from the solution of the others (a row
    the pure-translation check left out) or from the robot's moves (the two-step's check)."""
    m = re.search(r"is (\d+\.\d+) mm (from where the solution of the other observations puts it|off where the "
                  r"robot motion puts it)", reason)
    assert m, reason
    return float(m.group(1))


def typed(ds: Dataset, path) -> list[dict]:
    """``ds`` as a table typed by hand would give it: every number to 4 decimals."""
    write_dataset(path, ds)

    def rounded(v):
        if isinstance(v, float):
            return round(v, 4)
        if isinstance(v, list):
            return [rounded(x) for x in v]
        if isinstance(v, dict):
            return {k: rounded(x) for k, x in v.items()}
        return v

    return [rounded(json.loads(line)) for line in path.read_text().splitlines()]


@pytest.mark.parametrize("kind", ["sphere_centre", "circle"])
def test_a_typed_table_with_one_centre_off_by_2_mm_names_the_row_and_the_size(tmp_path, kind):
    """A typo of 2 mm in one centre coordinate (a digit wrong) is flagged by its row with
    a size near 2 mm, although the distances the centre moved change by less (under 1.5
    mm, and beyond the check's tolerance for one other row only: the typo lies mostly
    across the robot's moves)."""
    cell = standard_cell("eye_in_hand", seed=21, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=10), kind=kind, centre_noise_mm=0.01)
    path = tmp_path / "paper-table.dataset.jsonl"
    rows = typed(ds, path)
    row = rows[1 + 15]  # observation 15 (line 17), station S3
    if kind == "sphere_centre":
        row["sphere_centre_mm"][1] = round(row["sphere_centre_mm"][1] + 2.0, 4)
    else:
        row["circle"]["centre_yz_mm"][0] = round(row["circle"]["centre_yz_mm"][0] + 2.0, 4)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    flags, res = flagged_reasons(read_dataset(path))
    assert list(flags) == [15], flags
    if kind == "sphere_centre":  # the pure-translation check (distances moved) caught it, with one other row
        assert "inconsistent with observation 16 of its station" in flags[15] and "the typo is in this row" in flags[15]
        gap = float(re.search(r"the distances differ by (\d+\.\d+) mm", flags[15]).group(1))
        assert gap < 1.5  # understated: the typo lies mostly across the robot's moves
    assert error_size_mm(flags[15]) == pytest.approx(2.0, rel=0.2), flags[15]
    assert res.residuals.n_centres_used == len(ds.observations) - 1
    assert_known_answer(res, cell)


def test_a_sign_flip_in_a_quaternion_component_is_named_with_its_angle():
    ds, cell = table()
    q = list(ds.observations[14].base_from_flange.quaternion_wxyz)
    k = 1 + int(np.argmax(np.abs(q[1:])))
    q[k] = -q[k]
    bad = with_row(ds, 14, base_from_flange=Pose(translation_mm=ds.observations[14].base_from_flange.translation_mm,
                                                 quaternion_wxyz=tuple(q)))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [14] and "turned" in flags[14] and "within a station the robot may only translate" in flags[14]
    assert_known_answer(res, cell)


#: Five stations tilted about 20 deg from each other, as a hand-held teach pendant session gives them.
TILTS_20 = [(0.0, 0.0, 0.0), (20.0, 0.0, 0.0), (0.0, 20.0, 0.0), (0.0, 0.0, 20.0), (-20.0, 0.0, 0.0)]


def one_label_for_five_orientations(per_orientation: int) -> tuple[Dataset, Dataset, object]:
    """Sphere-centre rows at five orientations 20-40 deg apart, ``per_orientation`` rows
    of each: as labelled (S1-S5), and all labelled S1 (a table whose station column was
    left at its default)."""
    cell = standard_cell("eye_in_hand", seed=9, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4, tilts_deg=TILTS_20), kind="sphere_centre",
                                 centre_noise_mm=0.02)
    rows = [o for o in ds.observations if o.index % 4 < per_orientation]
    rows = [o.model_copy(update={"index": k}) for k, o in enumerate(rows)]
    one = [o.model_copy(update={"station": "S1"}) for o in rows]
    return ds.model_copy(update={"observations": rows}), ds.model_copy(update={"observations": one}), cell


@pytest.mark.parametrize("per_orientation", [1, 3])
def test_rows_of_several_orientations_under_one_label_are_named_and_solved_by_orientation(per_orientation):
    """Within a station the robot may only translate: rows at five orientations under one
    label are not a station. With one row per orientation the two-step cannot start, and
    the start from any orientations solves them: the known answer, no row blamed as a
    typo, the label named with the orientations it holds; no two rows share an
    orientation, so the station robot error model (the default without joints) has
    nothing to estimate: the fit takes the robot's error as pose noise and says so. With
    three, each orientation's rows (sphere centres need no sweep) are split off as a
    station of their own, each named, and the two-step starts as on labelled stations."""
    _, one, cell = one_label_for_five_orientations(per_orientation)
    res = solve(one).result
    # five rows (one per orientation) determine the transform to about 0.2 deg (stated): the chi^2 checks that
    assert_known_answer(res, cell, rot_deg=0.5 if per_orientation == 1 else 0.15)
    assert res.flagged == []
    orientation = res.diagnostics.station_orientation
    if per_orientation == 1:
        assert res.diagnostics.start["method"] == "linear"
        assert orientation["split_by_orientation"] == {"S1": 5}, orientation
        assert orientation["notes"][0] == ("station S1: its rows are at 5 orientations, not one station of pure "
                                           "translations: grouped by orientation"), orientation
        assert res.robot_error.model == "none"
        assert "the station model needs shots that share an orientation and no two rows do" in \
            res.robot_error.model_choice, res.robot_error.model_choice
    else:
        assert orientation["split_stations"] == {"S1": ["S1", "S1/b", "S1/c", "S1/d", "S1/e"]}, orientation
        assert all("solved as a station of their own" in n for n in orientation["notes"]), orientation
        assert res.robot_error.model == "station"


def test_too_few_rows_of_several_orientations_under_one_label_name_both_causes():
    """Four rows at four orientations under one label: neither start can solve them. The
    refusal names the label with its orientations and what the start from any
    orientations needs; never a crash, never the rows blamed as typos, never 'all
    stations share one orientation', the opposite of the cause."""
    _, one, _ = one_label_for_five_orientations(1)
    four = one.model_copy(update={"observations": one.observations[:4]})
    with pytest.raises(DegenerateDataError) as caught:
        solve(four)
    said = str(caught.value)
    assert re.match(r"station S1: its 4 observations are at 4 different orientations \(up to \d+\.\d deg apart\)",
                    said), said
    assert "label each orientation a station of its own" in said, said
    assert ("Nor can the start from any orientations solve it: 4 row(s) with a sphere centre: the start from any "
            "orientations needs at least 5") in said, said
    assert "share one orientation" not in said and "typo" not in said, said


def test_rows_of_several_orientations_under_one_label_are_split_and_solved_as_labelled():
    """Four rows at each of five orientations, all labelled S1: each orientation is split
    off as a station of its own, no row is blamed, and the result is that of the table
    as it should have been labelled (the orientations' 20-40 deg differences are not
    taken for orientation read noise)."""
    labelled, one, cell = one_label_for_five_orientations(4)
    res, ref = solve(one).result, solve(labelled).result
    orientation = res.diagnostics.station_orientation
    assert orientation["split_stations"] == {"S1": ["S1", "S1/b", "S1/c", "S1/d", "S1/e"]}
    assert orientation["rotation_noise_seen_deg"] < 0.01, orientation
    assert res.flagged == ref.flagged == []
    assert geo.rotation_angle_deg(res.transform.rotation_matrix, ref.transform.rotation_matrix) < 1e-6
    assert np.allclose(res.transform.translation, ref.transform.translation, atol=1e-6)
    assert_known_answer(res, cell)


def test_stations_of_one_sphere_centre_each_are_solved_from_any_orientations():
    """Every station one sphere centre: no pure-translation move, so the two-step cannot
    find the rotation; the start from any orientations can (five rows, turned about three
    axes), and gives the known answer. Four such rows are too few, and the refusal says
    how many it needs."""
    labelled, _, cell = one_label_for_five_orientations(1)
    res = solve(labelled).result
    assert res.diagnostics.start["method"] == "linear"
    assert_known_answer(res, cell, rot_deg=0.5)  # five rows: about 0.2 deg stated, the chi^2 checks it
    four = labelled.model_copy(update={"observations": labelled.observations[:4]})
    with pytest.raises(DegenerateDataError, match=r"no station has two shots the robot moved between by a pure "
                                                  r"translation: the rotation is not determined.*Nor can the start "
                                                  r"from any orientations solve it: 4 row\(s\)"):
        solve(four)


def test_a_hand_typed_table_with_a_non_unit_quaternion_names_the_line(tmp_path):
    ds, _ = table()
    path = tmp_path / "paper-table.dataset.jsonl"
    write_dataset(path, ds)
    lines = path.read_text().splitlines()
    row = json.loads(lines[6])
    q = row["base_from_flange"]["quaternion_wxyz"]
    row["base_from_flange"]["quaternion_wxyz"] = [round(q[0] + 0.05, 4), *(round(v, 4) for v in q[1:])]
    lines[6] = json.dumps(row)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetFileError, match=r"line 7 \(observation 5\): base_from_flange\.quaternion_wxyz: .*has norm "
                                               r"1\.0\d+; expected a unit quaternion"):
        read_dataset(path)
    # rounding to 4 decimals, as tables print them, is not a typo
    row["base_from_flange"]["quaternion_wxyz"] = [round(v, 4) for v in q]
    lines[6] = json.dumps(row)
    path.write_text("\n".join(lines) + "\n")
    assert read_dataset(path).observations[5].base_from_flange is not None


def test_a_small_inconsistency_is_flagged_in_mm_never_used():
    ds, cell = table(kind="circle")
    c = ds.observations[10].circle
    bad = with_row(ds, 10, circle=Circle(centre_yz_mm=(c.centre_yz_mm[0] + 0.4, c.centre_yz_mm[1]),
                                         radius_mm=c.radius_mm))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [10]
    assert "0.4" in flags[10] or "0.3" in flags[10], flags[10]  # the size of the inconsistency, mm
    assert res.residuals.n_centres_used == len(ds.observations) - 1
    assert_known_answer(res, cell)


def test_in_a_station_of_two_the_solution_of_the_others_names_the_row_with_the_typo():
    cell = standard_cell("eye_in_hand", seed=3, noise=NOISE, fov=reference_fov())
    ds = minimal(simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind="sphere_centre",
                                         centre_noise_mm=0.01))
    o = next(x for x in ds.observations if x.index == 7)  # S2 holds observations 4 and 7
    t = list(o.base_from_flange.translation_mm)
    t[1] = -t[1]
    bad = with_row(ds, 7, base_from_flange=Pose(translation_mm=tuple(t), quaternion_wxyz=o.base_from_flange.quaternion_wxyz))
    flags, res = flagged_reasons(bad)
    assert list(flags) == [7], flags  # not 4, its station's other row
    assert "inconsistent with observation 4 of its station" in flags[7] and "the typo is in this row" in flags[7]
    assert error_size_mm(flags[7]) == pytest.approx(2 * abs(o.base_from_flange.translation_mm[1]), rel=0.2)
    assert res.residuals.n_centres_used == 9
    assert_known_answer(res, cell, rot_deg=0.3, trans_mm=0.5)


def two_rows_moved_otherwise(ds: Dataset, sizes: dict[str, float], how: str) -> Dataset:
    """Each station of ``sizes`` cut to its first and last rows, the last row's sphere
    centre moved otherwise than the robot by ``sizes[station]`` mm: 'across' keeps the
    distance it moved (only the direction is wrong, as a wrong sign or a swapped pair of
    coordinates in a hand-typed row gives it), 'along' changes the distance by that much."""
    by: dict[str, list] = {}
    for o in ds.observations:
        by.setdefault(o.station, []).append(o)
    out = []
    for label, rows in by.items():
        if label not in sizes:
            out += rows
            continue
        first, last = rows[0], rows[-1]
        c1, c2 = np.array(first.sphere_centre_mm), np.array(last.sphere_centre_mm)
        d, size = c2 - c1, sizes[label]
        D = np.linalg.norm(d)
        if how == "along":
            e = size * d / D
        else:  # |d + e| = |d|: e at the angle whose cosine is -size / (2 D) to the move
            w = np.cross(d, [0.0, 0.0, 1.0])
            w /= np.linalg.norm(w)
            cos = -size / (2 * D)
            e = size * (cos * d / D + np.sqrt(1 - cos**2) * w)
        out += [first, last.model_copy(update={"sphere_centre_mm": tuple(float(v) for v in c2 + e)})]
    return ds.model_copy(update={"observations": [o.model_copy(update={"index": k}) for k, o in enumerate(out)]})


def quaternion_in(text: str) -> np.ndarray:
    return np.array([float(v) for v in re.search(r"quaternion_wxyz \[([^\]]+)\]", text).group(1).split(",")])


@pytest.mark.parametrize("how", ["across", "along"])
def test_the_ten_row_table_names_the_inconsistent_rows_and_what_is_still_determined(how):
    """A published table: S1 four pure translations, which alone determine the rotation;
    S2-S4 two rows each, and in S3 and S4 the sphere centre moved 27 and 33 mm otherwise
    than the robot did. Moved the right distance in a wrong direction, only the rotation
    S1 gives can show it (the rotation pooled over every station is pulled 30 deg off, and
    judged against it no row stands out). Both rows of S3 and S4 (observations 6-9) are
    named with their station's error in mm and left out; S1 and S2 cannot determine the
    translation, and the refusal says so and gives the rotation S1 determines, with how
    well, never 'the data do not fit the model at all'."""
    cell = standard_cell("eye_in_hand", seed=9, noise=NOISE, fov=reference_fov())
    full = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind="sphere_centre", centre_noise_mm=0.02)
    ds = two_rows_moved_otherwise(minimal(full), {"S3": 27.0, "S4": 33.0}, how)
    assert [o.station for o in ds.observations] == ["S1"] * 4 + ["S2", "S2", "S3", "S3", "S4", "S4"]
    with pytest.raises(DegenerateDataError) as caught:
        solve(ds)
    said = str(caught.value)
    for a, b, size in ((6, 7, 27.0), (7, 6, 27.0), (8, 9, 33.0), (9, 8, 33.0)):
        flag = re.search(rf"observation {a}: inconsistent with observation {b} of its station[^;]*?(\d+\.\d+) mm"
                         r"(?: away from where|, the least the error can be)", said)
        assert flag and abs(float(flag.group(1)) - size) < 0.5, (a, said)
    assert "both left out" in said and "do not fit the model" not in said
    assert "one component of the translation is not determined" in said, said
    spread = re.search(r"the rotation is determined, by the moves within station\(s\) S1, to about (\d\.\d+) deg: "
                       r"flange_from_sensor quaternion_wxyz", said)
    assert spread, said
    off = geo.rotation_angle_deg(geo.matrix_from_quat_wxyz(quaternion_in(said)), cell.true_transform.rotation_matrix)
    assert off < 3 * float(spread.group(1)) and off < 1.0, (off, said)


def test_two_row_stations_that_moved_the_wrong_way_are_left_out_and_the_rest_solved():
    """As the ten-row table, with three stations of four rows tilted about three axes:
    S2 and S5, two rows each, moved the right distance in a wrong direction (27 and 33
    mm); their rows are left out with that size and the other stations give the known
    answer."""
    cell = standard_cell("eye_in_hand", seed=9, noise=NOISE, fov=reference_fov())
    plan = SweepPlan(profiles_per_station=4, tilts_deg=TILTS_20)
    ds = two_rows_moved_otherwise(
        simulate_centre_dataset(cell, plan, kind="sphere_centre", centre_noise_mm=0.02), {"S2": 27.0, "S5": 33.0},
        "across")
    flags, res = flagged_reasons(ds)
    assert sorted(flags) == [4, 5, 14, 15], flags
    for i, size in ((4, 27.0), (5, 27.0), (14, 33.0), (15, 33.0)):
        moved = float(re.search(r"the sphere centre moved (\d+\.\d+) mm away", flags[i]).group(1))
        assert abs(moved - size) < 0.5 and "nothing tells which: both left out" in flags[i], flags[i]
    assert res.residuals.n_centres_used == len(ds.observations) - 4
    assert_known_answer(res, cell)


@pytest.mark.parametrize("known", ["centre_std_mm", "radius_std_mm"])
def test_a_circle_may_give_one_standard_deviation_and_the_other_is_estimated(mounting, known):
    """Each of a circle's two standard deviations is optional on its own: the
    one not given is estimated from the data, the one given is used as it is."""
    cell = standard_cell(mounting, seed=7, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind="circle", centre_noise_mm=0.03,
                                 radius_noise_mm=0.03, give_covariance=True)
    other = "radius_std_mm" if known == "centre_std_mm" else "centre_std_mm"
    ds = ds.model_copy(update={"observations": [
        o.model_copy(update={"circle": o.circle.model_copy(update={other: None})}) for o in ds.observations]})
    assert all(getattr(o.circle, known) is not None and getattr(o.circle, other) is None for o in ds.observations)
    res = solve(ds, CalibrationOptions(robot_error_model="none")).result
    assert_known_answer(res, cell)
    est = res.diagnostics.noise["centre_noise_mm"]
    assert est is not None and 0.01 < est < 0.06, est  # (the missing one: 0.03 mm simulated)


def test_fill_unknown_sets_only_what_was_not_given():
    from spherecal.estimation.problem import fill_unknown, unknown_variances

    nan = np.nan
    cov = np.array([[[4.0, nan, 0.0], [nan, nan, nan], [0.0, nan, 9.0]], np.full((3, 3), nan), np.eye(3)])
    assert unknown_variances(cov).tolist() == [[False, True, False], [True, True, True], [False, False, False]]
    out = fill_unknown(cov, 0.5)
    np.testing.assert_array_equal(out[0], np.diag([4.0, 0.5, 9.0]))
    np.testing.assert_array_equal(out[1], 0.5 * np.eye(3))
    np.testing.assert_array_equal(out[2], np.eye(3))
    np.testing.assert_array_equal(fill_unknown(cov, np.array([1.0, 2.0, 3.0]))[1], 2.0 * np.eye(3))


def test_medians_of_the_others_are_those_of_numpy():
    """The metres-among-millimetres check compares each row with the median of the
    others; one sort gives all of them (a median per row takes 1.2 s on 4,000 rows),
    exactly as numpy's, ties and both parities included."""
    from spherecal.estimation.centres import _medians_of_the_others

    rng = np.random.default_rng(0)
    for n in (3, 4, 5, 6, 11, 100, 501):
        for rep in range(6):
            x = rng.normal(size=n) * (1000.0 if rep % 2 else 1.0)
            if rep % 3 == 0:
                x = np.round(x)
            np.testing.assert_array_equal(_medians_of_the_others(x),
                                          [np.median(np.delete(x, k)) for k in range(n)])


def test_three_centre_rows_turned_under_one_label_become_a_station_of_their_own():
    """A label holding four centre rows at one orientation and three at another: the three
    share an orientation, and sphere centres need no sweep, so they are solved as a station
    of their own (not left out as turned), and the answer is the known one."""
    cell = standard_cell("eye_in_hand", seed=2, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4), kind="sphere_centre", centre_noise_mm=0.02)
    moved = [o.index for o in ds.observations if o.station == "S2"][:3]
    obs = [o.model_copy(update={"station": "S1"}) if o.index in moved else o for o in ds.observations]
    obs = [o for o in obs if not (o.station == "S2")]  # (S2's fourth row goes: only the three turned ones remain)
    result = solve(ds.model_copy(update={"observations": obs})).result
    assert not result.flagged, [f.reason for f in result.flagged]
    assert_known_answer(result, cell)
