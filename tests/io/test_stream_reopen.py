"""Continuing an interrupted stream recording: what was written stays, a line cut by the
interruption is dropped, and what is appended must continue the file."""

import numpy as np
import pytest

from spherecal.core.errors import InputError
from spherecal.core.streams import SweepInfo
from spherecal.io.streams import RecordingWriter, TruncatedFileWarning, read_recording, reopen_recording

SWEEPS = [SweepInfo("S1", 50.0, (1.0, 0.0, 0.0)), SweepInfo("S1", 50.0, (-1.0, 0.0, 0.0))]
Q = np.tile([1.0, 0.0, 0.0, 0.0], (3, 1))


def poses(t0):
    t = t0 + np.array([0.0, 0.004, 0.008])
    return t, np.column_stack([t, t, t]), Q, np.zeros((3, 6)), np.arange(3) + int(t0 * 1000)


def started(path):
    out = RecordingWriter(path, mounting="eye_in_hand", sphere_radius_mm=19.05, sweeps=SWEEPS,
                          clocks={"robot": "r", "sensor": "s"})
    out.add_poses(*poses(1.0))
    out.add_profile(5.0, [[0.0, -20.0], [1.0, -20.1]], frame=7, sweep=0)
    out.close()


def test_a_reopened_recording_continues_after_a_cut_last_line(tmp_path):
    path = tmp_path / "rec.jsonl"
    started(path)
    with open(path, "ab") as fh:
        fh.write(b'{"profile": {"t_sensor_s": 5.01, "fra')  # killed while writing
    with pytest.warns(TruncatedFileWarning, match="line 4 is incomplete"):
        out = reopen_recording(path)
    with out:
        out.add_poses(*poses(2.0))
        out.add_profile(6.0, [[2.0, -19.0]], frame=9, sweep=1)
    rec = read_recording(path)
    assert rec.poses.n == 6 and rec.profiles.t_sensor_s.tolist() == [5.0, 6.0]
    assert rec.profiles.sweep.tolist() == [0, 1] and rec.profiles.frame.tolist() == [7, 9]
    assert rec.sweeps == SWEEPS and rec.poses.joints_deg.shape == (6, 6)


def test_a_reopened_recording_refuses_stamps_that_do_not_continue_it(tmp_path):
    path = tmp_path / "rec.jsonl"
    started(path)
    with reopen_recording(path) as out:
        with pytest.raises(InputError, match="t_robot_s"):
            out.add_poses(*poses(0.5))  # before the last pose sample: another clock, or a reset one
        with pytest.raises(InputError, match="frame"):
            out.add_profile(7.0, [[0.0, -20.0]], sweep=1)  # the frame counter given before, missing now
    assert read_recording(path).poses.n == 3  # the refused calls wrote nothing
