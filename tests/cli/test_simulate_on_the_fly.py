"""spherecal simulate --on-the-fly: a recording in the stream form whose provenance holds
the truth of its time relation; with --config, the run's robot type and estimator settings
too, which solve of the file starts from."""

import json

import numpy as np
import pytest

from spherecal.app.provenance import CALIBRATION_OPTIONS_KEY
from spherecal.app.simulate import stream_settings_for
from spherecal.app.solving import calibration_options
from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_USAGE, main
from spherecal.config import CalibrationOptions, load_config
from spherecal.core.streams import sensor_to_robot_time
from spherecal.io.dataset import read_dataset
from spherecal.io.streams import read_recording
from spherecal.sim import NoiseModel, SweepPlan, simulate_recording, standard_cell
from reference_sensor import reference_fov


def test_on_the_fly_writes_the_simulated_recording_and_its_truth(tmp_path, capsys):
    out = tmp_path / "otf.jsonl"
    assert main(["simulate", str(out), "--on-the-fly", "--mounting", "eye_to_hand", "--seed", "4",
                 "--pose-noise-mm", "0.03"]) == EXIT_OK
    said = capsys.readouterr()
    assert "on-the-fly recording (eye_to_hand)" in said.out + said.err
    rec = read_recording(out)
    assert rec.mounting == "eye_to_hand" and len(rec.sweeps) == 32
    assert rec.clocks["robot"] != rec.clocks["sensor"]
    p = rec.provenance
    assert p["stream_settings"]["pose"]["translation_noise_mm"] == 0.03  # the pose noise, made smooth
    # the file holds what the simulator gives for the same cell: stamps exactly, points to float32
    cell = standard_cell("eye_to_hand", seed=4, fov=reference_fov(),
                         noise=NoiseModel(point_noise_mm=0.01, pose_translation_noise_mm=0.03))
    ref = simulate_recording(cell, settings=stream_settings_for(cell), stations=SweepPlan())
    np.testing.assert_array_equal(rec.poses.t_robot_s, ref.poses.t_robot_s)
    np.testing.assert_array_equal(rec.profiles.t_sensor_s, ref.profiles.t_sensor_s)
    np.testing.assert_array_equal(rec.profiles.start, ref.profiles.start)
    np.testing.assert_allclose(rec.profiles.points_yz_mm, ref.profiles.points_yz_mm, atol=1e-5)
    np.testing.assert_allclose(rec.poses.t_mm, ref.poses.t_mm, atol=1e-9)
    assert json.loads(json.dumps(ref.provenance)) == p
    # the truth read back maps the first and last profiles into the pose stream's span
    assert p["t_sensor0_s"] == rec.t_sensor0_s
    t = sensor_to_robot_time(rec.profiles.t_sensor_s[[0, -1]], p["true_offset_s"], p["true_drift"],
                             p["t_sensor0_s"])
    assert rec.poses.t_robot_s[0] - 0.01 < t[0] and t[1] < rec.poses.t_robot_s[-1] + 0.01

    assert main(["simulate", str(out), "--on-the-fly"]) == EXIT_DATA  # never overwrites without --force
    assert main(["simulate", str(out), "--on-the-fly", "--force"]) == EXIT_OK
    assert read_recording(out).mounting == "eye_in_hand"


def test_profiles_per_station_are_refused_on_the_fly(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "x.jsonl"), "--on-the-fly", "--profiles", "5"]) == EXIT_USAGE
    assert "--profiles" in capsys.readouterr().err
    assert not (tmp_path / "x.jsonl").exists()


@pytest.mark.slow
def test_on_the_fly_from_a_configuration_streams_the_arm_s_joints(tmp_path, sim_config):
    # (without the example's car-door panel under the sphere: casting 14,000 profiles at it takes a minute)
    cfg = sim_config(**{r'^scan_object = "car_door_panel".*$': 'scan_object = "none"'})
    out = tmp_path / "otf.jsonl"
    assert main(["simulate", str(out), "--on-the-fly", "--config", str(cfg)]) == EXIT_OK
    rec = read_recording(out)
    assert rec.poses.joints_deg is not None and rec.poses.joints_deg.shape[1] == 6
    assert "robot_error" in rec.provenance and rec.provenance["flange_error_mm_range"][1] > 0.3
    assert len({s.station for s in rec.sweeps}) >= 4
    # as calibrate's journal: the robot type (solve takes its kinematics for the joints) and the run's settings
    assert (rec.provenance["robot"], rec.provenance["sensor"]) == ("abb_irb2400", "nxsensor_i")
    assert CalibrationOptions.model_validate(rec.provenance[CALIBRATION_OPTIONS_KEY]) == calibration_options(
        load_config(cfg).config)


def test_a_dataset_from_a_configuration_solves_with_its_settings(tmp_path, sim_config, capsys):
    """The kinematic example's identify_kinematics and nominal transform reach solve
    through the simulated dataset's provenance, as through calibrate's journal."""
    cfg = sim_config("sim-kinematic-eye-in-hand.toml")
    out = tmp_path / "kin.jsonl"
    assert main(["simulate", str(out), "--config", str(cfg)]) == EXIT_OK
    recorded = read_dataset(out).provenance
    assert recorded["robot"] == "abb_irb2400" and recorded[CALIBRATION_OPTIONS_KEY]["identify_kinematics"] is True
    capsys.readouterr()
    assert main(["solve", str(out), "--out", str(tmp_path / "solved"), "--no-report"]) == EXIT_OK
    said = capsys.readouterr().err
    assert "settings from the dataset (the run's [calibration]): " in said and "identify_kinematics = True" in said
    assert (tmp_path / "solved" / "robot_calibrated.urdf").exists()  # the arm's geometry was identified
