"""A RED result never exits 0 silently: the verdict is printed with its likely cause,
the exit code is 7, and result.json and the exports are written only with --force.
Cases: eye-in-hand data labelled eye-to-hand, one station's profiles shifted 2 mm,
radius 19 given for 19.1. (The example cells' AMBER results exit 0:
tests/cli/test_calibrate.py.)"""

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_RED, main
from spherecal.sim import SweepPlan, simulate_dataset, standard_cell
from reference_sensor import reference_fov

EXPORTS = ["result.json", "SpherecalSensor.mod", "flange_from_sensor_4x4.txt", "ros_static_transform.yaml"]


@pytest.fixture(scope="module")
def clean():
    # a small dataset (160 points per profile, 6 per station) keeps the absurd solve short
    cell = standard_cell("eye_in_hand", seed=3, fov=reference_fov(n_columns=160))
    return simulate_dataset(cell, SweepPlan(profiles_per_station=6))


def _shifted(ds, station, dy):
    obs = [o.model_copy(update={"profile": o.profile.model_copy(update={"y_mm": o.profile.y_mm + dy})})
           if o.station == station else o for o in ds.observations]
    return ds.model_copy(update={"observations": obs})


CASES = {
    "wrong_mounting": (lambda ds: ds.model_copy(update={"mounting": "eye_to_hand"}),
                       ["mounting is probably wrong", "it says eye_to_hand", "solved as eye_in_hand"]),
    "radius_19_for_19_1": (lambda ds: ds.model_copy(update={"sphere_radius_mm": 19.0}),
                           ["sphere radius is probably wrong", "the data prefer 19.1", "19 mm was given"]),
    "station_shifted_2mm": (lambda ds: _shifted(ds, "S1", 2.0), ["station S1 disagrees with the others"]),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(CASES))
def test_a_red_result_exits_7_names_the_cause_and_writes_no_exports(tmp_path, clean, capsys, case):
    make, expected = CASES[case]
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, make(clean))
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out), "--no-report"]) == EXIT_RED
    cap = capsys.readouterr()
    assert "verdict: RED" in cap.out
    assert "\n  advice: " in cap.out  # what to do, in the terminal too (the headline says "advice below")
    for text in expected:
        assert text in cap.out, (text, cap.out)
    assert "NOT written" in cap.out and "--force" in cap.out
    assert "no report either: --no-report" in cap.out and "report in" not in cap.out
    assert "exit 7" in cap.err
    assert not any((out / f).exists() for f in EXPORTS)
    assert not (out / "report.html").exists()
    # data that fit nothing are not screened profile by profile (minutes of futile refits)
    assert ("the data fit nothing, screening skipped" in cap.err) == (case == "wrong_mounting")


@pytest.mark.slow
def test_force_writes_a_red_result_and_still_exits_7(tmp_path, clean, capsys):
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, clean.model_copy(update={"sphere_radius_mm": 19.0}))
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out), "--force"]) == EXIT_RED
    assert all((out / f).exists() for f in EXPORTS)
    assert (out / "report.html").exists()
    assert "likely cause" in (out / "report.html").read_text()  # the report shows the run's verdict
    assert "written with --force" in capsys.readouterr().out
    # result.json itself says it is RED, written with --force
    verdict = dataio.read_result(out / "result.json").diagnostics.verdict
    assert verdict["level"] == "red" and verdict["written_with_force"] and "likely cause" in verdict["headline"].lower()
    # and so does every exported file, at the top, in its own comment syntax; each still reads back
    assert_every_export_warns(out, True)


def exported_text_files(out):
    return [p for p in sorted(out.iterdir()) if p.suffix in {".txt", ".mod", ".yaml", ".py", ".sh", ".xacro"}]


def assert_every_export_warns(out, red):
    from spherecal.io.exporters import RED_WARNING
    from spherecal.report import export as X

    files = exported_text_files(out)
    assert len(files) == 7, files  # .mod, 4x4, xyz+quaternion, ROS .sh, .yaml, .launch.py, .xacro
    for path in files:
        head = " ".join(line.lstrip("#!< -").strip() for line in path.read_text().splitlines()[:4])
        assert (RED_WARNING in head) == red, (path.name, head)
    X.read_matrix_text((out / "flange_from_sensor_4x4.txt").read_text())
    X.read_xyz_quaternion((out / "flange_from_sensor_xyz_quat_wxyz.txt").read_text())
    X.read_ros_yaml((out / "ros_static_transform.yaml").read_text())
    X.read_ros_launch((out / "ros_static_transform.launch.py").read_text())
    X.read_ros_command((out / "ros_static_transform.sh").read_text())
    X.read_ros_urdf_joint((out / "ros_sensor_joint.urdf.xacro").read_text())


def test_a_good_result_exits_0_with_its_verdict(tmp_path, clean, capsys):
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, clean)
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out), "--no-report"]) == EXIT_OK
    assert "verdict: GREEN" in capsys.readouterr().out
    assert all((out / f).exists() for f in EXPORTS)
    assert_every_export_warns(out, False)


REPLAY = """mounting = "eye_in_hand"
output_dir = "out"
replay = "data.jsonl"
[nominal_transform]
translation_mm = [44.5, -19.8, 166.2]
quaternion_wxyz = [0.02714, -0.96565, 0.25663, 0.03026]
[sphere]
radius_mm = 19.0
[robot]
type = "abb_irb2400"
[sensor]
type = "nxsensor_i"
"""


def test_calibrate_replaying_red_data_exits_7_and_force_writes(tmp_path, clean, capsys):
    dataio.write_dataset(tmp_path / "data.jsonl", clean.model_copy(update={"sphere_radius_mm": 19.0}))
    cfg = tmp_path / "replay.toml"
    cfg.write_text(REPLAY)
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_RED
    assert "sphere radius is probably wrong" in capsys.readouterr().out
    assert not (tmp_path / "out" / "result.json").exists()
    assert main(["calibrate", str(cfg), "--no-report", "--force", "--out", str(tmp_path / "forced")]) == EXIT_RED
    assert (tmp_path / "forced" / "result.json").exists()


def test_the_terminal_verdict_lists_the_reasons_of_an_amber_one_too():
    """'see the checks below' is followed by them in the terminal, not only in the report:
    amber and red reasons (red first), never the green ones."""
    from spherecal.report.assess import Verdict
    from spherecal.report.terminal import format_verdict

    amber = Verdict("amber", "Usable with care: see the checks and the advice below.",
                    [("green", "residuals fine"), ("amber", "rotation 1-sigma 0.06 deg")])
    assert format_verdict(amber).splitlines() == ["verdict: AMBER: Usable with care: see the checks and the advice below.",
                                                  "  amber: rotation 1-sigma 0.06 deg"]
    red = Verdict("red", "Do not use yet.", [("amber", "a"), ("red", "b"), ("green", "c")])
    assert format_verdict(red).splitlines()[1:] == ["  red: b", "  amber: a"]
    assert format_verdict(Verdict("green", "Good.", [("green", "c")])) == "verdict: GREEN: Good."


def test_the_summary_s_verdict_gives_the_one_reason_that_decides_it():
    """calibrate and solve (without -v) print the reason a verdict stands on: the likely
    cause when one was named (not the generic list of likely causes), else the first reason
    of the verdict's level; and how many amber or red checks more there are, and where."""
    from spherecal.report.assess import Verdict
    from spherecal.report.terminal import format_verdict

    red = Verdict("red", "Wrong. Likely cause: the mounting.",
                  [("green", "g"), ("amber", "a"), ("red", "residuals 400 x"), ("red", "likely causes: a, b or c"),
                   ("red", "likely cause: the mounting is probably wrong")])
    assert format_verdict(red, everything=False).splitlines() == [
        "verdict: RED: Wrong. Likely cause: the mounting.", "  red: likely cause: the mounting is probably wrong",
        "  (3 more amber or red checks: with -v, and in the report)"]
    amber = Verdict("amber", "Usable with care.", [("green", "g"), ("amber", "first"), ("amber", "second")])
    assert format_verdict(amber, everything=False).splitlines()[1:] == [
        "  amber: first", "  (1 more amber or red check: with -v, and in the report)"]
    assert format_verdict(Verdict("amber", "h", [("amber", "only")]), everything=False).splitlines()[1:] == [
        "  amber: only"]


@pytest.mark.slow
def test_a_wrong_mounting_is_named_when_the_arm_s_geometry_is_identified(tmp_path):
    """The likely-cause checks solve again (here: with the other mounting) with the run's
    options; when those identify the arm's geometry the re-solve needs the arm's
    kinematics too, or it refuses and the check names nothing (a generic list only).
    Centre rows with joints keep the two kinematic solves short."""
    from spherecal.estimation import CalibrationOptions
    from spherecal.plugins.host import PluginHost
    from spherecal.app.solving import solve_and_write
    from spherecal.sim import NoiseModel, RobotErrorModel, simulate_centre_dataset

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    cell = standard_cell("eye_in_hand", seed=12, noise=noise, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov())
    ds = simulate_centre_dataset(cell, SweepPlan(profiles_per_station=6), kind="sphere_centre", centre_noise_mm=0.01)
    bad = ds.model_copy(update={"mounting": "eye_to_hand"})
    exports = PluginHost().export_plan(None, bad.mounting, None)
    _, graded, written = solve_and_write(bad, CalibrationOptions(identify_kinematics=True), tmp_path / "res", exports,
                                         log=lambda msg: None, report=False, kinematics=kin)
    assert graded.level == "red" and not written
    causes = [text for level, text in graded.reasons if text.startswith("likely cause: ")]
    assert len(causes) == 1, graded.reasons
    for text in ("mounting is probably wrong", "it says eye_to_hand", "solved as eye_in_hand"):
        assert text in causes[0], causes[0]
    assert "Likely cause: the dataset's mounting is probably wrong" in graded.headline


def _quaternions_xyzw(ds):
    """The poses as a tool writing quaternions scalar last would give them, read w first."""
    obs = [o.model_copy(update={"base_from_flange": o.base_from_flange.model_copy(update={
        "quaternion_wxyz": np.roll(np.asarray(o.base_from_flange.quaternion_wxyz), -1)})}) for o in ds.observations]
    return ds.model_copy(update={"observations": obs})


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_quaternions_written_scalar_last_are_named(tmp_path, capsys, mounting):
    """Every pose's quaternion written (x, y, z, w): the fit breaks down or makes no sense;
    the command names the cause it can show (the data read the other way fit), exits
    non-zero, and never shows NumPy's error alone."""
    cell = standard_cell(mounting, seed=3, fov=reference_fov(n_columns=160))
    ds = _quaternions_xyzw(simulate_dataset(cell, SweepPlan(profiles_per_station=6)))
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds)
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    cap = capsys.readouterr()
    assert code in (EXIT_DATA, EXIT_RED)
    text = cap.out + cap.err
    assert "the poses' quaternions are probably written (x, y, z, w): read that way the same data fit" in text
    assert "internal error" not in text and "LinAlgError" not in text


@pytest.mark.slow
def test_quaternions_written_scalar_last_in_a_centre_table_are_named_before_the_robot_is_blamed(tmp_path, capsys):
    """A sphere-centre table (no joints) whose quaternions are written (x, y, z, w). The
    default robot error model takes the misfit into per-station effects, so the result is
    not absurd; the stations disagree by degrees (the station rotation scale at the 5 deg
    bound the fit puts on it, not a measurement). Such a disagreement is a data error: the
    quaternion order is checked before the robot is blamed and named, kinematic
    calibration is not advised, and the bound is printed as the bound it is (the verdict's
    line and, with -v, the robot error model's)."""
    from spherecal.sim import NoiseModel, simulate_centre_dataset

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    cell = standard_cell("eye_in_hand", seed=1, noise=noise, fov=reference_fov())
    plan = SweepPlan(profiles_per_station=4, tilts_deg=[(0, 0, 0), (20, 0, 0), (0, 20, 0), (0, 0, 20)])
    ds = _quaternions_xyzw(simulate_centre_dataset(cell, plan, kind="sphere_centre", centre_noise_mm=0.02))
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds)
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report", "-v"])
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert code == EXIT_RED, (code, text)
    assert "Likely cause: the poses' quaternions are probably written (x, y, z, w)" in text, text
    assert "read that way the same data fit" in text
    assert "calibrate the robot's kinematics" not in text and "robot's own geometric error limits" not in text, text
    assert "advice: The stations disagree by more than any arm's geometry: a data error" in text
    assert "the robot's error differs between stations by 0.000 mm and at least 5 deg per axis" in text, text
    assert "stations disagree by 0.000 mm and at least 5 deg per axis)" in text and "5.0000 deg" not in text


def test_centres_each_at_its_own_orientation_written_xyzw_are_named(tmp_path, capsys):
    """A sphere-centre table whose every row has its own orientation, its quaternions
    written (x, y, z, w): read w first the rows look like poorly spread orientations and
    the result is RED for its uncertainty, not its residuals; the quaternion order is
    tried and named, and the lead line does not give the figure as the robot's."""
    from spherecal.sim import NoiseModel, simulate_general_dataset

    noise = NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.02, pose_rotation_noise_deg=0.002)
    cell = standard_cell("eye_in_hand", seed=1, noise=noise, fov=reference_fov())
    ds = _quaternions_xyzw(simulate_general_dataset(cell, 30, kind="sphere_centre", centre_noise_mm=0.02, plan_seed=1))
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds)
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    text = capsys.readouterr().out
    assert code == EXIT_RED, text
    assert "Likely cause: the poses' quaternions are probably written (x, y, z, w)" in text, text
    lead = next(ln for ln in text.splitlines() if ln.startswith("a point"))
    assert "not the robot's error" in lead and "mostly from" not in lead, lead
    assert "Add a station tilted" not in text  # (more data read the wrong way would not help)


@pytest.mark.slow
def test_a_diameter_given_as_the_radius_is_named_and_the_robot_not_blamed(tmp_path, clean, capsys):
    """The sphere's diameter (38.2 mm) given as its radius: the per-station effects take in
    the misfit (the stations then 'disagree' by tens of mm), and a fit with the radius
    free breaks down from so far. The diameter is named (the data fit with half of it),
    and no advice sends the user to the robot's geometry."""
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, clean.model_copy(update={"sphere_radius_mm": 38.2}))
    assert main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"]) == EXIT_RED
    out = capsys.readouterr().out
    assert "Likely cause: the sphere's diameter is probably given as its radius." in out, out
    assert "with 19.1 mm the same data fit with residual RMS 0.0" in out, out
    assert "robot's own geometric error limits" not in out and "calibrate the robot" not in out, out
    # the lead line gives the point error as the data stand, not as the robot's
    lead = out.splitlines()[0] if out.startswith("a point") else next(ln for ln in out.splitlines() if ln.startswith("a point"))
    assert "not the robot's error" in lead and "mostly from" not in lead, lead
    assert "a data error" in out and "the radius and not the diameter" in out


@pytest.mark.slow
def test_eye_to_hand_data_labelled_eye_in_hand_is_named(tmp_path, capsys):
    """The reverse of the wrong-mounting case above: there the fit made no sense, here it
    can break down altogether; either way the mounting is named."""
    cell = standard_cell("eye_to_hand", seed=3, fov=reference_fov(n_columns=160))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=6)).model_copy(update={"mounting": "eye_in_hand"})
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds)
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    text = "".join(capsys.readouterr())
    assert code in (EXIT_DATA, EXIT_RED)
    assert "the dataset's mounting is probably wrong: it says eye_in_hand, but solved as eye_to_hand" in text
    assert "internal error" not in text


@pytest.mark.slow
@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
def test_one_station_s_quaternions_written_scalar_last_are_named(tmp_path, capsys, mounting):
    """Station S2's poses written (x, y, z, w), the others w first (poses gathered from two
    tools): the fit breaks down (eye-in-hand) or the stations disagree (eye-to-hand, RED);
    either way the station is named, found by reading its quaternions the other way."""
    cell = standard_cell(mounting, seed=0, fov=reference_fov(n_columns=160))
    ds = simulate_dataset(cell, SweepPlan(profiles_per_station=6))
    obs = [o.model_copy(update={"base_from_flange": o.base_from_flange.model_copy(update={
        "quaternion_wxyz": np.roll(np.asarray(o.base_from_flange.quaternion_wxyz), -1)})}) if o.station == "S2" else o
        for o in ds.observations]
    path = tmp_path / "data.jsonl"
    dataio.write_dataset(path, ds.model_copy(update={"observations": obs}))
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    text = "".join(capsys.readouterr())
    assert code in (EXIT_DATA, EXIT_RED)
    assert "station S2's quaternions are probably written (x, y, z, w): read that way the stations fit together" in text
