"""`spherecal solve` of a recording (dataset format version 3, the stream form): the clock
relation in the terminal, result.json and the report, against the simulated truth."""

import json

import pytest

from spherecal.cli import EXIT_OK, main
from spherecal.config import OnTheFlyPlan, StreamSimSettings
from spherecal.io.streams import write_recording
from spherecal.sim import standard_cell
from spherecal.sim.streams import simulate_recording
from reference_sensor import reference_fov


@pytest.mark.slow
def test_solve_a_recording_prints_and_writes_the_clock_relation(tmp_path, capsys):
    cell = standard_cell("eye_to_hand", seed=5, fov=reference_fov())
    rec = simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05),
                             StreamSimSettings(sensor={"rate_hz": 100.0}, seed=5))
    path = tmp_path / "run.recording.jsonl"
    write_recording(path, rec)
    out = tmp_path / "res"
    assert main(["solve", str(path), "--out", str(out)]) == EXIT_OK
    printed = capsys.readouterr().out
    assert "clock relation: t_robot = t_sensor + offset + drift" in printed
    assert "identified: the sweeps separate the clock offset" in printed
    assert "clock offset error" in printed  # the simulated truth line
    timing = json.loads((out / "result.json").read_text())["timing"]
    true_ms = 1e3 * rec.provenance["true_offset_s"]
    assert abs(timing["offset_ms"] - true_ms) < max(4 * timing["offset_std_ms"], 0.05)
    assert {"offset_ms", "offset_std_ms", "drift_ppm", "drift_std_ppm"} <= set(timing)
    assert (out / "report.html").exists()


@pytest.mark.slow
def test_a_recording_of_the_other_mounting_is_named_as_such(tmp_path, capsys):
    """An eye-in-hand recording whose header says eye-to-hand: the fit is absurd, and the
    verdict names the mounting (the recording solved as eye-in-hand fits)."""
    from dataclasses import replace

    cell = standard_cell("eye_in_hand", seed=4, fov=reference_fov())
    rec = simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05, stations=3),
                             StreamSimSettings(sensor={"rate_hz": 25.0}, seed=4))
    path = tmp_path / "wrong.recording.jsonl"
    write_recording(path, replace(rec, mounting="eye_to_hand"))
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    printed = capsys.readouterr().out
    assert code == 7
    assert "likely cause: the recording's mounting is probably wrong: it says eye_to_hand" in printed


@pytest.mark.slow
def test_a_recording_whose_fit_breaks_down_names_the_mounting(tmp_path, capsys):
    """An eye-to-hand recording whose header says eye-in-hand: the fit breaks down before
    any result, and the error names the mounting (the recording solved as eye-to-hand
    fits), not only a list of suspects."""
    from dataclasses import replace

    cell = standard_cell("eye_to_hand", seed=4, fov=reference_fov())
    rec = simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05, stations=3),
                             StreamSimSettings(sensor={"rate_hz": 25.0}, seed=4))
    path = tmp_path / "wrong.recording.jsonl"
    write_recording(path, replace(rec, mounting="eye_in_hand"))
    code = main(["solve", str(path), "--out", str(tmp_path / "res"), "--no-report"])
    err = capsys.readouterr().err
    assert code == 3
    assert ("likely cause: the recording's mounting is probably wrong: it says eye_in_hand, but solved as "
            "eye_to_hand the same data fit") in err
    assert not (tmp_path / "res" / "result.json").exists()
