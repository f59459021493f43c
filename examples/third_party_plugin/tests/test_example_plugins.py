"""Tests of the example plugins, written the way a plugin author would write them: with
the fixtures spherecal installs into pytest (``spherecal_host``, ``spherecal_cell``,
``spherecal_context``, the harnesses). Run with ``pytest`` after ``pip install .``."""

import pytest

from spherecal.plugins import ConfigError, DeviceError, InputError

ROBOT = {"type": "example_cartesian"}
SENSOR = {"type": "example_profiler"}


def test_both_types_are_installed(spherecal_host):
    names = {(d.kind, d.name): d.plugin for d in spherecal_host.describe()}
    assert names[("robot", "example_cartesian")] == "example_cartesian"
    assert names[("sensor", "example_profiler")] == "example_profiler"


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_robot_honours_the_protocol(spherecal_host, spherecal_context, spherecal_robot_harness):
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    report = spherecal_robot_harness.check(robot)
    assert report.max_move_error_mm == 0.0


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_sensor_honours_the_protocol(spherecal_host, spherecal_context, spherecal_sensor_harness):
    sensor = spherecal_host.create_sensor({**SENSOR, "order": "ascending_y"}, spherecal_context)
    report = spherecal_sensor_harness.check(sensor)
    assert report.n_profiles >= 4


def test_robot_refuses_a_target_outside_its_workspace(spherecal_host, spherecal_context, spherecal_stations):
    low_box = {"min_mm": [0.0, -1000.0, 0.0], "max_mm": [2000.0, 1000.0, 100.0]}
    robot = spherecal_host.create_robot({**ROBOT, "workspace": low_box}, spherecal_context)
    target = spherecal_stations[0][1][0]
    box = r"outside the configured workspace box min_mm=\[0.0, -1000.0, 0.0\] max_mm=\[2000.0, 1000.0, 100.0\]"
    with pytest.raises(InputError, match="move_linear: target flange position .* is " + box):
        robot.check_target(target, 50.0)  # the plan check, before the first motion
    before = spherecal_context.cell.current_base_from_flange
    with pytest.raises(InputError, match="target flange position .* is " + box):
        robot.move_linear(target, 50.0)
    assert spherecal_context.cell.current_base_from_flange is before  # nothing moved
    with pytest.raises(InputError, match=r"speed_mm_s = 300.0 exceeds the configured max_speed_mm_s = 250.0"):
        robot.check_move(target, 300.0)


def test_config_errors_name_the_setting(spherecal_host):
    with pytest.raises(ConfigError, match=r"robot\.workspace\.max_mm\[0\]: Input should be a valid number"):
        spherecal_host.validate_robot_config("example_cartesian",
                                             {"workspace": {"min_mm": [0, -1000, 0], "max_mm": ["far", 1000, 1500]}})
    with pytest.raises(ConfigError, match=r"sensor\.decimate: Input should be less than or equal to 16"):
        spherecal_host.validate_sensor_config("example_profiler", {"decimate": 50})


def test_without_a_cell_there_is_no_device(spherecal_host):
    with pytest.raises(DeviceError, match="simulated robot and has no hardware"):
        spherecal_host.create_robot(ROBOT)
