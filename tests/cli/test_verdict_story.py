"""The eye-to-hand example as a user runs it: its verdict, reasons and advice tell one
story, the arm's geometric error, with one figure and one remedy."""

import re

import pytest

from spherecal.cli import EXIT_OK, main


@pytest.mark.slow
def test_the_eye_to_hand_example_names_one_cause(sim_config, capsys):
    """The simulated arm is off its nominal geometry: the stations' differences show
    0.034 mm of its error and a point at a new pose is expected 0.67 mm off (k = 2). The
    headline names the arm and the advice asks for the arm's calibration; nothing blames
    bad observations, the start or says the stations disagree beyond the noise. (The
    advice's explanation of a start that parts from the result by the arm's error is
    tested in tests/estimation/test_robot_error.py.)"""
    assert main(["calibrate", str(sim_config("sim-eye-to-hand.toml"))]) == EXIT_OK
    out = capsys.readouterr().out
    headline = re.search(r"^verdict: AMBER: (.*)$", out, re.M).group(1)
    expected = re.search(r"^a point measured at a new pose[^:]*: expected error (\d+\.\d+) mm", out, re.M).group(1)
    assert headline.startswith("Robot error dominates: the arm's geometric error, not the calibration")
    assert f"{expected} mm off (k = 2); calibrating the arm is the remedy" in headline
    advice = re.findall(r"^  advice: (.*)$", out, re.M)
    assert len(advice) == 1 and advice[0].startswith("The robot's own geometric error limits this calibration")
    assert f"expect {expected} mm (k = 2)" in advice[0] and "calibrate the arm's geometry with spherecal" in advice[0]
    assert "bad observations" not in out and "disagree by more than the noise" not in out
    assert "start and refinement disagree" not in out


@pytest.mark.slow
def test_profiles_at_their_own_orientations_without_joints_name_the_robots_error(tmp_path, capsys):
    """Raw profiles, every shot at its own orientation, on an arm with geometric error,
    the poses without joints: no station and no kinematic model can take the arm's error,
    so it shows as residuals and pose noise. The advice names the robot's own error and
    what to record (joints and the robot type), not the sensor's exposure or the pose
    timing; on a clean arm the same plan is GREEN."""
    from spherecal.cli import main
    from spherecal.io import dataset as dataio
    from spherecal.plugins.host import PluginHost
    from spherecal.sim import RobotErrorModel, simulate_general_dataset, standard_cell
    from reference_sensor import reference_fov

    arm = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})
    for label, error in (("arm", RobotErrorModel()), ("clean", None)):
        cell = standard_cell("eye_in_hand", seed=6, fov=reference_fov(), arm=arm, robot_error=error)
        ds = simulate_general_dataset(cell, 40, kind="profile", plan_seed=6)
        ds = ds.model_copy(update={"observations": [o.model_copy(update={"joints_deg": None}) for o in ds.observations]})
        path = tmp_path / f"{label}.jsonl"
        dataio.write_dataset(path, ds)
        main(["solve", str(path), "--out", str(tmp_path / label), "--no-report"])
        text = capsys.readouterr().out
        verdict_line = next(ln for ln in text.splitlines() if ln.startswith("verdict:"))
        if label == "clean":
            assert verdict_line.startswith("verdict: GREEN"), text
        else:
            assert "advice: The robot's own error shows as pose noise" in text, text
            assert "solve --robot TYPE" in text and "WaitRob" not in text, text
