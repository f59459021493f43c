"""A bag's joint states become flange poses through the robot's kinematics: the arm's
joints picked out of each message by name (reordered, or among a gripper's), a clear
refusal when the names do not match, and the robot type taken from --robot-config as
for a dataset."""

import numpy as np
import pytest

from bag_files import joint_state, make_truth, profile_messages, write_bag
from spherecal.app.solve_recording import convert_bag
from spherecal.io.rosbag import BagTopicError, BagWarning, read_bag
from spherecal.plugins.host import PluginHost

CLOUD = "sensor_msgs/msg/PointCloud2"
JOINTS = "sensor_msgs/msg/JointState"
ARM = [f"joint_{k}" for k in range(1, 7)]


def _joints_deg(n):
    s = np.linspace(0.0, 1.0, n)[:, None]
    return np.array([10.0, 15.0, 20.0, -30.0, 45.0, 60.0]) + s * [20.0, -10.0, 15.0, 40.0, -20.0, 30.0]


def _bag(tmp_path, names, order=None, extra=()):
    """Profiles, and joint states naming ``names`` with the arm's joints in ``order``
    (indices into the arm's), then the ``extra`` joints (name, radians) of the message."""
    truth = make_truth(n_profiles=20)
    q = np.radians(_joints_deg(len(truth.pose_ns)))
    order = list(range(6)) if order is None else order
    msgs = [(int(ns) + 900_000, joint_state(int(ns), [names[j] for j in order] + [e for e, _ in extra],
                                            np.append(q[i, order], [v for _, v in extra])))
            for i, ns in enumerate(truth.pose_ns)]
    return write_bag(tmp_path / "bag", "mcap", {"/profiles": (CLOUD, profile_messages(truth)),
                                                "/joint_states": (JOINTS, msgs)})


def _convert(tmp_path, bag, **kw):
    return convert_bag(bag, tmp_path / "out", profile_topic="/profiles", pose_topic="/joint_states",
                       mounting="eye_in_hand", sphere_radius_mm=19.05, **kw)


def _expected_t_mm(j23_coupled=True):
    arm = PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400", "j23_coupled": j23_coupled})
    return np.array([arm.flange_pose_from_joints(q).translation for q in _joints_deg(200)])


def test_joint_states_are_matched_to_the_arm_by_name(tmp_path):
    # the driver's own order, and a gripper's joint in the same message
    bag = _bag(tmp_path, ARM, order=[2, 0, 1, 5, 3, 4], extra=[("gripper_finger_joint", 0.01)])
    rec = _convert(tmp_path, bag, robot_type="abb_irb2400")
    np.testing.assert_allclose(rec.poses.joints_deg, _joints_deg(200), atol=1e-9)
    np.testing.assert_allclose(rec.poses.t_mm, _expected_t_mm(), atol=1e-6)
    assert rec.provenance["joint_names"] == ARM and rec.provenance["joints_matched_by_name"] is True


def test_joint_names_that_do_not_match_are_refused_naming_both(tmp_path):
    bag = _bag(tmp_path, [f"a{k}" for k in range(1, 7)])
    with pytest.raises(BagTopicError, match=r"no message names the arm's joints \['joint_1', .*'joint_6'\], .*the "
                                            r"messages name \['a1', 'a2', 'a3', 'a4', 'a5', 'a6'\] \(200 messages\)"):
        _convert(tmp_path, bag, robot_type="abb_irb2400")


def test_robot_config_alone_gives_the_bag_its_robot(tmp_path):
    """`--robot-config FILE` with its [robot] type, without --robot, as for a dataset: here
    a ROS-Industrial /joint_states (joint 3 relative to joint 2, j23_coupled = false)."""
    bag = _bag(tmp_path, ARM)
    config = tmp_path / "robot.toml"
    config.write_text('[robot]\ntype = "abb_irb2400"\nj23_coupled = false\n')
    rec = _convert(tmp_path, bag, robot_config=config)
    np.testing.assert_allclose(rec.poses.t_mm, _expected_t_mm(j23_coupled=False), atol=1e-6)


def test_kinematics_without_joint_names_take_the_messages_order_and_say_so(tmp_path):
    bag = _bag(tmp_path, ARM, order=[1, 0, 2, 3, 4, 5])

    def fk(q_deg):
        return np.tile(np.eye(3), (len(q_deg), 1, 1)), np.column_stack([q_deg[:, :2], 500.0 + q_deg[:, 2]])

    with pytest.warns(BagWarning, match=r"names no joints: the joints are taken in the order of the first "
                                        r"message's names, \['joint_2', 'joint_1', 'joint_3'"):
        rec = read_bag(bag, profile_topic="/profiles", pose_topic="/joint_states", mounting="eye_in_hand",
                       sphere_radius_mm=19.05, joints_to_pose=fk)
    np.testing.assert_allclose(rec.poses.joints_deg[:, :2], _joints_deg(200)[:, [1, 0]], atol=1e-9)
    assert rec.provenance["joints_matched_by_name"] is False
