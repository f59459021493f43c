"""How long an acquisition took, in the time of the clock it ran on: a simulated run's
moves, settles and shots in simulated seconds (no real waiting), reported as profiles a
minute of robot time."""

import time

import numpy as np
import pytest

from spherecal.config import AcquisitionConfig
from spherecal.core.models import Pose, Profile
from spherecal.io import dataset as dataio
from spherecal.motion.acquisition import Target, WallClock, acquire, robot_time_line
from spherecal.sim.timeline import SimClock

MOVE_S, SHOT_S = 1.25, 0.002


class _Arm:
    """Every move takes MOVE_S of the simulated clock."""

    def __init__(self, clock):
        self.clock, self.pose = clock, None

    def move_linear(self, pose, speed_mm_s):
        self.pose = pose
        self.clock.advance(MOVE_S)

    def read_flange_pose(self):
        return self.pose

    def read_joints_deg(self):
        return None


class _Sensor:
    """Every shot takes SHOT_S of the simulated clock."""

    def __init__(self, clock):
        self.clock = clock

    def read_profile(self):
        self.clock.advance(SHOT_S)
        y = np.linspace(-8.0, 8.0, 40)
        return Profile(y_mm=y, z_mm=-20.0 - 0.01 * y**2)


def _targets(n):
    return [Target(index=i, station="S1", pose=Pose(translation_mm=[900.0 + 5 * i, 0.0, 800.0],
                                                    quaternion_wxyz=[0.0, 0.0, 1.0, 0.0]),
                   first_of_station=i == 0, speed_mm_s=50.0) for i in range(n)]


def test_the_acquisitions_robot_time_is_its_moves_settles_and_shots_in_simulated_seconds(tmp_path):
    clock = SimClock(100.0)
    acq = AcquisitionConfig(sphere_centre_mm=[1000.0, 0.0, 500.0], settle_s=3.0,
                            workspace={"min_mm": [0.0, -500.0, 0.0], "max_mm": [2000.0, 500.0, 1500.0]})
    wall = time.monotonic()
    with dataio.DatasetWriter(tmp_path / "journal.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.1) as writer:
        rep = acquire(_Arm(clock), _Sensor(clock), _targets(4), writer, acq, log=lambda m: None, clock=clock)
    assert time.monotonic() - wall < 2.0  # four settles of 3 s, none of them waited in real time
    assert rep.taken == 4 and rep.simulated_time
    assert rep.robot_time_s == pytest.approx(4 * (MOVE_S + 3.0 + SHOT_S), rel=1e-12)
    assert rep.robot_time_line() == "4 profiles in 17.0 s of simulated robot time, 14.1 profiles a minute"


def test_the_wall_clock_says_it_is_not_simulated():
    assert not WallClock().simulated
    assert robot_time_line(10, 20.0, False) == "10 profiles in 20.0 s of robot time (wall clock), 30.0 profiles a minute"
