"""Tests of the example plugins, written the way a plugin author would write them: with
the fixtures spherecal installs into pytest (``spherecal_host``, ``spherecal_cell``,
``spherecal_context``, the harnesses; the cell is this package's, tests/conftest.py), and
``spherecal calibrate`` run on the package's configurations, checked against the
simulated truth they give. Run with ``pytest`` after ``pip install .``."""

import json
import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from spherecal.plugins import (ConfigError, DeviceContext, DeviceError, InputError, Pose, PoseStreamStalled,
                               SimulatedDeviceServer, ik_seeds_deg, rotation_angle_deg)

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
ROBOT = {"type": "example_arm"}
SENSOR = {"type": "example_profiler"}


def test_both_types_are_installed(spherecal_host):
    names = {(d.kind, d.name): d.plugin for d in spherecal_host.describe()}
    assert names[("robot", "example_arm")] == "example_arm"
    assert names[("sensor", "example_profiler")] == "example_profiler"


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_robot_honours_the_protocol(spherecal_host, spherecal_context, spherecal_robot_harness):
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    report = spherecal_robot_harness.check(robot, flange_pose_from_joints=spherecal_host.robot_kinematics(ROBOT))
    assert report.max_move_error_mm < 1e-6
    assert report.max_kinematics_error_mm < 1e-3  # joints carried with 6 decimals


@pytest.mark.parametrize("spherecal_cell", ["eye_in_hand", "eye_to_hand"], indirect=True)
def test_sensor_honours_the_protocol(spherecal_host, spherecal_context, spherecal_sensor_harness):
    sensor = spherecal_host.create_sensor({**SENSOR, "order": "ascending_y"}, spherecal_context)
    report = spherecal_sensor_harness.check(sensor)
    assert report.n_profiles >= 4


def test_a_move_runs_the_cells_arm_on_its_timeline(spherecal_host, spherecal_context, spherecal_stations):
    """The simulated controller moves the cell's arm: the flange is where the arm puts the
    joints the robot reports, and the move took simulated time (at most 100 mm/s, then a
    settle) on the cell's clock, whose timeline holds those joints."""
    cell = spherecal_context.cell
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    target = spherecal_stations[0][1][0]
    distance_mm = np.linalg.norm(target.translation - robot.read_flange_pose().translation)
    T0 = cell.clock.now_s
    robot.move_linear(target, 100.0)
    joints = robot.read_joints_deg()
    assert cell.clock.now_s - T0 > distance_mm / 100.0 + 0.1
    flange = cell.arm.true_flange_pose(joints)
    assert np.linalg.norm(flange.translation - cell.current_base_from_flange.translation) < 1e-4  # 6 decimals
    _, _, timeline_joints, _ = cell.timeline.at([cell.clock.now_s])
    np.testing.assert_allclose(timeline_joints[0], joints, atol=1e-6)
    robot.close()


def test_the_arm_declares_its_home_where_its_controller_starts(spherecal_host, spherecal_context):
    """The robot type declares the arm's home: the core seeds inverse kinematics there
    before the arm is connected (not at zero joints, the stretched elbow, a singularity),
    and the simulated controller starts there."""
    home_deg = ik_seeds_deg(spherecal_host.arm_kinematics(ROBOT))[0]
    assert home_deg.tolist() == [0.0, 0.0, 0.0, 0.0, 90.0, 0.0]
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    np.testing.assert_allclose(robot.read_joints_deg(), home_deg, atol=1e-6)
    robot.close()


def test_limits_refuse_a_move_before_anything_is_sent(spherecal_host, spherecal_context, spherecal_stations):
    low_box = {"min_mm": [-1600.0, -1600.0, -200.0], "max_mm": [1600.0, 1600.0, 100.0]}
    robot = spherecal_host.create_robot({**ROBOT, "workspace": low_box}, spherecal_context)
    target = spherecal_stations[0][1][0]
    box = (r"outside the configured workspace box min_mm=\[-1600.0, -1600.0, -200.0\] "
           r"max_mm=\[1600.0, 1600.0, 100.0\]")
    with pytest.raises(InputError, match="move_linear: target flange position .* is " + box):
        robot.check_target(target, 50.0)  # the plan check, before the first motion
    with pytest.raises(InputError, match="target flange position .* is " + box):
        robot.move_linear(target, 50.0)
    with pytest.raises(InputError, match=r"speed_mm_s = 300.0 exceeds the configured max_speed_mm_s = 250.0"):
        robot.check_move(target, 300.0)
    assert robot.simulator.controller.moves == 0  # nothing was sent
    robot.close()


def test_reach_is_checked_along_the_path_before_anything_is_sent(spherecal_host, spherecal_context,
                                                                  spherecal_stations):
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    target = spherecal_stations[0][1][0]
    far = Pose.from_rt(target.rotation_matrix, [1590.0, 0.0, 1800.0])  # in the box, beyond the arm's reach
    with pytest.raises(InputError, match=r"move_linear: target: flange pose \[1590.0, 0.0, 1800.0\] mm is out of "
                                         r"the example arm's reach"):
        robot.move_linear(far, 50.0)
    assert robot.simulator.controller.moves == 0
    robot.close()


def _fake_controller(pose_offset_mm: float) -> SimulatedDeviceServer:
    """A stand-in XA/1 controller at the home joints whose pose is off the model's by
    ``pose_offset_mm`` along base x (a controller working in a shifted base frame)."""
    def handle(line: bytes) -> bytes:
        if line == b"JOINTS\n":
            return b"JOINTS 0 0 0 0 90 0\n"
        return f"POSE 12.5 {910.0 + pose_offset_mm} 0 1360 0 0 1 0\n".encode()

    return SimulatedDeviceServer(handle, name="fake XA/1 controller")


def test_a_controller_in_another_frame_is_refused_on_connecting(spherecal_host):
    with _fake_controller(50.0) as server:
        with pytest.raises(DeviceError, match=r"example arm: the controller reports the flange 50.0 mm and 0.00 deg "
                                              r"away .* Set the controller's base and tool frames to none"):
            spherecal_host.create_robot({**ROBOT, "port": server.port}, DeviceContext())
    with _fake_controller(0.0) as server:  # the same controller in the arm's base frame is taken
        robot = spherecal_host.create_robot({**ROBOT, "port": server.port}, DeviceContext())
        assert robot.read_flange_pose().translation_mm == pytest.approx((910.0, 0.0, 1360.0))
        robot.close()


def test_no_controller_is_a_device_error_naming_the_address(spherecal_host):
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(DeviceError, match=rf"example arm: cannot connect to 127.0.0.1:{port} .* robot.host / robot.port"):
        spherecal_host.create_robot({**ROBOT, "port": port}, DeviceContext())


def test_config_errors_name_the_setting(spherecal_host):
    with pytest.raises(ConfigError, match=r"robot\.workspace\.max_mm\[0\]: Input should be a valid number"):
        spherecal_host.validate_robot_config("example_arm",
                                             {"workspace": {"min_mm": [0, -1000, 0], "max_mm": ["far", 1000, 1500]}})
    with pytest.raises(ConfigError, match=r"robot\.port: Input should be less than or equal to 65535"):
        spherecal_host.validate_robot_config("example_arm", {"port": 70000})
    with pytest.raises(ConfigError, match=r"sensor\.decimate: Input should be less than or equal to 16"):
        spherecal_host.validate_sensor_config("example_profiler", {"decimate": 50})


@pytest.mark.parametrize("mounting", ["eye-in-hand", "eye-to-hand"])
def test_spherecal_calibrate_recovers_the_simulated_truth(mounting, tmp_path):
    """``spherecal calibrate`` on the package's configuration: the arm over XA/1 to its
    simulated controller, the profiler, the truth the configuration gives."""
    config = CONFIGS / f"example-arm-{mounting}.toml"
    proc = subprocess.run([sys.executable, "-m", "spherecal.cli", "calibrate", str(config), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    truth = tomllib.loads(config.read_text())["simulation"]["true_transform"]
    found = json.loads((tmp_path / "out" / "result.json").read_text())["transform"]
    error_mm = np.linalg.norm(np.subtract(found["translation_mm"], truth["translation_mm"]))
    true_R = Pose.from_xyz_quat_wxyz(truth["translation_mm"], truth["quaternion_wxyz"]).rotation_matrix
    found_R = Pose.from_xyz_quat_wxyz(found["translation_mm"], found["quaternion_wxyz"]).rotation_matrix
    # the nominal transform was ~2 mm and ~1 deg off; the cell's noise is 0.01-0.02 mm
    assert error_mm < 0.1 and rotation_angle_deg(true_R, found_R) < 0.1, (error_mm, proc.stdout)


def _sweep(robot, target: Pose, length_mm: float = 60.0) -> Pose:
    """Put the arm at ``target`` (stop-and-go) and return the end of a straight sweep from there."""
    robot.move_linear(target, 100.0)
    return Pose.from_rt(target.rotation_matrix, target.translation + [0.0, length_mm, 0.0])


def test_the_pose_stream_follows_the_move_on_the_controllers_clock(spherecal_host, spherecal_context,
                                                                  spherecal_stations):
    """Between STREAM and UNSTREAM the controller sends a sample every 4 ms of its clock:
    consecutive sequence numbers, the controller's stamps (not the PC's), the pose it
    reports along the move at each stamp's true time, the last one where the move ended."""
    cell = spherecal_context.cell
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    end = _sweep(robot, spherecal_stations[0][1][0])
    T_start = cell.clock.now_s
    robot.start_pose_stream()
    robot.move_linear(end, 50.0)
    stream = robot.stop_pose_stream()
    duration_s = cell.clock.now_s - T_start
    assert stream.n == pytest.approx(duration_s / 0.004, abs=2) and duration_s > 60.0 / 50.0
    assert np.all(np.diff(stream.seq) == 1) and robot.pose_stream_counts().lost == 0
    T_true = cell.controller_clock.true_time(stream.t_robot_s)  # stamps on the controller's clock (20 us jitter)
    assert np.all((T_true > T_start - 1e-4) & (T_true < cell.clock.now_s + 1e-4))
    _, t_reported, joints = cell.timeline.reported_at(T_true)
    np.testing.assert_allclose(stream.t_mm, t_reported, atol=0.01)  # 50 mm/s x 0.1 ms of jitter at most
    np.testing.assert_allclose(stream.joints_deg, joints, atol=1e-3)
    assert np.linalg.norm(stream.t_mm[-1] - end.translation) < 1e-6
    assert np.ptp(stream.t_mm[:, 1]) == pytest.approx(60.0, abs=1e-6)  # the whole sweep
    robot.close()


def test_a_pose_stream_that_goes_silent_stalls_keeping_what_came(spherecal_host, spherecal_context,
                                                                 spherecal_stations):
    robot = spherecal_host.create_robot(ROBOT, spherecal_context)
    end = _sweep(robot, spherecal_stations[0][1][0])
    robot.start_pose_stream()
    robot.simulator.controller.samples_left = 20  # then the controller goes silent, still streaming
    robot.move_linear(end, 50.0)
    with pytest.raises(PoseStreamStalled, match=r"example arm: the pose stream ended: no sample for the last 1\.\d+ s"
                       ) as err:
        robot.stop_pose_stream()
    assert err.value.stream.n == 21 and err.value.counts.received == 21  # the first, and 20 more
    assert np.all(np.diff(err.value.stream.seq) == 1)
    robot.close()


@pytest.mark.slow
def test_spherecal_calibrate_on_the_fly_recovers_the_simulated_truth(tmp_path):
    """``spherecal calibrate`` on the fly: the arm streams its pose over XA/1 while it sweeps,
    the nxSensor-I streams profiles, each on its own clock; the transform and the clocks'
    offset come out near the simulated truth."""
    config = CONFIGS / "example-arm-on-the-fly.toml"
    proc = subprocess.run([sys.executable, "-m", "spherecal.cli", "calibrate", str(config), "--yes", "--no-report",
                           "--json", "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = json.loads(proc.stdout)
    assert "0 pose samples lost" in proc.stderr and "(32 sweeps)" in proc.stderr
    truth = out["simulated_truth"]
    assert truth["translation_error_mm"] < 0.05 and truth["rotation_error_deg"] < 0.05, truth
    assert abs(truth["clock_offset_error_ms"]) < 0.2, truth  # the clocks' epochs differ by an hour
    assert out["verdict"]["level"] == "green", out["verdict"]
