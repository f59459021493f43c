"""The simulated world behind the live streams: a sweep through the real protocols (EGM
over UDP, the nxSensor-I over pyusb) gives streams whose stamps map back to the
simulated truth, each on its own clock."""

import numpy as np
import pytest

from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell
from spherecal.app.plugin_host import open_devices, robot_arm
from spherecal.config import load_config
from spherecal.core.models import Pose
from spherecal.sim.live import CounterClock, clock_truth, true_time_relation
from spherecal.sim.timeline import DeviceClock

EGM = "[robot.egm]\nport = 0\nstall_timeout_s = 2.0\n\n[sensor]"


@pytest.fixture
def devices(sim_config):
    """The example cell's robot and sensor as a simulated run opens them, and the cell."""
    path = sim_config(**{r"^\[sensor\]": EGM, r"^scan_object = .*$": ""})
    host = plugin_host.make_host()
    loaded, fov = configured_for_sensor(load_config(path), host)
    cell = make_cell(loaded.config, robot_arm(loaded, host), fov)
    with open_devices(loaded, host, cell, lambda _: None) as (robot, sensor):
        yield robot, sensor, cell


def test_a_sweep_streams_poses_and_profiles_whose_stamps_map_back_to_the_simulated_truth(devices):
    robot, sensor, cell = devices
    start = robot.read_flange_pose()
    end = Pose.from_rt(start.rotation_matrix, start.translation + np.array([0.0, 60.0, 0.0]))
    sensor.start_profile_stream()
    robot.start_pose_stream()
    T0 = cell.clock.now_s
    robot.move_linear(end, 50.0)
    T1 = cell.clock.now_s
    poses = robot.stop_pose_stream()
    profiles = sensor.stop_profile_stream()
    assert T1 - T0 > 60.0 / 50.0  # the move took simulated time
    # poses: the controller's stamps on its own clock, the report at that true time
    T_pose = cell.controller_clock.true_time(poses.t_robot_s)
    assert T_pose[0] == pytest.approx(T0, abs=1e-3) and T_pose[-1] == pytest.approx(T1, abs=5e-3)
    _, t_reported, _ = cell.timeline.reported_at(T_pose)
    assert np.abs(poses.t_mm - t_reported).max() < 0.01  # 50 mm/s x the 20 us stamp jitter, and float32 steps
    assert poses.t_mm[-1] == pytest.approx(end.translation, abs=0.01)
    # profiles: the sensor's counter, the frame's true exposure time
    truth = {f.counter: f.T_true_s for f in sensor._backend.streamed if f.sent}
    T_true = np.array([truth[int(k)] for k in profiles.frame])
    T_profile = CounterClock(cell.sensor_clock).to_true_s(profiles.t_sensor_s)
    assert np.abs(T_profile - T_true).max() < 2e-6  # the counter's microsecond
    assert profiles.n > 0.9 * (T1 - T0) * 100.0  # the configured 100 Hz over the move
    # the two together: the truth of the clocks' relation maps each profile to the pose
    # stream's time of its exposure
    offset, drift = true_time_relation(clock_truth(cell), profiles.t_sensor_s[0])
    t_robot = profiles.t_sensor_s + offset + drift * (profiles.t_sensor_s - profiles.t_sensor_s[0])
    assert np.abs(t_robot - cell.controller_clock.stamp(T_true)).max() < 2e-6


def test_the_true_time_relation_is_exact_for_linear_clocks():
    robot = DeviceClock(offset_s=0.25, drift_ppm=40.0, epoch_s=3725.25)
    sensor = DeviceClock(offset_s=0.75, drift_ppm=-15.0, epoch_s=1.7e9)
    truth = {"robot": {"epoch_s": robot.epoch_s, "offset_s": robot.offset_s, "rate": robot.rate},
             "sensor": {"epoch_s": sensor.epoch_s, "offset_s": sensor.offset_s, "rate": sensor.rate}}
    T = np.array([10.0, 500.0, 3000.0])
    t_sensor = sensor.stamp(T)
    offset, drift = true_time_relation(truth, t_sensor[0])
    assert drift * 1e6 == pytest.approx(55.0, abs=0.01)
    np.testing.assert_allclose(t_sensor + offset + drift * (t_sensor - t_sensor[0]), robot.stamp(T), atol=1e-6)
