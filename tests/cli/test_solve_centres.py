"""`spherecal solve` on dataset format version 2: centre observations alone and mixed
with profiles, end to end with the report."""

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.cli import EXIT_OK, main
from spherecal.estimation.centres import circles_from_profiles
from spherecal.sim import NoiseModel, SweepPlan, simulate_centre_dataset, simulate_dataset, standard_cell
from reference_sensor import reference_fov

NOISE = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)


def within_truth(result, cell, k=5.0):
    rot = geo.rotation_angle_deg(cell.true_transform.rotation_matrix, result.transform.rotation_matrix)
    dt = np.linalg.norm(cell.true_transform.translation - result.transform.translation)
    return rot < k * np.linalg.norm(result.std_rotation_deg) and dt < k * np.linalg.norm(result.std_translation_mm)


@pytest.mark.slow
@pytest.mark.parametrize("mounting, kind", [("eye_in_hand", "sphere_centre"), ("eye_to_hand", "circle")])
def test_solve_a_dataset_of_centres_with_its_report(tmp_path, capsys, mounting, kind):
    cell = standard_cell(mounting, seed=9, noise=NOISE, fov=reference_fov())
    path = tmp_path / "centres.dataset.jsonl"
    dataio.write_dataset(path, simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind,
                                                       centre_noise_mm=0.02))
    assert dataio.read_dataset_header(path).version == 2
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out)]) == EXIT_OK
    printed = capsys.readouterr().out
    assert "simulated truth: error" in printed
    assert "24 centre observations" in (out / "run.log").read_text()  # the residuals' line: -v prints it
    result = dataio.read_result(out / "result.json")
    assert within_truth(result, cell)
    assert result.residuals.n_centres_used == 24 and result.residuals.n_profiles_used == 0
    html = (out / "report.html").read_text()
    assert "24 centre observations" in html and "fig-residuals_per_centre" in html
    assert "fig-residuals_per_profile" not in html and not (out / "report_residuals_per_profile.png").exists()
    assert (out / "report_residuals_per_centre.png").exists() and (out / "report_sphere_3d.png").exists()


@pytest.mark.slow
def test_solve_a_file_mixing_profiles_and_circles(tmp_path, capsys):
    cell = standard_cell("eye_to_hand", seed=2, noise=NOISE, fov=reference_fov())
    profiles = simulate_dataset(cell, SweepPlan(profiles_per_station=6))
    circles = {o.index: o for o in circles_from_profiles(profiles).observations}
    mixed = [circles.get(o.index) if o.station in ("S2", "S4") else o for o in profiles.observations]
    path = tmp_path / "mixed.dataset.jsonl"
    dataio.write_dataset(path, profiles.model_copy(update={"observations": [o for o in mixed if o is not None]}))
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out)]) == EXIT_OK
    result = dataio.read_result(out / "result.json")
    assert within_truth(result, cell)
    assert result.residuals.n_profiles_used == 12 and result.residuals.n_centres_used == 12
    for fig in ("residuals_per_profile", "residuals_per_centre", "residuals_per_station", "sphere_3d"):
        assert (out / f"report_{fig}.png").exists(), fig


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["sphere_centre", "circle"])
def test_eye_in_hand_centres_labelled_eye_to_hand_are_red_with_the_likely_cause(tmp_path, capsys, kind):
    """The rule on centre-only data: the noise estimated from the fit's residuals
    takes in any misfit, so the residuals are judged against the noise the centres show
    within their stations (pure translations, whatever the mounting) instead. A RED exit,
    the mounting named, and no result or exports without --force."""
    from spherecal.cli import EXIT_RED

    cell = standard_cell("eye_in_hand", seed=9, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind=kind, centre_noise_mm=0.01)
    path = tmp_path / "centres.dataset.jsonl"
    dataio.write_dataset(path, ds.model_copy(update={"mounting": "eye_to_hand"}))
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out), "--no-report", "-v"]) == EXIT_RED  # -v: every reason
    cap = capsys.readouterr()
    assert "verdict: RED: Wrong: the data do not fit the model at all" in cap.out, cap.out
    assert "their noise within stations, where the robot only translated" in cap.out
    for text in ("mounting is probably wrong", "it says eye_to_hand", "solved as eye_in_hand"):
        assert text in cap.out, (text, cap.out)
    assert "NOT written" in cap.out and "exit 7" in cap.err
    assert not (out / "result.json").exists() and not list(out.glob("*4x4*")) and not list(out.glob("*.mod"))
    # --force writes it, still RED, and the file says so
    assert main(["solve", str(path), "--out", str(tmp_path / "forced"), "--no-report", "--force"]) == EXIT_RED
    verdict = dataio.read_result(tmp_path / "forced" / "result.json").diagnostics.verdict
    assert verdict["level"] == "red" and verdict["written_with_force"]


def test_centre_rows_of_several_orientations_under_one_label_are_solved_or_a_data_error(tmp_path, capsys):
    """Two sphere-centre rows at each of five orientations, all labelled S1 (a table whose
    station column was left at its default): too few per orientation for the two-step, so
    the start from any orientations solves it (exit 0) and the terminal names station S1
    with its orientations. One row at each of four orientations is too few for it: a data
    error (exit 3) naming station S1, its orientations and what the start from any
    orientations needs; never an internal error."""
    from spherecal.cli import EXIT_DATA, EXIT_OK

    cell = standard_cell("eye_in_hand", seed=9, noise=NOISE, fov=reference_fov())
    tilts = [(0.0, 0.0, 0.0), (20.0, 0.0, 0.0), (0.0, 20.0, 0.0), (0.0, 0.0, 20.0), (-20.0, 0.0, 0.0)]
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=4, tilts_deg=tilts), kind="sphere_centre",
                                 centre_noise_mm=0.02)
    rows = [o.model_copy(update={"station": "S1", "index": k})
            for k, o in enumerate(o for o in ds.observations if o.index % 4 in (0, 3))]
    path = tmp_path / "centres.dataset.jsonl"
    dataio.write_dataset(path, ds.model_copy(update={"observations": rows}))
    assert main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"]) == EXIT_OK
    err = capsys.readouterr().err
    assert "station S1: its rows are at 5 orientations, not one station of pure translations" in err, err
    path = tmp_path / "four.dataset.jsonl"
    dataio.write_dataset(path, ds.model_copy(update={"observations": rows[:8:2]}))
    assert main(["solve", str(path), "--out", str(tmp_path / "res4"), "--no-report"]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "internal error" not in err, err
    assert "error: station S1: its 4 observations are at 4 different orientations" in err, err
    assert "label each orientation a station of its own" in err, err
    assert "Nor can the start from any orientations solve it: 4 row(s) with a sphere centre" in err, err


def _swapped_circles(ds):
    return ds.model_copy(update={"observations": [o.model_copy(update={"circle": o.circle.model_copy(update={
        "centre_yz_mm": (o.circle.centre_yz_mm[1], o.circle.centre_yz_mm[0])})}) for o in ds.observations]})


def test_a_circle_table_says_that_its_twin_with_y_and_z_swapped_cannot_be_excluded(tmp_path, capsys):
    """Circles carry no arc: the sensor turned half a turn about its (0, 1, 1) axis fits a
    circle table with y and z swapped exactly as the right transform fits it as given, and
    without a nominal transform nothing tells them apart. The result is given, AMBER, and
    says so in the terminal and in result.json with what would tell them apart; with a
    nominal transform it is not said, and a swapped table is RED with the swap named."""
    from spherecal.cli import EXIT_RED

    cell = standard_cell("eye_to_hand", seed=9, noise=NOISE, fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind="circle", centre_noise_mm=0.02)
    path, swapped = tmp_path / "circles.dataset.jsonl", tmp_path / "swapped.dataset.jsonl"
    dataio.write_dataset(path, ds)
    dataio.write_dataset(swapped, _swapped_circles(ds))
    twin = "a twin of this result cannot be excluded: the sensor turned half a turn about its (0, 1, 1) axis fits this "
    for name in (path, swapped):  # either way round, the data alone cannot tell
        out = tmp_path / name.stem
        assert main(["solve", str(name), "--out", str(out), "--no-report"]) == EXIT_OK
        printed = capsys.readouterr().out
        assert "verdict: AMBER" in printed and f"amber: {twin}table with y and z swapped in every circle" in printed
        assert "Give a nominal transform (calibration.nominal_transform; spherecal solve --nominal)" in printed
        result = dataio.read_result(out / "result.json")
        assert result.diagnostics.mirror_twin["excluded"] is False
        assert result.diagnostics.mirror_twin["text"].startswith(twin)
    X = cell.true_transform
    nominal = ",".join(str(v) for v in (*X.translation_mm, *X.quaternion_wxyz))
    assert main(["solve", str(path), "--out", str(tmp_path / "nominal"), "--no-report", "--nominal", nominal]) == EXIT_OK
    printed = capsys.readouterr().out
    assert "twin" not in printed and dataio.read_result(tmp_path / "nominal" / "result.json").diagnostics.mirror_twin is None
    assert main(["solve", str(swapped), "--out", str(tmp_path / "caught"), "--no-report", "--nominal", nominal]) == EXIT_RED
    printed = capsys.readouterr().out
    assert "red: the result is 180.0 deg and " in printed, printed
    assert "turned half a turn about the sensor's (0, 1, 1) axis, which is what data with y and z swapped" in printed
