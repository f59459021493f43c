"""A sweep on the fly cut by Ctrl-C: both streams are stopped, nothing of the sweep is
written, and one line names the sweep, so that the devices' own lines that may follow
are read against it (and the run's "interrupted ... --resume" line after it)."""

from pathlib import Path

import pytest

from spherecal.config import load_config
from spherecal.devices.pose_streaming import PoseStreamCounts
from spherecal.core.models import Pose
from spherecal.core.streams import SweepInfo
from spherecal.motion.on_the_fly import PlannedSweep, SweepJournal, acquire_sweeps


EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sim-on-the-fly-eye-in-hand.toml"


class _Robot:
    """Ctrl-C arrives during the first sweep's MoveL (its move to the start goes)."""

    def __init__(self):
        self.streaming = False
        self.stopped = 0

    def move_linear(self, pose, speed_mm_s):
        if self.streaming:
            raise KeyboardInterrupt

    def start_pose_stream(self):
        self.streaming = True

    def stop_pose_stream(self):
        self.streaming = False
        self.stopped += 1
        return None

    def pose_stream_counts(self):
        return PoseStreamCounts()


class _Sensor:
    def __init__(self):
        self.stopped = 0

    def start_profile_stream(self, rate_hz=None):
        pass

    def stop_profile_stream(self):
        self.stopped += 1
        return None


class _Writer:
    def __getattr__(self, name):
        raise AssertionError(f"nothing of an interrupted sweep is written ({name})")


def test_a_sweep_cut_by_ctrl_c_is_named_and_nothing_of_it_is_written(tmp_path):
    acq = load_config(EXAMPLE).config.acquisition
    start = Pose.from_xyz_quat_wxyz([1000.0, 0.0, 500.0], [0.0, 1.0, 0.0, 0.0])  # (w, x, y, z)
    end = Pose.from_xyz_quat_wxyz([1060.0, 0.0, 500.0], [0.0, 1.0, 0.0, 0.0])
    sweeps = [PlannedSweep(0, "S1", start, end, 50.0, SweepInfo("S1", 50.0, (1.0, 0.0, 0.0)), False),
              PlannedSweep(1, "S1", end, start, 50.0, SweepInfo("S1", 50.0, (-1.0, 0.0, 0.0)), True)]
    robot, sensor, said = _Robot(), _Sensor(), []
    with pytest.raises(KeyboardInterrupt):
        acquire_sweeps(robot, sensor, sweeps, SweepJournal(_Writer(), tmp_path / "sweeps.jsonl"), acq, log=said.append)
    assert said == ["sweep 0 (station S1, forth at 50 mm/s): interrupted; none of its data is written (--resume "
                    "takes it again)"]
    assert (robot.stopped, sensor.stopped) == (1, 1) and not (tmp_path / "sweeps.jsonl").exists()
