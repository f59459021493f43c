"""A station's shots share one arm configuration: a shot reached with a joint more than
90 deg from the station's shot before it (a resumed run coming from elsewhere, the
other wrist solution) is kept and said as a warning, its joints named."""

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.motion.acquisition import Target, acquire, configuration_change
from spherecal.config import AcquisitionConfig
from spherecal.core.models import Observation, Pose, Profile

WRIST = [10.4, 39.6, 47.3, -178.2, -46.1, 144.3]
FLIPPED = [10.4, 39.6, 47.3, 1.8, 46.1, -35.7]  # the same flange pose, the other wrist solution


@pytest.mark.parametrize("joints, before, expected", [
    (WRIST, WRIST, None),
    ([179.0, 0, 0, 0, 0, 0], [-179.0, 0, 0, 0, 0, 0], None),  # 2 deg the short way round
    ([100.0, 0, 0, 0, 0, 0], [0.0, 0, 0, 0, 0, 0], "joint 1 moved 100.0 deg"),
    (FLIPPED, WRIST, "joint 4 moved 180.0 deg, joint 5 92.2 deg, joint 6 180.0 deg"),
])
def test_configuration_change(joints, before, expected):
    assert configuration_change(joints, before) == expected


class _Arm:
    """Reports the pose it was sent to, and the joints ``joints[k]`` at its k-th move."""

    def __init__(self, joints):
        self.joints, self.moves, self.pose = joints, 0, None

    def move_linear(self, pose, speed_mm_s):
        self.pose, self.moves = pose, self.moves + 1

    def read_flange_pose(self):
        return self.pose

    def read_joints_deg(self):
        return np.array(self.joints[self.moves - 1], float)


class _Sensor:
    def read_profile(self):
        y = np.linspace(-8.0, 8.0, 40)
        return Profile(y_mm=y, z_mm=-20.0 - 0.01 * y**2)


def _targets(n, station="S4"):
    return [Target(index=i, station=station, pose=Pose(translation_mm=[900.0 + 5 * i, 0.0, 800.0],
                                                       quaternion_wxyz=[0.0, 0.0, 1.0, 0.0]),
                   first_of_station=i == 0, speed_mm_s=50.0) for i in range(n)]


def _run(tmp_path, joints, done=(), taken=()):
    acq = AcquisitionConfig(sphere_centre_mm=[1000.0, 0.0, 500.0],
                            workspace={"min_mm": [0.0, -500.0, 0.0], "max_mm": [2000.0, 500.0, 1500.0]})
    logs = []
    with dataio.DatasetWriter(tmp_path / "journal.jsonl", mounting="eye_in_hand", sphere_radius_mm=19.1) as writer:
        rep = acquire(_Arm(joints), _Sensor(), _targets(3), writer, acq, set(done), log=logs.append, taken=taken)
    return rep, [m for m in logs if m.startswith("warning:")]


def test_a_station_in_one_configuration_raises_no_warning(tmp_path):
    rep, warnings = _run(tmp_path, [WRIST, WRIST, WRIST])
    assert rep.taken == 3 and warnings == []


def test_a_resumed_shot_in_the_other_wrist_solution_is_kept_and_named(tmp_path):
    """The journal's station S4 was taken with the wrist at -178/-46/144; the resumed run
    reaches target 2 with the other solution: kept (the journal holds it) and named."""
    before = [Observation(index=i, station="S4", base_from_flange=_targets(3)[i].pose, joints_deg=tuple(WRIST),
                          profile=_Sensor().read_profile(), target=i) for i in (0, 1)]
    rep, warnings = _run(tmp_path, [FLIPPED], done={0, 1}, taken=before)
    assert rep.taken == 1
    assert len(warnings) == 1
    assert warnings[0].startswith("warning: target 2 (station S4) was reached with the arm in another configuration "
                                  "than the station's shot before it (joint 4 moved 180.0 deg, joint 5 92.2 deg")
    assert "[10.4, 39.6, 47.3, 1.8, 46.1, -35.7] deg" in warnings[0]
