"""What `solve` prints (calibrate prints the same through spherecal.cli.finish.say_result):
what the result means for a point measured at a new pose first, then the verdict with the
one reason that decides it, the transform in one line, the simulated truth and where the
results are. The parameter tables and the estimator's terms come with -v, and go to
run.log either way. A kinematic calibration leads with the controller's nominal arm
model, then the calibrated model where alone its accuracy holds."""

from __future__ import annotations

import html
import json
import re

import pytest

from spherecal.cli import EXIT_OK, main
from spherecal.io import dataset as dataio

from tests.cli.conftest import example_config

#: What the summary leaves to -v: the second frame, the 1-sigma and k = 2 tables, the
#: residuals' line and the robot error model's terms.
DETAILS = ("sensor_from_flange", "expanded U (k = 2)", "std relative to the robot's own frame", "residuals: RMS",
           "robot error: the arm's geometry", "its parts (RMS 3-D, k = 1)")
#: The estimator's terms of the marginalised kinematic model, left to -v too.
ESTIMATOR = ("likelihood ratio", "marginalised", "prior spread")


def _solve(capsys, dataset, out, *extra, report=False):
    """solve's human text (standard error with --json, then the summary is returned too)."""
    argv = ["solve", str(dataset), "--out", str(out), "--robot", "abb_irb2400", *extra]
    assert main(argv + ([] if report else ["--no-report"])) == EXIT_OK
    cap = capsys.readouterr()
    return (cap.err, json.loads(cap.out)) if "--json" in extra else cap.out


def _transform_numbers(line: str) -> list[float]:
    m = re.fullmatch(r"flange_from_sensor \(maps points in sensor to flange\): translation_mm = \[(.*)\], "
                     r"quaternion_wxyz = \[(.*)\]", line)
    assert m, line
    return [float(v) for v in (m[1] + ", " + m[2]).split(", ")]


@pytest.fixture(scope="module")
def arm_error_dataset(tmp_path_factory):
    """The eye-in-hand example's cell (its arm off its model by a real arm's error) and its
    four stations, a few short profiles each, with joints: the marginalised kinematic model."""
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import RobotErrorModel, SweepPlan, simulate_dataset, standard_cell
    from reference_sensor import reference_fov

    kin = PluginHost().arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=3, robot_error=RobotErrorModel(), arm=kin,
                         fov=reference_fov(n_columns=160))
    path = tmp_path_factory.mktemp("data") / "arm.jsonl"
    dataio.write_dataset(path, simulate_dataset(cell, SweepPlan(profiles_per_station=6)))
    return path


def test_the_summary_leads_with_the_point_error_and_leaves_the_tables_to_v(arm_error_dataset, tmp_path, capsys):
    printed = _solve(capsys, arm_error_dataset, tmp_path / "plain")
    result = dataio.read_result(tmp_path / "plain" / "result.json")
    err = result.robot_error
    assert err.model == "kinematic" and "likelihood ratio" in err.model_choice
    lines = printed.splitlines()
    assert lines[0].startswith(f"a point measured at a new pose, with the robot as it is: expected error "
                               f"{err.point_error_k2_mm:.3f} mm (k = 2), mostly from "), lines[0]
    assert lines[0].endswith("(robot error model: the arm's geometry, kinematic)")  # the one auto chose
    level = result.diagnostics.verdict["level"]
    assert lines[1].startswith(f"verdict: {level.upper()}: ")
    if level != "green":  # one reason, one piece of advice, and where the others are
        assert len([ln for ln in lines if ln.startswith(("  amber: ", "  red: "))]) == 1
        assert len([ln for ln in lines if ln.startswith("  advice: ") and " more: " not in ln]) == 1
    (transform,) = [ln for ln in lines if ln.startswith("flange_from_sensor")]
    got = _transform_numbers(transform)
    assert got[:3] == pytest.approx(result.transform.translation_mm, abs=5e-5)
    assert got[3:] == pytest.approx(result.transform.quaternion_wxyz, abs=5e-9)
    assert any(ln.startswith("simulated truth: error ") for ln in lines)
    assert lines[-1] == f"results in {tmp_path / 'plain'}"
    for term in DETAILS + ESTIMATOR:
        assert term not in printed, term
    log = (tmp_path / "plain" / "run.log").read_text()
    assert all(term in log for term in DETAILS + ESTIMATOR)  # recorded all the same

    verbose = _solve(capsys, arm_error_dataset, tmp_path / "verbose", "-v")
    assert verbose.splitlines()[0] == lines[0]
    for term in DETAILS + ESTIMATOR:
        assert term in verbose, term
    assert f"a point measured at a new pose: expected error {err.point_error_k2_mm:.3f} mm (k = 2); its parts" in verbose


@pytest.mark.slow
def test_a_kinematic_calibration_leads_with_the_controller_s_nominal_model(tmp_path, capsys):
    """The nominal arm model's figure first (the exported transform without the calibrated
    model), then the calibrated model's, saying that its accuracy holds only through it;
    -v lists the identified parameters with their 1-sigma. The --json summary holds the
    nominal model's figure; the report links the calibrated URDF written beside it."""
    config = example_config(tmp_path, "sim-kinematic-eye-in-hand.toml",
                            **{r"^profiles_per_station = 8$": "profiles_per_station = 4"})
    data = tmp_path / "kinematic.jsonl"
    assert main(["simulate", str(data), "--config", str(config)]) == EXIT_OK
    capsys.readouterr()
    printed, summary = _solve(capsys, data, tmp_path / "k", "--identify-kinematics", "-v", "--json", report=True)
    err = dataio.read_result(tmp_path / "k" / "result.json").robot_error
    assert summary["uncertainty"]["point_error_nominal_arm_k2_mm"] == err.point_error_nominal_arm_k2_mm
    lines = printed.splitlines()  # (after the progress and debug lines, which share standard error with --json)
    lines = lines[next(i for i, ln in enumerate(lines) if ln.startswith("a point measured")):]
    assert lines[0] == ("a point measured at a new pose, on the controller's nominal arm model (the exported "
                        f"transform without the calibrated model): expected error {err.point_error_nominal_arm_k2_mm:.3f} "
                        "mm (k = 2), mostly from the arm's geometric error")
    assert lines[1].startswith(f"  through spherecal's calibrated arm model (robot_calibrated.urdf): expected error "
                               f"{err.point_error_k2_mm:.3f} mm (k = 2), mostly from ")
    assert lines[1].endswith("; this accuracy holds only where poses go through that model")
    assert err.point_error_nominal_arm_k2_mm > 2 * err.point_error_k2_mm
    assert "identified geometric parameters (estimate +/- 1-sigma" in printed
    for p in err.kinematic_parameters:
        assert (f"    {p.name} {p.value:+.4f} +/- {p.std:.4f} {p.unit}" in printed) == p.identified, p.name
    report = (tmp_path / "k" / "report.html").read_text()
    assert '<a href="robot_calibrated.urdf">robot_calibrated.urdf</a>' in report
    urdf = (tmp_path / "k" / "robot_calibrated.urdf").read_text()
    assert html.escape(urdf, quote=True) in report  # shown, as written
