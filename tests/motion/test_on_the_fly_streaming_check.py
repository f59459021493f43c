"""An on-the-fly acquisition refuses a robot or a sensor whose plugin cannot stream,
before anything moves, and names the section of the plugin author's guide that says how
to stream; those sections exist."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from spherecal.core.errors import InputError
from spherecal.motion.on_the_fly import ROBOT_STREAMING_GUIDE, SENSOR_STREAMING_GUIDE, check_streaming

REPO = Path(__file__).resolve().parents[2]


class StopAndGoRobot:
    """A robot of the plain Robot protocol: it moves and reads, it does not stream."""

    def __init__(self):
        self.moves = 0

    def read_flange_pose(self):
        raise AssertionError("not read by the check")

    def read_joints_deg(self):
        return None

    def move_linear(self, base_from_flange, speed_mm_s):
        self.moves += 1

    def close(self):
        pass


class ShotSensor:
    """A sensor of the plain Sensor protocol: profiles on request only."""

    def read_profile(self):
        return None

    def close(self):
        pass


def test_devices_that_cannot_stream_are_refused_naming_the_guides():
    robot = StopAndGoRobot()
    with pytest.raises(InputError, match="nothing was moved") as err:
        check_streaming(robot, ShotSensor(), "acme_arm", "acme_profiler")
    said = str(err.value)
    assert ("robot type 'acme_arm' does not stream its pose (its plugin does not implement PoseStreamingRobot: "
            "docs/writing-a-robot-plugin.md, \"Streaming the pose while the arm moves\")") in said
    assert ("sensor type 'acme_profiler' does not stream profiles (its plugin does not implement "
            "ProfileStreamingSensor: docs/writing-a-sensor-plugin.md, \"Streaming profiles\")") in said
    assert robot.moves == 0


@pytest.mark.parametrize("guide", [ROBOT_STREAMING_GUIDE, SENSOR_STREAMING_GUIDE])
def test_the_sections_the_refusal_names_exist(guide):
    page, title = re.fullmatch(r'(docs/[\w-]+\.md), "(.+)"', guide).groups()
    text = (REPO / page).read_text(encoding="utf-8")
    assert f"\n## {title}\n" in text
    section = text[text.index(f"\n## {title}\n"):]
    assert "PoseStreamingRobot" in section or "ProfileStreamingSensor" in section
