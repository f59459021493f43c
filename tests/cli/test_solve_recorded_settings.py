"""`spherecal solve` of a journal or recording that holds the estimator settings of the run
that took it (`calibrate`, stop-and-go and on the fly, writes them in its journal's
provenance): solved with those by default, the command line's options replacing them, the terminal saying which came from
the recording; and the simulated clocks' truth the journal holds turned into the truth
line's clock offset and drift, as `calibrate` prints it."""

from types import SimpleNamespace

import numpy as np
import pytest

from spherecal.app import solve as dataset_app
from spherecal.app import solve_recording as app
from spherecal.app.calibrate import _journal_provenance as _stop_and_go_provenance
from spherecal.app.calibrate_on_the_fly import _journal_provenance
from spherecal.app.provenance import CALIBRATION_OPTIONS_KEY, with_clock_truth
from spherecal.app.solving import calibration_options
from spherecal.cli import EXIT_DATA, main
from spherecal.config import load_config
from spherecal.core.errors import InputError
from spherecal.core.streams import POSES_ASSUMED_KEY, PoseStream, ProfileStream, Recording
from spherecal.estimation import CalibrationOptions
from spherecal.io.dataset import write_dataset
from spherecal.io.streams import write_recording
from spherecal.sim import simulate_dataset, standard_cell
from spherecal.sim.live import true_time_relation
from reference_sensor import reference_fov

NOMINAL = {"translation_mm": [44.5, -19.8, 166.2], "quaternion_wxyz": [0.0, 1.0, 0.0, 0.0]}
#: Settings as calibrate records them (CalibrationOptions.model_dump(mode="json")).
RECORDED = {**CalibrationOptions().model_dump(mode="json"), "robot_error_model": "station", "fit_radius": True,
            "nominal_transform": NOMINAL, "pose_translation_noise_mm": 0.05}
#: The simulated clocks of a journal: the robot's counts from 1.7e9 s, 20 ppm fast; the
#: sensor's from 12.5 s, 30 ppm slow (each reads epoch_s + offset_s + rate T).
CLOCKS = {"robot": {"epoch_s": 1.7e9, "offset_s": 3.0, "rate": 1 + 20e-6},
          "sensor": {"epoch_s": 0.0, "offset_s": 12.5, "rate": 1 - 30e-6}}


def _recording(**provenance) -> Recording:
    """A tiny recording (what is solved of it is not the point here)."""
    poses = PoseStream.from_quaternions([100.0, 100.004, 100.008], np.zeros((3, 3)), np.tile([1.0, 0, 0, 0], (3, 1)))
    profiles = ProfileStream.from_profiles([20.0, 20.01], [np.zeros((3, 2)), np.ones((3, 2))])
    return Recording("eye_in_hand", 19.1, poses, profiles, provenance=provenance)


def test_the_recorded_settings_are_used_and_said():
    said = []
    options = app.recorded_options({CALIBRATION_OPTIONS_KEY: RECORDED}, "j.jsonl", said.append)
    assert options == CalibrationOptions.model_validate(RECORDED)
    assert options.robot_error_model == "station" and options.fit_radius and options.pose_translation_noise_mm == 0.05
    line, = said
    assert line.startswith("settings from the recording (the run's [calibration]): ")
    assert 'robot_error_model = "station"' in line and "fit_radius = True" in line
    assert "pose_translation_noise_mm = 0.05" in line and "nominal transform [44.5, -19.8, 166.2] mm" in line
    assert "point_noise_mm" not in line  # a default is not said
    assert line.endswith("--robot-error-model, --fit-radius, --nominal replace them")


def test_options_given_replace_the_recorded_ones_and_are_named():
    said = []
    options = app.recorded_options({CALIBRATION_OPTIONS_KEY: RECORDED}, "j.jsonl", said.append,
                                   robot_error_model="auto", fit_radius=False)
    assert (options.robot_error_model, options.fit_radius) == ("auto", False)
    assert options.nominal_transform.translation_mm == pytest.approx(NOMINAL["translation_mm"])  # kept
    assert 'robot_error_model = "station"' not in said[0] and "fit_radius" not in said[0]
    assert said[0].endswith("--robot-error-model, --fit-radius given instead of the recording's")


def test_a_recording_without_settings_is_solved_with_the_defaults_saying_nothing():
    said = []
    assert app.recorded_options({"source": "a bag"}, "r.jsonl", said.append) == CalibrationOptions()
    assert app.recorded_options({}, "r.jsonl", said.append, robot_error_model="none").robot_error_model == "none"
    assert said == []


def test_a_recorded_setting_unknown_is_named_and_one_refused_names_its_field():
    said = []
    options = app.recorded_options({CALIBRATION_OPTIONS_KEY: {**RECORDED, "future_knob": 3}}, "j.jsonl", said.append)
    assert options.robot_error_model == "station"
    assert said[0] == "j.jsonl: recorded settings this version does not know, ignored: future_knob"
    with pytest.raises(InputError, match=r"j.jsonl: provenance.calibration_options: a setting .*: robot_error_model = 'magic': Input "):
        app.recorded_options({CALIBRATION_OPTIONS_KEY: {**RECORDED, "robot_error_model": "magic"}}, "j.jsonl")
    with pytest.raises(InputError, match=r"calibration_options is not an object"):
        app.recorded_options({CALIBRATION_OPTIONS_KEY: "station"}, "j.jsonl")


def test_the_journal_records_the_run_s_settings(sim_config):
    """What calibrate on the fly writes in its journal's provenance is what it solves with."""
    loaded = load_config(sim_config("sim-on-the-fly-eye-in-hand.toml"))
    provenance = _journal_provenance(SimpleNamespace(cfg=loaded.config, loaded=loaded), "digest", None)
    recorded = provenance[CALIBRATION_OPTIONS_KEY]
    assert recorded["robot_error_model"] == "station"  # the example's, not solve's default "auto"
    assert CalibrationOptions.model_validate(recorded) == calibration_options(loaded.config)


def test_solve_of_a_recording_runs_with_its_settings_unless_given(tmp_path, monkeypatch, capsys):
    path = tmp_path / "journal.stream.jsonl"
    write_recording(path, _recording(**{CALIBRATION_OPTIONS_KEY: RECORDED}))
    used = []

    def solve_and_write(header, options, *args, **kwargs):  # the options, and no solve
        used.append(options)
        raise InputError("not solved here")

    monkeypatch.setattr(app, "solve_and_write", solve_and_write)
    for flags in ([], ["--robot-error-model", "none", "--no-fit-radius", "--nominal", "1,2,3,1,0,0,0"]):
        assert main(["solve", str(path), "--out", str(tmp_path / f"o{len(used)}"), "--no-report", *flags]) == EXIT_DATA
    recorded, given = used
    assert recorded == CalibrationOptions.model_validate(RECORDED)
    assert (given.robot_error_model, given.fit_radius, list(given.nominal_transform.translation_mm)) == \
        ("none", False, [1.0, 2.0, 3.0])
    assert given.pose_translation_noise_mm == 0.05  # what no option gives stays the recording's
    said = capsys.readouterr().err
    assert said.count("settings from the recording") == 2 and "given instead of the recording's" in said


def test_the_simulated_clocks_give_the_truth_of_the_clock_relation():
    rec = _recording(simulated_clocks=CLOCKS)
    provenance = with_clock_truth(rec)
    offset_s, drift = true_time_relation(CLOCKS, 20.0)
    assert (provenance["true_offset_s"], provenance["true_drift"]) == (offset_s, drift)
    assert drift == pytest.approx(50e-6, rel=1e-4) and offset_s == pytest.approx(1.7e9 + 3 - 12.5, abs=1e-3)
    assert "true_offset_s" not in rec.provenance  # the recording's own is left as it was
    computed = with_clock_truth(_recording(simulated_clocks=CLOCKS, **{POSES_ASSUMED_KEY: "poses from the "
                                                                        "programmed line, not measured"}))
    assert "true_offset_s" not in computed and "true_drift" not in computed
    assert "true_offset_s" not in with_clock_truth(_recording())


def test_a_stop_and_go_journal_records_the_run_s_settings(sim_config):
    loaded = load_config(sim_config("sim-kinematic-eye-in-hand.toml"))
    run = SimpleNamespace(cfg=loaded.config, loaded=loaded, fov=None)
    recorded = _stop_and_go_provenance(run, "digest", None)[CALIBRATION_OPTIONS_KEY]
    assert recorded["identify_kinematics"] and recorded["pose_translation_noise_mm"] == 0.02  # the example's
    assert CalibrationOptions.model_validate(recorded) == calibration_options(loaded.config)


def test_solve_of_a_stop_and_go_journal_runs_with_its_settings_unless_given(tmp_path, monkeypatch, capsys):
    """The journal's settings by default (the example's identify_kinematics and pose noise
    too, which solve's defaults would drop); each option given replaces its own, said."""
    dataset = simulate_dataset(standard_cell("eye_in_hand", seed=0, fov=reference_fov()))
    path = tmp_path / "journal.jsonl"
    recorded = {**RECORDED, "identify_kinematics": True, "station_rotation_tolerance_deg": 0.5}
    write_dataset(path, dataset.model_copy(update={"provenance": {CALIBRATION_OPTIONS_KEY: recorded}}))
    used = []

    def solve_and_write(dataset, options, *args, **kwargs):  # the options, and no solve
        used.append(options)
        raise InputError("not solved here")

    monkeypatch.setattr(dataset_app, "solve_and_write", solve_and_write)
    monkeypatch.setattr(dataset_app, "solve_kinematics", lambda dataset, *a, **k: (None, dataset, object()))
    flags = ["--robot-error-model", "none", "--no-fit-radius", "--station-rotation-tolerance-deg", "2",
             "--no-identify-kinematics"]
    for extra in ([], flags):
        assert main(["solve", str(path), "--out", str(tmp_path / f"o{len(used)}"), "--no-report", *extra]) == EXIT_DATA
    as_run, given = used
    assert as_run == CalibrationOptions.model_validate(recorded)
    assert (given.robot_error_model, given.fit_radius, given.station_rotation_tolerance_deg) == ("none", False, 2.0)
    assert not given.identify_kinematics and given.pose_translation_noise_mm == 0.05  # not given: the journal's
    said = [line for line in capsys.readouterr().err.splitlines() if line.startswith("settings from the dataset")]
    assert len(said) == 2
    assert "identify_kinematics = True" in said[0] and "identify_kinematics" not in said[1]
    replaced = said[1].split("; ")[-1]
    assert replaced.endswith(" given instead of the dataset's") and sorted(replaced.split(" given")[0].split(", ")) == \
        sorted(["--robot-error-model", "--fit-radius", "--station-rotation-tolerance-deg", "--identify-kinematics"])
