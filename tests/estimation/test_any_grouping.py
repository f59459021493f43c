"""Any grouping of rows into stations ends in a result or in an error naming its cause:
rows of several orientations under one label, every row its own label, labels at random,
station data beside rows at orientations of their own. The station robot error model
gets its stations from the rows' orientations, or the solve says which model it took."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.errors import DegenerateDataError
from spherecal.estimation import CalibrationOptions, solve
from spherecal.sim import (
    NoiseModel, RobotErrorModel, SweepPlan, simulate_centre_dataset, simulate_dataset, simulate_general_dataset,
    standard_cell,
)
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)


def relabelled(ds, how: str, seed: int = 0):
    rng = np.random.default_rng(seed)
    n = len(ds.observations)
    labels = {"one": ["S1"] * n, "own": [f"R{i}" for i in range(n)],
              "random3": [f"G{rng.integers(3)}" for _ in range(n)], "pairs": [f"Q{i // 2}" for i in range(n)]}[how]
    return ds.model_copy(update={"observations": [o.model_copy(update={"station": s})
                                                  for o, s in zip(ds.observations, labels)]})


def datasets(kind: str):
    cell = standard_cell("eye_in_hand", seed=3, noise=NOISE, fov=reference_fov())
    general = simulate_general_dataset(cell, 20, kind=kind, centre_noise_mm=0.02)
    station = (simulate_dataset(cell, SweepPlan(profiles_per_station=6)) if kind == "profile" else
               simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind, centre_noise_mm=0.02))
    extra = [o.model_copy(update={"index": o.index + 1000}) for o in general.observations]
    mixed = station.model_copy(update={"observations": [*station.observations, *extra]})
    return cell, {"general": general, "station": station, "mixed": mixed}


#: What a refusal of a grouping names: a label holding several orientations, a station too
#: thin, or what the start from any orientations would need (the side of the laser plane).
CAUSES = ("different orientations", "usable profiles", "Nor can the start from any orientations solve it")


@pytest.mark.parametrize("kind", ["sphere_centre", "circle", "profile"])
@pytest.mark.parametrize("how", ["one", "own", "random3", "pairs"])
def test_every_grouping_ends_in_a_right_result_or_a_named_cause(kind, how):
    """No crash, never a wrong transform, never a row blamed as a typo for its label."""
    cell, sets = datasets(kind)
    X = cell.true_transform
    for name, ds in sets.items():
        try:
            res = solve(relabelled(ds, how)).result
        except DegenerateDataError as exc:
            said = str(exc)
            assert any(c in said for c in CAUSES) and "typo" not in said, (name, said)
            assert kind != "sphere_centre", f"sphere centres at any grouping are determined ({name}): {said}"
            continue
        rot = geo.rotation_angle_deg(res.transform.rotation_matrix, X.rotation_matrix)
        trans = float(np.linalg.norm(res.transform.translation - X.translation))
        assert rot < 0.2 and trans < 0.3, (name, rot, trans)
        assert not any("typo" in f.reason for f in res.flagged), (name, res.flagged)


@pytest.mark.parametrize("kind", ["sphere_centre", "profile"])
def test_labels_of_one_row_each_are_grouped_into_the_stations_of_their_orientations(kind):
    """Station data with every row under a label of its own: the rows that share an
    orientation are taken as a station (and said so), and the result is the one of the
    table as labelled."""
    _, sets = datasets(kind)
    labelled = sets["station"]
    res, ref = solve(relabelled(labelled, "own")).result, solve(labelled).result
    note = res.diagnostics.station_orientation["single_row_labels_grouped"]
    assert note.startswith("every label holds one row: the rows at one orientation (within 0.02 deg) were taken "
                           "as one station each, labelled by their first row: R0 (6 rows), R6 (6 rows)"), note
    assert res.diagnostics.start["method"] == "two-step" and res.robot_error.model == ref.robot_error.model == "station"
    assert geo.rotation_angle_deg(res.transform.rotation_matrix, ref.transform.rotation_matrix) < 1e-6
    assert np.allclose(res.transform.translation, ref.transform.translation, atol=1e-5)


def test_the_station_model_asked_for_rows_at_their_own_orientations_takes_the_kinematic_one_with_joints():
    """No two rows share an orientation: station offsets have nothing to be estimated
    from. With joints and the robot's kinematics the kinematic model is taken, and the
    result says so."""
    from spherecal.plugins.host import PluginHost

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=12, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    ds = simulate_general_dataset(cell, 30, kind="sphere_centre", centre_noise_mm=0.02)
    assert all(o.joints_deg is not None for o in ds.observations)
    res = solve(ds, CalibrationOptions(robot_error_model="station"), kinematics=kin).result
    assert res.robot_error.model == "kinematic", res.robot_error.model
    assert ("robot_error_model 'station': the station model needs shots that share an orientation and no two rows "
            "do: the kinematic model (the arm's geometric error, from the joints) was used") in \
        res.robot_error.model_choice
    rot = geo.rotation_angle_deg(res.transform.rotation_matrix, cell.true_transform.rotation_matrix)
    assert rot < 0.3, rot


@pytest.mark.parametrize("mounting_", ["eye_in_hand", "eye_to_hand"])
def test_rows_at_their_own_orientations_without_joints_state_the_robots_shared_error(mounting_):
    """An arm 0.5-2 mm off its reported poses, sphere centres each at its own orientation,
    no joints: no station offsets to estimate, so the robot's error shared by every row
    (its stated accuracy; in eye-in-hand also constant on the flange, which the transform
    takes whole) is considered in the reported covariance, and the transform lies within
    it; the covariance relative to the robot's frame leaves it out."""
    from spherecal.plugins.host import PluginHost

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    for seed in range(3):
        cell = standard_cell(mounting_, seed=seed, noise=NOISE, robot_error=RobotErrorModel(), arm=kin,
                             fov=reference_fov())
        ds = simulate_general_dataset(cell, 30, kind="sphere_centre", centre_noise_mm=0.02, plan_seed=seed)
        ds = ds.model_copy(update={"observations": [o.model_copy(update={"joints_deg": None})
                                                    for o in ds.observations]})
        res = solve(ds).result
        assert res.robot_error.model == "none" and "is in the uncertainty" in res.robot_error.model_choice
        X = cell.true_transform
        w = geo.rotvec_from_matrix(res.transform.rotation_matrix @ X.rotation_matrix.T)
        e = np.concatenate([w, res.transform.translation - X.translation])
        assert e @ np.linalg.solve(np.array(res.covariance)[:6, :6], e) < 27.86, (seed, e)
        assert max(res.robot_error.std_translation_mm_robot_frame) < max(res.std_translation_mm)
