"""`spherecal solve` of a ROS 2 bag: a simulated recording published as a driver would
(PointCloud2 profiles in metres, PoseStamped flange poses with quaternions x, y, z, w),
converted once into the stream form and calibrated with its clock relation."""

import functools
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bag_files import (
    cloud,
    make_truth,
    pose_messages,
    pose_stamped,
    profile_messages,
    q_xyzw,
    tf_message,
    transform,
    write_bag,
)
from spherecal.cli import EXIT_DATA, EXIT_OK, EXIT_USAGE, main
from spherecal.config import OnTheFlyPlan, StreamSimSettings
from spherecal.io.streams import read_recording
from spherecal.sim import standard_cell
from spherecal.sim.streams import simulate_recording
from reference_sensor import reference_fov


def _ns(t_s: float) -> int:
    return int(round(t_s * 1e9))


@functools.cache
def _three_stations():
    """A recording of the standard eye-in-hand cell, three stations, the profiler at 100 Hz
    (read-only: the tests that write it into bags share it)."""
    cell = standard_cell("eye_in_hand", seed=2, fov=reference_fov())
    return simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05, stations=3),
                              StreamSimSettings(sensor={"rate_hz": 100.0}, seed=2))


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_solve_a_bag_finds_the_clocks_and_the_transform(tmp_path, capsys, storage):
    rec = _three_stations()
    ps, poses = rec.profiles, rec.poses
    clouds = []
    for j in range(ps.n):
        yz = ps.profile(j)
        xyz_m = np.column_stack([np.zeros(len(yz)), yz]) / 1000.0
        # the recorder logs each message a little after its stamp, on the computer's clock
        clouds.append((_ns(ps.t_sensor_s[j]) + 3_000_000, cloud(_ns(ps.t_sensor_s[j]), xyz_m)))
    q = q_xyzw(poses.R)
    # the controller stamps on its own clock (from power-on); the recorder logs on the computer's
    to_computer = -rec.provenance["true_offset_s"]
    pose_msgs = [(_ns(poses.t_robot_s[i] + to_computer) + 1_000_000,
                  pose_stamped(_ns(poses.t_robot_s[i]), poses.t_mm[i] / 1000.0, q[i])) for i in range(poses.n)]
    bag = write_bag(tmp_path / "cell.bag", storage, {
        "/profiler/points": ("sensor_msgs/msg/PointCloud2", clouds),
        "/robot/flange_pose": ("geometry_msgs/msg/PoseStamped", pose_msgs)})
    out = tmp_path / "res"
    args = ["solve", str(bag), "--profile-topic", "/profiler/points", "--pose-topic", "/robot/flange_pose",
            "--mounting", "eye_in_hand", "--sphere-radius-mm", str(rec.sphere_radius_mm), "--out", str(out),
            "--no-report"]
    assert main(args) == EXIT_OK
    printed = capsys.readouterr().out
    assert "clock relation" in printed
    converted = read_recording(out / "recording.jsonl")
    assert converted.profiles.n == ps.n and converted.poses.n == poses.n
    timing = json.loads((out / "result.json").read_text())["timing"]
    # the bag's stamps are whole nanoseconds; the simulator's truth is exact
    assert abs(timing["offset_ms"] - 1e3 * rec.provenance["true_offset_s"]) < max(4 * timing["offset_std_ms"], 0.05)
    result = json.loads((out / "result.json").read_text())
    truth = rec.provenance["true_transform"]["translation_mm"]
    assert np.linalg.norm(np.subtract(result["transform"]["translation_mm"], truth)) < 1.0


def test_a_bag_without_its_topics_is_refused_naming_what_to_give(tmp_path, capsys):
    bag = write_bag(tmp_path / "cell.bag", "mcap", {"/robot/flange_pose": ("geometry_msgs/msg/PoseStamped", [
        (1_000, pose_stamped(1_000, [1.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0]))])})
    code = main(["solve", str(bag), "--out", str(tmp_path / "res")])
    assert code == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--profile-topic" in err and "--mounting" in err and "--sphere-radius-mm" in err


@pytest.mark.slow
def test_solve_a_bag_of_joint_states_through_the_robots_kinematics(tmp_path, capsys):
    """Joint states (radians, sensor_msgs/JointState) instead of flange poses: `--robot`
    maps them through the robot plugin's forward kinematics (the IRB 2400's here, on a
    simulated arm without geometric error, with smooth pose noise). The solve with the arm's
    kinematic model converges, finds the clock relation, and states a transform the
    simulator's truth lies within: on a sampled stream the fit's last steps chatter at a
    thousandth of a standard deviation, and they end it as converged (else it would stop
    "not converged", skip the smooth-noise refit and end RED)."""
    from spherecal.plugins.host import PluginHost

    from bag_files import joint_state

    kin = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})
    cell = standard_cell("eye_in_hand", seed=4, fov=reference_fov(), arm=kin)
    rec = simulate_recording(cell, OnTheFlyPlan(crossing_fraction=1.15, pause_s=0.05, stations=3),
                             StreamSimSettings(sensor={"rate_hz": 100.0}, seed=4))
    ps, poses = rec.profiles, rec.poses
    assert poses.joints_deg is not None
    clouds = [(_ns(ps.t_sensor_s[j]) + 3_000_000,
               cloud(_ns(ps.t_sensor_s[j]), np.column_stack([np.zeros(len(ps.profile(j))), ps.profile(j)]) / 1000.0))
              for j in range(ps.n)]
    names = [f"joint_{k}" for k in range(1, 7)]
    to_computer = -rec.provenance["true_offset_s"]
    joints = [(_ns(poses.t_robot_s[i] + to_computer) + 1_000_000,
               joint_state(_ns(poses.t_robot_s[i]), names, np.radians(poses.joints_deg[i]))) for i in range(poses.n)]
    bag = write_bag(tmp_path / "cell.bag", "mcap", {
        "/profiler/points": ("sensor_msgs/msg/PointCloud2", clouds),
        "/joint_states": ("sensor_msgs/msg/JointState", joints)})
    out = tmp_path / "res"
    base = ["solve", str(bag), "--profile-topic", "/profiler/points", "--pose-topic", "/joint_states",
            "--mounting", "eye_in_hand", "--sphere-radius-mm", str(rec.sphere_radius_mm), "--no-report"]
    # without the robot's kinematics, joint states cannot become poses: said, naming --robot
    assert main([*base, "--out", str(tmp_path / "no-robot")]) == EXIT_DATA
    assert "--robot" in capsys.readouterr().err
    assert main([*base, "--robot", "abb_irb2400", "--out", str(out)]) == EXIT_OK  # not RED
    converted = read_recording(out / "recording.jsonl")
    assert converted.poses.joints_deg is not None and converted.poses.n == poses.n
    # the poses the kinematics gave are the simulator's (the arm has no geometric error here)
    assert np.abs(converted.poses.t_mm - poses.t_mm).max() < 1e-3
    result = json.loads((out / "result.json").read_text())
    timing = result["timing"]
    assert abs(timing["offset_ms"] - 1e3 * rec.provenance["true_offset_s"]) < max(4 * timing["offset_std_ms"], 0.05)
    # the arm's geometry is marginalised (the kinematic model): the transform is as
    # certain as an arm of unknown geometry allows, and within that
    truth = rec.provenance["true_transform"]["translation_mm"]
    error = np.abs(np.subtract(result["transform"]["translation_mm"], truth))
    assert np.all(error < 3.0 * np.asarray(result["std_translation_mm"])), (error, result["std_translation_mm"])


def test_a_bags_errors_name_the_command_lines_flags(tmp_path, capsys):
    """The bag reader's messages name its Python parameters (line_axis='x', base_frame,
    overwrite=True); on the command line they name the flags to give."""
    truth = make_truth(n_profiles=10)
    along_x = [(log, cloud(int(ns), p[:, [1, 0, 2]]))
               for (log, _), ns, p in zip(profile_messages(truth), truth.profile_ns, truth.points_m)]
    poses = pose_messages(truth)
    bag = write_bag(tmp_path / "x.bag", "mcap", {"/profiles": ("sensor_msgs/msg/PointCloud2", along_x),
                                                 "/pose": ("geometry_msgs/msg/PoseStamped", poses)})
    base = ["--profile-topic", "/profiles", "--mounting", "eye_in_hand", "--sphere-radius-mm", "19.05", "--no-report"]
    assert main(["solve", str(bag), "--pose-topic", "/pose", *base, "--out", str(tmp_path / "r1")]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "off the laser plane" in err and "give --line-axis x" in err and "line_axis" not in err, err

    tf = [(log, tf_message([transform(int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec), "base_link",
                                      "tool0", [m.pose.position.x, m.pose.position.y, m.pose.position.z],
                                      [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                                       m.pose.orientation.w])])) for log, m in poses]
    bag = write_bag(tmp_path / "tf.bag", "mcap", {"/profiles": ("sensor_msgs/msg/PointCloud2", profile_messages(truth)),
                                                  "/tf": ("tf2_msgs/msg/TFMessage", tf)})
    assert main(["solve", str(bag), "--pose-topic", "/tf", *base, "--out", str(tmp_path / "r2")]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "--base-frame (e.g. base_link) and --flange-frame (e.g. tool0)" in err and "base_frame" not in err, err
    code = main(["solve", str(bag), "--pose-topic", "/tf", "--base-frame", "base", "--flange-frame", "tool0", *base,
                 "--out", str(tmp_path / "r3")])
    err = capsys.readouterr().err
    assert code == EXIT_DATA and "--base-frame 'base' is in no transform" in err, err

    # a folder holding an earlier run's conversion: refused naming --overwrite, before the bag is read
    out = tmp_path / "r4"
    out.mkdir()
    (out / "recording.jsonl").write_text("an earlier run's\n")
    assert main(["solve", str(bag), "--pose-topic", "/tf", *base, "--out", str(out)]) == EXIT_DATA
    err = capsys.readouterr().err
    assert "recording.jsonl exists" in err and "--overwrite" in err and "overwrite=True" not in err, err
    assert (out / "recording.jsonl").read_text() == "an earlier run's\n"


@pytest.mark.slow
def test_a_bag_with_the_line_along_x_exports_the_clouds_own_frame(tmp_path, capsys):
    """A driver that puts the laser line along the cloud's x (--line-axis x), its clouds in
    'profiler_link', the poses in 'robot_base' and the flange named 'ee_link': the terminal,
    run.log and result.json say the calibrated sensor frame is not the clouds' frame, and
    the ROS exports publish 'profiler_link' in 'ee_link' so that its clouds land where the
    calibration puts them."""
    from spherecal.report import export as ex

    rec = _three_stations()
    ps, poses = rec.profiles, rec.poses
    clouds = []
    for j in range(ps.n):
        yz = ps.profile(j)
        xyz_m = np.column_stack([yz[:, 0], np.zeros(len(yz)), yz[:, 1]]) / 1000.0  # (line, 0, range)
        clouds.append((_ns(ps.t_sensor_s[j]) + 3_000_000, cloud(_ns(ps.t_sensor_s[j]), xyz_m, frame="profiler_link")))
    q = q_xyzw(poses.R)
    to_computer = -rec.provenance["true_offset_s"]
    pose_msgs = [(_ns(poses.t_robot_s[i] + to_computer) + 1_000_000,
                  pose_stamped(_ns(poses.t_robot_s[i]), poses.t_mm[i] / 1000.0, q[i], frame="robot_base"))
                 for i in range(poses.n)]
    bag = write_bag(tmp_path / "cell.bag", "mcap", {
        "/profiler/points": ("sensor_msgs/msg/PointCloud2", clouds),
        "/robot/flange_pose": ("geometry_msgs/msg/PoseStamped", pose_msgs)})
    out = tmp_path / "res"
    assert main(["solve", str(bag), "--profile-topic", "/profiler/points", "--pose-topic", "/robot/flange_pose",
                 "--mounting", "eye_in_hand", "--sphere-radius-mm", str(rec.sphere_radius_mm), "--line-axis", "x",
                 "--flange-frame", "ee_link", "--out", str(out), "--no-report"]) == EXIT_OK
    said = "the calibrated sensor frame is NOT the clouds' frame 'profiler_link': sensor_from_cloud = Rz(+90 deg)"
    assert said in capsys.readouterr().out and said in (out / "run.log").read_text()
    result = json.loads((out / "result.json").read_text())
    frames = result["data_frames"]
    assert (frames["base_frame_id"], frames["flange_frame_id"], frames["cloud_frame_id"]) == \
        ("robot_base", "ee_link", "profiler_link")
    ros = ex.read_ros_command((out / "ros_static_transform.sh").read_text())
    assert (ros["frame_id"], ros["child_frame_id"]) == ("ee_link", "profiler_link")
    # a cloud point (x, y, z) is the sensor point (-y, x, z): both land on one flange point
    X = ex.read_json((out / "result.json").read_text()).transform
    p_cloud_m = np.array([[0.01, 0.0, -0.02], [-0.015, 0.003, 0.03]])
    R = Rotation.from_quat(ros["quaternion_xyzw"]).as_matrix()
    sensor_mm = np.column_stack([-p_cloud_m[:, 1], p_cloud_m[:, 0], p_cloud_m[:, 2]]) * 1000.0
    np.testing.assert_allclose((p_cloud_m @ R.T + ros["xyz_m"]) * 1000.0, X.apply(sensor_mm), atol=2e-4)
