"""The pytest plugin for plugin authors: fixtures and the robot/sensor harnesses.

The harnesses must pass honest simulated devices and fail broken ones with a message
that says what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.errors import DeviceError
from spherecal.models import Pose, Profile
from spherecal.plugins.testing import RobotHarness, SensorHarness, acquire_dataset, pose_error


class CellRobot:
    """An honest robot on the cell; subclasses break one thing each."""

    def __init__(self, cell):
        self.cell = cell

    def move_linear(self, base_from_flange, speed_mm_s):
        if speed_mm_s <= 0:
            raise DeviceError(f"speed_mm_s = {speed_mm_s} must be positive")
        self.cell.move_flange_to(base_from_flange)

    def read_flange_pose(self):
        return self.cell.report_pose(self.cell.current_base_from_flange)

    def read_joints_deg(self):
        return None

    def close(self):
        pass


class OffsetRobot(CellRobot):
    def move_linear(self, base_from_flange, speed_mm_s):
        super().move_linear(Pose.from_rt(base_from_flange.rotation_matrix, base_from_flange.translation + [1, 0, 0]),
                            speed_mm_s)


class XyzwRobot(CellRobot):
    """Reports the quaternion in SciPy's (x, y, z, w) order: a classic."""

    def read_flange_pose(self):
        p = super().read_flange_pose()
        w, x, y, z = p.quaternion_wxyz
        return Pose(translation_mm=p.translation_mm, quaternion_wxyz=(x, y, z, w))


class Reckless(CellRobot):
    def move_linear(self, base_from_flange, speed_mm_s):
        self.cell.move_flange_to(base_from_flange)


class CellSensor:
    def __init__(self, cell, transform=None):
        self.cell = cell
        self.transform = transform or (lambda pts: pts)

    def read_profile(self):
        pts = self.cell.measure_profile()
        if len(pts) == 0:
            return None
        return Profile.from_points(self.transform(pts))

    def close(self):
        pass


def test_cell_fixture_defaults_to_eye_in_hand_and_is_seeded(spherecal_cell):
    from spherecal.sim import standard_cell

    assert spherecal_cell.mounting == "eye_in_hand"
    again = standard_cell("eye_in_hand", seed=0)
    assert np.array_equal(spherecal_cell.rng.normal(size=3), again.rng.normal(size=3))


@pytest.mark.parametrize("spherecal_cell", ["eye_to_hand", {"mounting": "eye_to_hand", "seed": 7}], indirect=True)
def test_cell_fixture_is_parametrisable(spherecal_cell, spherecal_stations, spherecal_context):
    assert spherecal_cell.mounting == "eye_to_hand"
    assert spherecal_context.cell is spherecal_cell
    assert [label for label, _ in spherecal_stations] == ["S1", "S2", "S3", "S4"]
    # the planned targets put the sphere in view
    pose = spherecal_stations[0][1][0]
    assert len(spherecal_cell.ideal_profile(pose)) > 100


def test_host_fixture_is_fresh_each_time(spherecal_host):
    from spherecal.plugins.host import PluginHost

    assert isinstance(spherecal_host, PluginHost)
    assert spherecal_host.registry is not PluginHost(load_entry_points=False).registry


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_robot_harness_passes_an_honest_robot(spherecal_cell, spherecal_robot_harness):
    report = spherecal_robot_harness.check(CellRobot(spherecal_cell))
    assert report.n_moves == 12
    assert report.max_move_error_mm == 0.0
    assert 0 < report.max_report_error_mm < 0.2  # the cell's pose noise, 0.02 mm per axis


@pytest.mark.parametrize(
    "robot_class, message",
    [
        (OffsetRobot, r"move_linear did not land where commanded \(station S1.*1\.000000 mm"),
        (XyzwRobot, r"read_flange_pose\(\) is .* deg from the commanded pose.*quaternion \(w, x, y, z\)\?"),
        (Reckless, r"speed_mm_s=0\.0\) was accepted"),
    ],
)
def test_robot_harness_catches_broken_robots(spherecal_cell, spherecal_robot_harness, robot_class, message):
    with pytest.raises(AssertionError, match=message):
        spherecal_robot_harness.check(robot_class(spherecal_cell))


def test_robot_harness_checks_kinematics_when_given(spherecal_cell, spherecal_robot_harness):
    class JointRobot(CellRobot):
        def read_joints_deg(self):
            return np.zeros(6)

    fk_right = lambda joints: spherecal_cell.current_base_from_flange  # noqa: E731
    report = spherecal_robot_harness.check(JointRobot(spherecal_cell), flange_pose_from_joints=fk_right)
    assert report.max_kinematics_error_mm == 0.0
    with pytest.raises(AssertionError, match=r"forward kinematics of read_joints_deg\(\) = \[0\.0, .*mm from"):
        RobotHarness(spherecal_cell, spherecal_robot_harness.stations).check(
            JointRobot(spherecal_cell), flange_pose_from_joints=lambda joints: Pose.identity())


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_sensor_harness_passes_an_honest_sensor(spherecal_cell, spherecal_sensor_harness):
    report = spherecal_sensor_harness.check(CellSensor(spherecal_cell))
    assert report.n_profiles == 12
    assert 0.005 < report.rms_distance_mm < 0.02  # the cell's point noise, 0.01 mm
    assert report.min_coverage > 0.95


@pytest.mark.parametrize(
    "transform, message",
    [
        (lambda p: p * [-1, 1], r"profile points are more than .* off the sphere"),  # y mirrored
        (lambda p: p * [1, -1], r"off the sphere.*z positive towards the sensor"),  # z flipped
        (lambda p: p / 1000.0, r"off the sphere"),  # metres
        (lambda p: p[: len(p) // 3], r"the profile covers 3\d% of the visible arc"),  # drops points
    ],
)
def test_sensor_harness_catches_broken_sensors(spherecal_cell, spherecal_sensor_harness, transform, message):
    with pytest.raises(AssertionError, match=message):
        spherecal_sensor_harness.check(CellSensor(spherecal_cell, transform))


def test_sensor_harness_wants_none_when_nothing_is_seen(spherecal_cell, spherecal_stations):
    class Stubborn(CellSensor):
        def read_profile(self):
            return super().read_profile() or Profile.from_points([[0.0, 0.0]])

    with pytest.raises(AssertionError, match=r"read_profile\(\) returned Profile with the sphere out of view"):
        SensorHarness(spherecal_cell, spherecal_stations).check(Stubborn(spherecal_cell))


def test_acquire_dataset_takes_one_observation_per_target(spherecal_cell, spherecal_stations):
    from spherecal.plugins.host import PluginHost

    seen, finished = [], []
    plugin = type("P", (), {
        "spherecal_observation_taken": staticmethod(lambda observation: seen.append(observation.index)),
        "spherecal_acquisition_finished": staticmethod(lambda dataset: finished.append(len(dataset.observations))),
    })()
    host = PluginHost(plugins=[("listener", plugin)], load_entry_points=False)
    dataset = acquire_dataset(CellRobot(spherecal_cell), CellSensor(spherecal_cell), spherecal_stations,
                              spherecal_cell.mounting, spherecal_cell.sphere_radius_mm, host=host)
    n_targets = sum(len(poses) for _, poses in spherecal_stations)
    assert len(dataset.observations) == n_targets == 40
    assert seen == list(range(40)) and finished == [40]
    last_target = spherecal_stations[-1][1][-1]
    assert pose_error(dataset.observations[-1].base_from_flange, last_target)[0] < 0.2


def test_pose_error_is_exact_for_small_and_large_angles():
    from spherecal.geometry import matrix_from_rotvec

    a = Pose.from_rt(matrix_from_rotvec([0.3, -0.2, 0.1]), [1.0, 2.0, 3.0])
    for angle_deg in (1e-7, 0.01, 90.0, 179.0):
        b = Pose.from_rt(matrix_from_rotvec(np.radians([0.0, 0.0, angle_deg])) @ a.rotation_matrix, [1.0, 2.0, 7.0])
        dt, da = pose_error(a, b)
        assert dt == pytest.approx(4.0)
        assert da == pytest.approx(angle_deg, rel=1e-6, abs=1e-9)
    assert pose_error(a, a) == (0.0, 0.0)


def _builtin_missing(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is None


@pytest.mark.skipif(_builtin_missing("spherecal.robots.abb_irb2400.plugin"), reason="abb_irb2400 plugin not written yet")
def test_builtin_robot_passes_the_robot_harness(spherecal_host, spherecal_context, spherecal_cell, spherecal_stations):
    section = {"type": "abb_irb2400"}
    robot = spherecal_host.create_robot(section, spherecal_context)
    try:
        report = RobotHarness(spherecal_cell, spherecal_stations, per_station=2).check(
            robot, flange_pose_from_joints=spherecal_host.robot_kinematics(section))
    finally:
        robot.close()
    assert report.max_kinematics_error_mm is not None


@pytest.mark.skipif(_builtin_missing("spherecal.sensors.nxsensor_i.plugin"), reason="nxsensor_i plugin not written yet")
def test_builtin_sensor_passes_the_sensor_harness(spherecal_host, spherecal_context, spherecal_sensor_harness):
    sensor = spherecal_host.create_sensor({"type": "nxsensor_i"}, spherecal_context)
    report = spherecal_sensor_harness.check(sensor)
    assert report.n_profiles == 12
