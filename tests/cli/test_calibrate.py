"""End-to-end runs of the CLI through the simulated serial controller and the simulated
USB sensor, resume after a kill, bad configurations."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.core import geometry as geo
from spherecal.cli import EXIT_DATA, EXIT_DEVICE, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, main
from spherecal.core.models import Pose


def check_against_truth(out, k=5.0):
    journal = dataio.read_dataset(out / "journal.jsonl")
    result = dataio.read_result(out / "result.json")
    true = Pose.model_validate(journal.provenance["true_transform"])
    rot = geo.rotation_angle_deg(true.rotation_matrix, result.transform.rotation_matrix)
    dt = np.linalg.norm(true.translation - result.transform.translation)
    assert rot < k * np.linalg.norm(result.std_rotation_deg)
    assert dt < k * np.linalg.norm(result.std_translation_mm)
    return journal, result


@pytest.mark.slow
def _at_shot(monkeypatch, n: int, action):
    """``take_shot`` calls ``action()`` at its ``n``-th call, then shoots as usual (an
    interruption at a known shot); returns the real ``take_shot``, to put back."""
    import spherecal.motion.acquisition as acq

    real = acq.take_shot
    calls = {"n": 0}

    def shot(*a, **k):
        calls["n"] += 1
        if calls["n"] == n:
            action()
        return real(*a, **k)

    monkeypatch.setattr(acq, "take_shot", shot)
    return real


def _interrupt():
    raise KeyboardInterrupt


@pytest.mark.slow
def test_a_run_resumed_within_a_station_keeps_the_arms_wrist(sim_config, monkeypatch):
    """Stopped at the 25th shot (mid-station) and resumed: the simulated arm stands where
    the journal's last shot left it, as a real arm does, so the station's next shot is
    reached in the same wrist solution (started from home it flipped: joints 4-6
    -116.5/-13.7/124.3 -> 62.4/13.9/-54.5)."""
    import spherecal.motion.acquisition as acq

    real = _at_shot(monkeypatch, 25, _interrupt)
    cfg = sim_config(**{r'^scan_object = "car_door_panel".*$': 'scan_object = "none"'})
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_INTERRUPTED
    monkeypatch.setattr(acq, "take_shot", real)
    assert main(["calibrate", str(cfg), "--resume", "--no-report"]) == EXIT_OK
    obs = dataio.read_dataset(cfg.parent / "out" / "journal.jsonl").observations
    before, after = obs[23], obs[24]
    assert before.station == after.station
    assert np.abs(np.subtract(after.joints_deg[3:], before.joints_deg[3:])).max() < 10.0


def test_sigterm_stops_as_ctrl_c_does_keeping_the_journal(sim_config, monkeypatch, capsys):
    """kill, timeout and service managers send SIGTERM: the run stops as on Ctrl-C (shots
    kept, the resume command said, run.log written), not ended on the spot; the
    process's own handler is back afterwards."""
    import os
    import signal

    _at_shot(monkeypatch, 7, lambda: os.kill(os.getpid(), signal.SIGTERM))
    before = signal.getsignal(signal.SIGTERM)
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_INTERRUPTED
    said = capsys.readouterr().err
    assert "terminated (SIGTERM)" in said and "--resume" in said
    assert signal.getsignal(signal.SIGTERM) is before
    out = cfg.parent / "out"
    assert 6 <= len(dataio.read_dataset(out / "journal.jsonl").observations) <= 7
    assert "terminated (SIGTERM)" in (out / "run.log").read_text()


@pytest.mark.parametrize("name", ["sim-eye-in-hand.toml", "sim-eye-to-hand.toml"])
def test_calibrate_end_to_end_in_both_modes(sim_config, name, capsys):
    import hashlib

    cfg = sim_config(name, **{r"^radius_mm = 19.1$": 'radius_mm = 19.1\nradius_uncertainty_mm = 0.002\n'
                                                     'certificate = "C-17"'})
    cfg.write_text(cfg.read_text() + '\n[report]\noperator = "from the file"\ncell = "Cell 3"\n')
    assert main(["calibrate", str(cfg), "--no-report", "--operator", "T. Tester"]) == EXIT_OK
    out = cfg.parent / "out"
    journal, result = check_against_truth(out)
    assert len(journal.observations) == 40
    assert journal.provenance["robot"] == "abb_irb2400" and journal.provenance["sensor"] == "nxsensor_i"
    assert result.mounting == journal.mounting
    printed = capsys.readouterr().out
    assert result.transform_name in printed and "quaternion_wxyz" in printed
    # the uncertainty tables: in run.log (and printed with -v, tests/cli/test_terminal_headline.py)
    expanded = "expanded U (k = 2): rotation " + ", ".join(f"{2 * v:.4f}" for v in result.std_rotation_deg)
    assert expanded not in printed and expanded in (out / "run.log").read_text()
    # the acquisition's time on the simulated cell's clock (moves, settles, shots), not the wall clock's
    timed = re.search(r"acquisition: 40 profiles in (\d+\.\d) s of simulated robot time, (\d+\.\d) profiles a "
                      r"minute", (out / "run.log").read_text())
    assert timed and 10.0 < float(timed.group(1)) < 120.0
    assert float(timed.group(2)) == pytest.approx(60 * 40 / float(timed.group(1)), rel=0.01)
    # identity and traceability: what the simulated devices said, the files' hashes, who and when
    p = result.provenance
    assert p["configuration_sha256"] == hashlib.sha256(cfg.read_bytes()).hexdigest()
    assert p["dataset_sha256"] == hashlib.sha256((out / "journal.jsonl").read_bytes()).hexdigest()
    assert p["robot"]["type"] == "abb_irb2400" and p["robot"]["model"] == "IRB 2400"
    assert p["sensor"] == {"type": "nxsensor_i", "manufacturer": "NextWare (simulated)", "model": "nxSensor-I",
                           "serial_number": "NXS-SIM-0001"}
    assert p["operator"] == "T. Tester" and p["cell"] == "Cell 3"  # --operator before the file's
    assert p["sphere"] == {"radius_mm": 19.1, "radius_uncertainty_mm_k2": 0.002, "certificate": "C-17"}
    for f in ["result.json", "SpherecalSensor.mod", "ros_static_transform.yaml", f"{result.transform_name}_4x4.txt"]:
        assert (out / f).exists(), f


def test_dry_run_moves_nothing(sim_config, capsys):
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_OK
    err = capsys.readouterr().err
    assert "plan: 40 shots in 4 stations" in err and "nothing moved" in err
    assert not (cfg.parent / "out").exists()


def test_a_target_outside_the_workspace_stops_before_any_motion(sim_config, capsys):
    cfg = sim_config(**{r"^max_mm = \[1600.0, 800.0, 1400.0\]": "max_mm = [1600.0, 800.0, 580.0]"})
    assert main(["calibrate", str(cfg)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "outside acquisition.workspace" in err and "nothing was moved" in err
    assert not (cfg.parent / "out" / "journal.jsonl").exists()


def test_a_target_the_robot_cannot_reach_stops_before_any_motion(sim_config, capsys):
    # the sphere moved far out of the arm's reach; the workspace box allows it
    cfg = sim_config(**{r"^sphere_centre_mm = \[1100.0, 150.0, 400.0\].*$": "sphere_centre_mm = [1500.0, 150.0, 1000.0]"})
    assert main(["calibrate", str(cfg)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "breaks the robot's limits" in err and "out of reach" in err
    assert not (cfg.parent / "out" / "journal.jsonl").exists()


def test_existing_journal_needs_resume(sim_config, capsys):
    cfg = sim_config()
    (cfg.parent / "out").mkdir()
    (cfg.parent / "out" / "journal.jsonl").write_text("")
    assert main(["calibrate", str(cfg)]) == EXIT_DATA
    assert "--resume" in capsys.readouterr().err


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_result(sim_config, tmp_path, capsys):
    """SIGKILL in the middle of the acquisition, then --resume: nothing taken is lost and
    the result equals that of an uninterrupted run."""
    cfg = sim_config(**{r"^approach_speed_mm_s = 100.0$": "approach_speed_mm_s = 100.0\nsettle_s = 0.02"})
    whole = tmp_path / "whole"
    assert main(["calibrate", str(cfg), "--out", str(whole), "--no-report"]) == EXIT_OK
    # the acceptance test it suggests checks this run, in the folder given
    assert f"acceptance test: spherecal validate {cfg} -o {whole} (" in capsys.readouterr().out

    cut = tmp_path / "cut"
    proc = subprocess.Popen([sys.executable, "-m", "spherecal.cli", "calibrate", str(cfg), "--out", str(cut),
                             "--no-report"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = cut / "journal.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if journal.exists() and journal.read_bytes().count(b"\n") >= 15:
            break
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    taken = len(dataio.read_dataset(journal).observations)
    assert 14 <= taken < 40, "the kill did not land mid-acquisition"
    assert not (cut / "result.json").exists()

    assert main(["calibrate", str(cfg), "--out", str(cut), "--resume", "--no-report"]) == EXIT_OK
    resumed = dataio.read_dataset(journal)
    assert sorted(o.target for o in resumed.observations) == list(range(40))
    a, b = dataio.read_result(whole / "result.json"), dataio.read_result(cut / "result.json")
    assert np.allclose(a.transform.as_matrix(), b.transform.as_matrix(), atol=1e-9)


def test_resume_refuses_a_journal_taken_with_another_plan(sim_config, monkeypatch, capsys):
    import spherecal.motion.acquisition as acq

    real = _at_shot(monkeypatch, 6, _interrupt)
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_INTERRUPTED
    monkeypatch.setattr(acq, "take_shot", real)
    cfg.write_text(cfg.read_text().replace("profiles_per_station = 10", "profiles_per_station = 12"))
    assert main(["calibrate", str(cfg), "--resume", "--no-report"]) == EXIT_DATA
    assert "was taken with another plan" in capsys.readouterr().err
    assert len(dataio.read_dataset(cfg.parent / "out" / "journal.jsonl").observations) == 5


def test_interrupt_keeps_the_journal(sim_config, monkeypatch, capsys):
    _at_shot(monkeypatch, 7, _interrupt)
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_INTERRUPTED
    assert "--resume" in capsys.readouterr().err
    assert len(dataio.read_dataset(cfg.parent / "out" / "journal.jsonl").observations) == 6


@pytest.mark.parametrize(
    "replace, message",
    [
        ({r"^mounting = .*$": 'mounting = "eye_on_hand"'}, "mounting: Input should be 'eye_in_hand' or 'eye_to_hand'"),
        ({r"^\[sphere\]": "[sphere]\ncolour = 'red'"}, "sphere.colour: unknown key (allowed here: radius_mm, radius_uncertainty_mm, certificate)"),
        ({r"^radius_mm = 19.1": "radius_mm = 0.0191"}, "sphere.radius_mm: radius_mm = 0.0191 looks like metres"),
        ({r"^max_speed_mm_s = 250.0": "max_speed_mm_s = 250.0\nbaudrate = -5"}, "robot.baudrate"),
        ({r'^type = "nxsensor_i"': 'type = "nxsensor_i"\nexposure = 3'}, "sensor.exposure"),
        ({r'^type = "abb_irb2400"': 'type = "abb_irb2600"'}, "abb_irb2600"),
        ({r"^speed_mm_s = 20.0": "speed_mm_s = 900.0"}, "acquisition: speed_mm_s = 900.0 exceeds max_speed_mm_s"),
        ({r"^profiles_per_station = 10": "profiles_per_station = 2"}, "acquisition.sweep.profiles_per_station"),
        ({r'^mounting = "eye_in_hand"': "mounting = 'eye_in_hand'\nreplay = 'x.jsonl'"}, "exactly one of [acquisition]"),
        ({r"^quaternion_wxyz = .*$": "quaternion_wxyz = [1.0, 1.0, 0.0, 0.0]"}, "nominal_transform.quaternion_wxyz"),
        ({r"^\[sphere\]": "[sphere"}, "not valid TOML"),
        ({r"^sphere_centre_mm = .*$": "sphere_centre_mm = [1000.0, 0.0]"},
         "acquisition.sphere_centre_mm: needs 3 numbers (x, y, z), got 2"),
        ({r"^\[acquisition\]$": "[acquisition]\nreference_flange_quaternion_wxyz = [0, 0, 2, 0]"},
         "acquisition.reference_flange_quaternion_wxyz: quaternion [0.0, 0.0, 2.0, 0.0] has norm 2.000000"),
        ({r"^\[calibration\]$": "[calibration]\nnominal_transform = {translation_mm = [0, 0, 0], quaternion_wxyz = [1, 0, 0, 0]}"},
         "give the rough transform as [nominal_transform] instead"),
        ({r"^length_mm = 80.0$": "length_mm = 80.0\nspeed_mm_s = 500.0"}, "scan.speed_mm_s = 500.0 exceeds acquisition.max_speed_mm_s"),
    ],
)
def test_bad_configurations_name_the_path(sim_config, capsys, replace, message):
    cfg = sim_config(**replace)
    assert main(["calibrate", str(cfg), "--dry-run"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert message in err, err
    assert str(cfg) in err


def test_a_dataset_given_to_calibrate_points_at_solve(tmp_path, capsys):
    path = tmp_path / "shots.jsonl"
    path.write_text('{"format": "spherecal-dataset", "version": 1}\n')
    assert main(["calibrate", str(path), "--dry-run"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert f"{path}: not valid TOML" in err and "it looks like a dataset (JSON Lines): solve it with `spherecal solve" in err


def test_missing_configuration_file(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope.toml")]) == EXIT_USAGE
    assert "nope.toml: cannot read the configuration" in capsys.readouterr().err


@pytest.mark.parametrize("fail_at, shots_taken", [(1, False), (4, True)], ids=["first-shot", "fourth-shot"])
def test_a_device_failure_prints_the_command_that_goes_on(sim_config, monkeypatch, capsys, fail_at, shots_taken):
    """A failure mid-acquisition names the command that continues the run; before the
    first shot too, where the journal holds the plan only (the same command again would be
    refused: the journal is never overwritten), and that command, run as printed, ends it."""
    import spherecal.motion.acquisition as acq
    from spherecal.core.errors import DeviceError

    calls = {"n": 0}
    real = acq.take_shot

    def failing(*a, **k):
        calls["n"] += 1
        if calls["n"] == fail_at:
            raise DeviceError("simulated sensor: no frame within 1 s")
        return real(*a, **k)

    monkeypatch.setattr(acq, "take_shot", failing)
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_DEVICE
    err = capsys.readouterr().err
    assert "no frame within 1 s" in err
    out = cfg.parent / "out"
    resume = f"spherecal calibrate {cfg} --out {out} --resume"
    assert (f"continue with {resume}" in err) == shots_taken, err
    assert (f"no shot was taken yet; start again with {resume}" in err) == (not shots_taken), err
    assert len(dataio.read_dataset(out / "journal.jsonl").observations) == fail_at - 1
    # the command printed, run as it is, continues the same run to its end
    monkeypatch.setattr(acq, "take_shot", real)
    assert main([*resume.split()[1:], "--no-report"]) == EXIT_OK
    assert (out / "result.json").exists()
    assert len(dataio.read_dataset(out / "journal.jsonl").observations) == 40


def test_resume_of_a_finished_run_says_where_an_interrupted_one_is(sim_config, tmp_path, capsys):
    """`--resume` without `--out` opens the default folder; when that holds a finished run
    but this configuration's interrupted run was given a folder of its own (a journal with
    shots, no result), it says where that run is and prints the command to continue it.
    Another configuration's interrupted run is not named."""
    cfg = sim_config()
    assert main(["calibrate", str(cfg), "--no-report"]) == EXIT_OK
    journal = (tmp_path / "out" / "journal.jsonl").read_text().splitlines(keepends=True)
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / "journal.jsonl").write_text("".join(journal[:12]))  # the header and some shots
    other = tmp_path / "other"
    other.mkdir()
    header = json.loads(journal[0])
    header["provenance"]["config"] = str(tmp_path / "another.toml")
    (other / "journal.jsonl").write_text(json.dumps(header) + "\n" + "".join(journal[1:12]))
    capsys.readouterr()
    assert main(["calibrate", str(cfg), "--resume", "--no-report"]) == EXIT_OK
    said = capsys.readouterr().out
    assert "holds a finished run" in said and "nothing to resume" in said
    assert (f"an interrupted run of this configuration is in {cut.resolve()}: continue it with spherecal calibrate "
            f"{cfg} --out {cut.resolve()} --resume") in said, said
    assert str(other) not in said
