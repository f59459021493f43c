"""``calibrate`` with ``[acquisition] mode = "on_the_fly"`` on the embedded default: the
example end to end, resume after a kill, stream faults stopping the run after the move
with the journal kept and the sweep named, a sweep refused before anything moves, and the
mode refused for devices that cannot stream."""

import contextlib
import json
import re

import numpy as np
import pytest

from spherecal.app import calibrate_on_the_fly as otf_app
from spherecal.app.calibrate import run_calibrate
from spherecal.cli import EXIT_DATA, EXIT_DEVICE, EXIT_OK, EXIT_RED, main
from spherecal.config import load_config
from spherecal.core import geometry as geo
from spherecal.core.errors import ConfigError, InputError
from spherecal.core.models import Pose
from spherecal.io import dataset as dataio
from spherecal.io.streams import read_recording
from spherecal.motion.on_the_fly import SweepJournal, SweepStreamError
from spherecal.sim.live import true_time_relation

EXAMPLE = "sim-on-the-fly-eye-in-hand.toml"
#: Three stations, one direction: 12 sweeps, for the runs that stop early.
SMALL = {r"^speeds_mm_s = .*$": "speeds_mm_s = [50.0, 100.0]\nstations = 3\ndirections_in_sensor = [[1.0, 0.0, 0.0]]"}
#: Three stations, both directions, one speed: 12 sweeps that solve (with --force: three
#: stations leave the translation uncertain against the arm's error, RED).
RESUMABLE = {r"^speeds_mm_s = .*$": "speeds_mm_s = [100.0]\nstations = 3"}
#: Stop-and-go on the same stations of the embedded default: 40 profiles in 32.2 s of
#: simulated robot time (tests/cli/test_calibrate.py, docs/architecture.md).
STOP_AND_GO_PER_MINUTE = 74.6


@pytest.fixture
def opened(monkeypatch):
    """The devices each run opens, as (robot, sensor), in order."""
    devices = []
    real = otf_app.open_devices

    @contextlib.contextmanager
    def spy(*args, **kwargs):
        with real(*args, **kwargs) as pair:
            devices.append(pair)
            yield pair

    monkeypatch.setattr(otf_app, "open_devices", spy)
    return devices


def run(cfg, log, **kw):
    return run_calibrate(load_config(cfg), report=False, yes=True, log=log, **kw)


def after_sweep(k, action):
    """A log that calls ``action()`` once, when sweep ``k`` (its index, from 0) has been taken."""
    lines = []

    def log(msg):
        lines.append(str(msg))
        if str(msg).startswith(f"sweep {k} ("):
            action()

    log.lines = lines
    return log


@pytest.mark.slow
def test_the_example_finds_the_clock_offset_within_its_uncertainty_and_says_the_truth(sim_config, capsys):
    cfg = sim_config(EXAMPLE)
    assert main(["calibrate", str(cfg), "--yes", "--no-report"]) == EXIT_OK
    out = cfg.parent / "out"
    printed = capsys.readouterr().out
    result = dataio.read_result(out / "result.json")
    recording = read_recording(out / "journal.stream.jsonl")
    truth = true_time_relation(recording.provenance["simulated_clocks"], recording.t_sensor0_s)
    error_ms = result.timing.offset_ms - 1e3 * truth[0]
    assert abs(error_ms) < 3 * result.timing.offset_std_ms and result.timing.offset_std_ms < 0.1
    assert f"clock offset error {error_ms:+.4f} ms" in printed and f"true {1e3 * truth[0]:.4f} ms" in printed
    # profiles at the sphere's edge, which sweeps on the fly cross by design, are said to be expected
    assert "cuts the sphere near its edge" in printed and "expected and left out" in printed
    assert "sweep_fraction" not in printed
    # every sweep's line, no losses on a clean stream; the robot time on the simulated clock
    finished = [json.loads(x) for x in (out / "journal.sweeps.jsonl").read_text().splitlines()]
    assert [r["sweep"] for r in finished] == list(range(len(recording.sweeps))) and len(finished) == 32
    assert sum(r["profiles"] for r in finished) == recording.profiles.n
    timed = re.search(r"acquisition: (\d+) profiles in (\d+\.\d) s of simulated robot time, (\d+\.\d) profiles a "
                      r"minute on the fly", (out / "run.log").read_text())
    assert timed and float(timed.group(3)) > 10 * STOP_AND_GO_PER_MINUTE
    true = Pose.model_validate(recording.provenance["true_transform"])
    assert np.linalg.norm(true.translation - result.transform.translation) < 3 * np.linalg.norm(result.std_translation_mm)
    assert geo.rotation_angle_deg(true.rotation_matrix, result.transform.rotation_matrix) < 3 * np.linalg.norm(
        result.std_rotation_deg)
    # solve of the journal: the run's settings (the station model, not solve's "auto"), its answer and truth line
    again = cfg.parent / "solved"
    assert main(["solve", str(out / "journal.stream.jsonl"), "--out", str(again), "--no-report"]) == EXIT_OK
    solved = capsys.readouterr()
    assert 'settings from the recording (the run\'s [calibration]): ' in solved.err
    assert 'robot_error_model = "station"' in solved.err
    resolved = dataio.read_result(again / "result.json")
    assert resolved.transform.translation == pytest.approx(result.transform.translation, abs=1e-9)
    assert resolved.timing.offset_ms == pytest.approx(result.timing.offset_ms, abs=1e-9)
    assert f"clock offset error {error_ms:+.4f} ms" in solved.out and f"true {1e3 * truth[0]:.4f} ms" in solved.out


@pytest.mark.slow
def test_a_killed_run_resumes_at_the_next_sweep_not_in_the_journal(sim_config):
    cfg = sim_config(EXAMPLE, **RESUMABLE)
    out = cfg.parent / "out"

    def kill():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(cfg, after_sweep(4, kill))
    assert sorted(SweepJournal.finished(out / "journal.sweeps.jsonl")) == [0, 1, 2, 3, 4]
    before = read_recording(out / "journal.stream.jsonl")
    assert set(before.profiles.sweep.tolist()) == {0, 1, 2, 3, 4}
    with pytest.raises(InputError, match="--resume"):  # never continued without asking
        run(cfg, lambda _: None)
    log = after_sweep(-1, lambda: None)
    outcome = run(cfg, log, resume=True, force=True)
    assert not [x for x in log.lines if re.match(r"sweep [0-4] \(", x)]  # those five were not taken again
    assert "resuming" in " ".join(log.lines) and "sweep 5 (station S2, back at 100 mm/s)" in " ".join(log.lines)
    after = read_recording(out / "journal.stream.jsonl")
    assert set(after.profiles.sweep.tolist()) == set(range(12))
    assert after.profiles.t_sensor_s[:before.profiles.n].tolist() == before.profiles.t_sensor_s.tolist()
    assert (out / "result.json").exists() and outcome.solution.result.timing is not None
    truth = true_time_relation(after.provenance["simulated_clocks"], after.t_sensor0_s)
    t = outcome.solution.result.timing
    assert abs(t.offset_ms - 1e3 * truth[0]) < 4 * t.offset_std_ms


def test_a_stalled_pose_stream_stops_the_run_after_the_move_naming_the_sweep(sim_config, opened):
    cfg = sim_config(EXAMPLE, **SMALL)

    def stall():
        opened[0][0].simulator.controller.egm.set_faults(stall_after=60)  # sweep 1 goes silent mid-move

    log = after_sweep(0, stall)
    with pytest.raises(SweepStreamError, match=r"sweep 1 \(station S1, back at 50 mm/s\): the pose stream") as err:
        run(cfg, log)
    robot, _ = opened[0]
    assert err.value.stream == "pose" and err.value.taken.pose_samples == 60
    moved_to = robot.simulator.controller.nominal_flange_pose().translation  # the move was finished
    assert moved_to == pytest.approx(err.value.sweep.end.translation, abs=0.05)
    out = cfg.parent / "out"
    assert sorted(SweepJournal.finished(out / "journal.sweeps.jsonl")) == [0]  # sweep 1 is taken again
    kept = read_recording(out / "journal.stream.jsonl")
    assert set(kept.profiles.sweep.tolist()) == {0, 1}  # what came before the fault is kept
    assert not (out / "result.json").exists()


def test_a_hung_sensor_stream_stops_the_run_keeping_its_frames(sim_config, opened, monkeypatch, capsys):
    cfg = sim_config(EXAMPLE, **SMALL)
    taken = []
    real = otf_app.acquire_sweeps

    def hang_in_sweep_1(robot, sensor, sweeps, journal, acq, done, log, **kw):
        return real(robot, sensor, sweeps, journal, acq, done, after_sweep(0, lambda: (
            taken.append(1), sensor._backend.hang_stream(after_frames=30))), **kw)

    monkeypatch.setattr(otf_app, "acquire_sweeps", hang_in_sweep_1)
    assert main(["calibrate", str(cfg), "--yes", "--no-report"]) == EXIT_DEVICE
    said = capsys.readouterr().err
    assert re.search(r"sweep 1 \(station S1, back at 50 mm/s\): the profile stream failed during the sweep: .*stall",
                     said)
    assert "30 profiles (0 frames lost" in said and "journal.stream.jsonl): continue with" in said and "--resume" in said
    kept = read_recording(cfg.parent / "out" / "journal.stream.jsonl")
    assert int((kept.profiles.sweep == 1).sum()) == 30 and taken


def test_lost_frames_and_samples_are_counted_per_sweep_written_and_said(sim_config, opened):
    cfg = sim_config(EXAMPLE, **SMALL)

    def lose():
        robot, sensor = opened[0]
        sensor._backend.drop_frames(3, after=20)
        start = robot.start_pose_stream

        def start_then_drop():  # four samples lost once the stream runs
            start()
            robot.simulator.controller.egm.set_faults(drop_next=4)
            robot.start_pose_stream = start

        robot.start_pose_stream = start_then_drop

    stop = after_sweep(2, lambda: (_ for _ in ()).throw(KeyboardInterrupt))
    log = after_sweep(0, lose)

    def both(msg):
        log(msg)
        stop(msg)

    with pytest.raises(KeyboardInterrupt):
        run(cfg, both)
    rows = SweepJournal.finished(cfg.parent / "out" / "journal.sweeps.jsonl")
    assert (rows[1]["frames_lost"], rows[1]["pose_lost"]) == (3, 4)
    assert (rows[0]["frames_lost"], rows[0]["pose_lost"], rows[2]["frames_lost"]) == (0, 0, 0)
    assert any(x.startswith("sweep 1 (") and "(4 lost, 0 late)" in x and "(3 frames lost" in x for x in log.lines)
    # the terminal numbers the sweeps as the journal does (from 0)
    assert [int(x.split()[1]) for x in log.lines if re.match(r"sweep \d+ \(station", x)] == sorted(rows) == [0, 1, 2]
    assert "sweeps numbered 0 to 11, as in the journal" in log.lines[0]


def test_a_sweep_outside_the_workspace_is_refused_before_anything_moves(sim_config, opened):
    cfg = sim_config(EXAMPLE, **{r"^max_mm = \[1600.0, 800.0, 1400.0\]$": "max_mm = [1168.0, 800.0, 1400.0]"})
    with pytest.raises(InputError, match=r"the on-the-fly plan breaks the limits; nothing was moved") as err:
        run(cfg, lambda _: None)
    assert re.search(r"\d+ targets in \d+ sweeps \(target \d+ \(station S1, sweep 0\), .*\): the first at "
                     r"\[1171.5, 186.0, 584.0\] mm is outside", str(err.value))
    assert not opened  # refused before the devices were opened
    assert not (cfg.parent / "out" / "journal.stream.jsonl").exists()


def test_the_mode_is_refused_for_a_robot_that_does_not_stream(sim_config, opened, capsys):
    cfg = sim_config(EXAMPLE, **{r"^\[robot\.egm\]\nport = 0\nstall_timeout_s = 1.0$": ""})
    assert main(["calibrate", str(cfg), "--yes", "--no-report"]) == EXIT_DATA
    said = capsys.readouterr().err
    assert "mode = \"on_the_fly\" needs a robot that streams its pose" in said
    assert "robot type 'abb_irb2400' is not configured to stream its pose" in said and "[robot.egm]" in said
    robot, _ = opened[0]
    assert robot.simulator.controller.moves == 0
    assert not (cfg.parent / "out" / "journal.stream.jsonl").exists()


def test_step_mode_is_refused_on_the_fly_before_anything_opens(sim_config, opened):
    cfg = sim_config(EXAMPLE)
    with pytest.raises(ConfigError, match="--step .* does not stop between sweeps"):
        run(cfg, lambda _: None, step=True)
    assert not opened


@pytest.mark.slow
def test_poses_from_the_programmed_line_are_said_and_no_clock_truth_is_claimed(sim_config, capsys):
    """A controller without EGM: the poses are computed along each move's programmed line,
    stamped by a clock of the robot's program. The journal, the result and the terminal
    say the poses were not measured; the simulated controller's clock is not that clock,
    so no truth of the offset is printed (it would be seconds off and look like a failure)."""
    cfg = sim_config(EXAMPLE, **RESUMABLE, **{r"^\[robot.egm\]\nport = 0\nstall_timeout_s = 1.0$":
                                             '[robot.pose_stream]\nmode = "programmed_line"'})
    code = main(["calibrate", str(cfg), "--yes", "--no-report", "--force"])
    printed = capsys.readouterr().out
    assert code in (EXIT_OK, EXIT_RED)  # (three stations of one speed: RED against the arm's error, written with --force)
    out = cfg.parent / "out"
    recording = read_recording(out / "journal.stream.jsonl")
    assert recording.provenance["poses_assumed"].startswith("poses from the programmed line, not measured")
    assert dataio.read_result(out / "result.json").timing.poses_assumed.startswith("poses from the programmed line")
    assert "robot poses NOT MEASURED" in printed
    assert "simulated truth: error" in printed and "clock offset error" not in printed


@pytest.mark.slow
def test_a_run_resumed_within_a_station_keeps_the_arms_configuration(sim_config):
    """Killed after the second sweep of station S3 and resumed: the next sweep is taken in
    the arm's configuration of the sweeps before it (the simulated arm stands where the
    kill left it, as a real one does), not in the other wrist solution reached from the
    controller's home, which carries another geometric error into one station."""
    cfg = sim_config(EXAMPLE)
    out = cfg.parent / "out"

    def kill():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(cfg, after_sweep(18, kill))
    before = read_recording(out / "journal.stream.jsonl")
    with pytest.raises(KeyboardInterrupt):
        run(cfg, after_sweep(19, kill), resume=True)
    q = read_recording(out / "journal.stream.jsonl").poses.joints_deg
    last_before, first_after = q[before.poses.n - 1], q[before.poses.n]
    assert np.abs(first_after - last_before).max() < 20.0, (last_before, first_after)



@pytest.mark.slow
def test_eye_to_hand_with_the_arms_error_ends_within_its_stated_error(sim_config, capsys):
    """The eye-to-hand example on the fly, robot_error_model "auto" on an arm whose geometry
    is off its model: the streamed joints select the kinematic model, whose prior factor
    jitters from step to step with a recording's piecewise-smooth cost (seed 2 of this cell
    wandered 0.05-0.2 mm a step for fifty steps and ended RED 3.9 mm off). The fit
    converges, names the arm as the limit, and the truth lies within its stated error."""
    cfg = sim_config("sim-on-the-fly-eye-to-hand.toml")
    assert main(["calibrate", str(cfg), "--yes", "--no-report"]) == EXIT_OK
    printed = capsys.readouterr().out
    result = dataio.read_result(cfg.parent / "out" / "result.json")
    assert result.robot_error is not None and result.robot_error.model == "kinematic"
    assert result.diagnostics.refinement["converged"]
    assert "Robot error dominates" in printed and "did not converge" not in printed
    expected = re.search(r"expected error (\d+\.\d+) mm \(k = 2\)", printed)
    recording = read_recording(cfg.parent / "out" / "journal.stream.jsonl")
    true = Pose.model_validate(recording.provenance["true_transform"])
    error_mm = float(np.linalg.norm(true.translation - result.transform.translation))
    assert expected and 0.3 < error_mm < float(expected.group(1))
