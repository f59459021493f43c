"""A recording whose poses were computed (the programmed line of a controller that
cannot stream), not measured: the result says so, the terminal and the report show it,
and the profiles next to the samples the stream marks as on a speed ramp are left out
and named, never mapped."""

from dataclasses import replace

import numpy as np

from spherecal.config import CalibrationOptions, OnTheFlyPlan, StreamSimSettings
from spherecal.core.streams import POSES_ASSUMED_KEY, PROGRAMMED_LINE_ASSUMPTION
from spherecal.estimation.on_the_fly import solve_recording
from spherecal.report.assess import verdict
from spherecal.report.html.sections import identity_html
from spherecal.report.terminal import timing_lines
from spherecal.sim import standard_cell
from spherecal.sim.streams import simulate_recording
from reference_sensor import reference_fov

TEXT = PROGRAMMED_LINE_ASSUMPTION + " (test)"


def _recording():
    cell = standard_cell("eye_in_hand", seed=1, fov=reference_fov())
    settings = StreamSimSettings(sensor={"rate_hz": 60.0}, seed=1,
                                 pose={"translation_noise_mm": 0.0, "rotation_noise_deg": 0.0})
    return simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05, stations=3), settings)


def _ramps(poses) -> np.ndarray:
    """The first and last fifth of every sweep's samples, as a computed stream marks its ramps."""
    ramp = np.zeros(poses.n, dtype=bool)
    for k in np.unique(poses.sweep[poses.sweep >= 0]):
        idx = np.flatnonzero(poses.sweep == k)
        cut = len(idx) // 5
        ramp[idx[:cut]] = ramp[idx[-cut:]] = True
    return ramp


def test_computed_poses_are_said_in_the_result_and_their_ramps_left_out():
    rec = _recording()
    ramp = _ramps(rec.poses)
    rec = replace(rec, poses=replace(rec.poses, on_ramp=ramp, assumption=TEXT))
    assert rec.poses_assumption == TEXT
    result = solve_recording(rec, CalibrationOptions()).result
    assert result.timing.poses_assumed == TEXT
    on_ramp = [f for f in result.flagged if "speed ramp" in f.reason]
    assert on_ramp and all("left out" in f.reason for f in on_ramp)
    assert any("NOT MEASURED" in line and TEXT in line for line in timing_lines(result.timing))
    assert any(TEXT in text for _, text in verdict(result).reasons)
    assert "not measured" in identity_html(result) and "programmed line" in identity_html(result)
    offset_error_ms = result.timing.offset_ms - 1e3 * rec.provenance["true_offset_s"]
    assert abs(offset_error_ms) < 0.02


def test_a_measured_stream_says_nothing_of_it():
    rec = _recording()
    assert rec.poses_assumption is None and rec.poses.on_ramp is None
    assert not rec.poses.ramp_at(rec.poses.t_robot_s).any()  # no ramp marks: nothing left out for them


def test_the_stream_form_keeps_the_assumption(tmp_path):
    from spherecal.io.streams import read_recording, write_recording

    rec = _recording()
    rec = replace(rec, poses=replace(rec.poses, assumption=TEXT))
    write_recording(tmp_path / "r.jsonl", rec)
    back = read_recording(tmp_path / "r.jsonl")
    assert back.provenance[POSES_ASSUMED_KEY] == TEXT and back.poses_assumption == TEXT
