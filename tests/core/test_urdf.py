"""A serial chain to URDF and back (spherecal.core.urdf): the round trip reproduces flange
poses to 1e-9 mm, Pinocchio reads the written file directly, URDFs written by others
(fixed joints in between, rotated and tilted axes, a UR5 from example-robot-data) read
as the same kinematics, and bad files are refused with the file and the link or joint
named."""

from __future__ import annotations

import math
from importlib import metadata

import numpy as np
import pinocchio as pin
import pytest

from spherecal.core.errors import InputError
from spherecal.core.kinematics import SerialChain
from spherecal.plugins.host import PluginHost
from spherecal.sim.robot_error import RobotErrorModel, perturbed_chain
from spherecal.core.urdf import (
    chain_from_urdf,
    chain_inverse_kinematics,
    chain_to_urdf,
    fold_zero_offsets,
    matrix_from_rpy,
    read_urdf_chain,
    rpy_from_matrix,
)

TOL_MM = 1e-9


@pytest.fixture(scope="module")
def nominal() -> SerialChain:
    return PluginHost().arm_kinematics({"type": "abb_irb2400"}).chain


@pytest.fixture(scope="module")
def perturbed(nominal) -> SerialChain:
    chain, dq = perturbed_chain(nominal, RobotErrorModel(), np.random.default_rng(7))
    return fold_zero_offsets(chain, dq)


@pytest.fixture(scope="module")
def joint_sets() -> np.ndarray:
    return np.random.default_rng(1).uniform(-math.pi, math.pi, (1000, 6))


def _max_flange_error_mm(a: SerialChain, b: SerialChain, Q) -> float:
    """Largest error over the joint sets: position (mm) and rotation entries times 1 m."""
    Ta, Tb = a.flange_matrices(Q), b.flange_matrices(Q)
    return float(max(np.abs(Ta[:, :3, 3] - Tb[:, :3, 3]).max(), 1000.0 * np.abs(Ta[:, :3, :3] - Tb[:, :3, :3]).max()))


@pytest.mark.parametrize("which", ["nominal", "perturbed"])
def test_round_trip_reproduces_flange_poses(which, request, joint_sets, tmp_path):
    chain = request.getfixturevalue(which)
    path = tmp_path / "robot.urdf"
    path.write_text(chain_to_urdf(chain, "irb2400"))
    back = chain_from_urdf(path, "base_link", "tool0", joint_names=[f"joint_{i}" for i in range(1, 7)])
    err = _max_flange_error_mm(chain, back, joint_sets)
    assert err < TOL_MM, err


def test_pinocchio_reads_the_written_file_directly(perturbed, joint_sets, tmp_path):
    path = tmp_path / "robot_calibrated.urdf"
    path.write_text(chain_to_urdf(perturbed, "irb2400_calibrated"))
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    tool0 = model.getFrameId("tool0")
    assert [model.names[j] for j in range(1, model.njoints)] == [f"joint_{i}" for i in range(1, 7)]
    worst = 0.0
    for q in joint_sets:
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        T = np.array(data.oMf[tool0].homogeneous)
        want = perturbed.flange_matrices(q)
        worst = max(worst, np.abs(T[:3, 3] * 1000.0 - want[:3, 3]).max(), 1000.0 * np.abs(T[:3, :3] - want[:3, :3]).max())
    assert worst < TOL_MM, worst


def test_header_says_units_and_convention(nominal):
    text = chain_to_urdf(nominal, "irb2400", comment="identified by spherecal from 20 stations")
    head = text.split("-->")[0]
    assert "metres" in head and "serial model" in head and "tool0" in head
    assert "placeholders" in head  # no limits given
    assert "identified by spherecal from 20 stations" in head
    limited = chain_to_urdf(nominal, "irb2400", joint_limits_rad=np.tile([-1.0, 2.0], (6, 1)))
    assert "placeholders" not in limited.split("-->")[0]
    u = read_urdf_chain(limited, "base_link", "tool0")
    assert np.array_equal(u.lower_rad, -np.ones(6)) and np.array_equal(u.upper_rad, 2 * np.ones(6))


@pytest.mark.parametrize("pitch", [0.3, math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-7, 3.0])
def test_rpy_is_exact_at_every_pitch_including_gimbal_lock(pitch):
    R = matrix_from_rpy(0.7, pitch, -2.1)
    assert np.abs(matrix_from_rpy(*rpy_from_matrix(R)) - R).max() < 1e-15


HAND_WRITTEN = """<?xml version="1.0"?>
<robot name="two_link_with_plates">
  <link name="world"/>
  <link name="mount"/>
  <link name="base"/>
  <link name="a"/>
  <link name="a_plate"/>
  <link name="b"/>
  <link name="flange"/>
  <link name="tcp"/>
  <joint name="world_to_mount" type="fixed">
    <parent link="world"/><child link="mount"/>
    <origin xyz="1 2 3" rpy="0.1 0 0"/>
  </joint>
  <joint name="mount_to_base" type="fixed">
    <parent link="mount"/><child link="base"/>
    <origin xyz="0 0 0.2" rpy="0 0 0.5"/>
  </joint>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="a"/>
    <origin xyz="0.1 0 0.3" rpy="0.2 -0.1 0.4"/>
    <axis xyz="0 0 -1"/>
    <limit lower="-2" upper="2" effort="10" velocity="1.5"/>
  </joint>
  <joint name="a_to_plate" type="fixed">
    <parent link="a"/><child link="a_plate"/>
    <origin xyz="0 0.05 0.4" rpy="1.5707963267948966 0 0"/>
  </joint>
  <joint name="j2" type="continuous">
    <parent link="a_plate"/><child link="b"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/>
    <axis xyz="0.6 0 0.8"/>
  </joint>
  <joint name="b_to_flange" type="fixed">
    <parent link="b"/><child link="flange"/>
    <origin xyz="0.1 0 0" rpy="0 0.3 0"/>
  </joint>
  <joint name="flange_to_tcp" type="fixed">
    <parent link="flange"/><child link="tcp"/>
    <origin xyz="0 0 0.15" rpy="0 0 0"/>
  </joint>
</robot>
"""


def _T(xyz, rpy):
    T = np.eye(4)
    T[:3, :3] = matrix_from_rpy(*rpy)
    T[:3, 3] = np.asarray(xyz) * 1000.0
    return T


def _rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    return T


def test_fixed_joints_in_between_fold_into_placements():
    """The hand-written URDF's kinematics computed by hand (fixed joints composed in
    order, rotations about the unaligned and the negative axes) equal the chain read."""
    u = read_urdf_chain(HAND_WRITTEN, "base", "tcp")
    assert u.joint_names == ("j1", "j2")
    assert u.lower_rad[0] == -2 and u.upper_rad[0] == 2 and u.velocity_rad_s[0] == 1.5
    assert math.isinf(u.upper_rad[1])  # continuous
    rng = np.random.default_rng(3)
    for q in rng.uniform(-3, 3, (20, 2)):
        want = (_T((0.1, 0, 0.3), (0.2, -0.1, 0.4)) @ _rot((0, 0, -1), q[0]) @ _T((0, 0.05, 0.4), (math.pi / 2, 0, 0))
                @ _T((0.3, 0, 0), (0, 0, 0)) @ _rot((0.6, 0, 0.8), q[1])
                @ _T((0.1, 0, 0), (0, 0.3, 0)) @ _T((0, 0, 0.15), (0, 0, 0)))
        assert np.abs(u.chain.flange_matrices(q) - want).max() < 1e-9
    # a base link further up the tree carries the fixed joints below it
    from_world = chain_from_urdf(HAND_WRITTEN, "world", "flange")
    q = np.array([0.4, -1.1])
    want = _T((1, 2, 3), (0.1, 0, 0)) @ _T((0, 0, 0.2), (0, 0, 0.5)) @ u.chain.flange_matrices(q) @ np.linalg.inv(
        _T((0, 0, 0.15), (0, 0, 0)))
    assert np.abs(from_world.flange_matrices(q) - want).max() < 1e-9


def _ur5_urdf():
    try:
        files = metadata.files("example-robot-data") or []
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed (pip install -e '.[test]')")
    for f in files:
        if str(f).endswith("ur_description/urdf/ur5_robot.urdf"):
            return f.locate()
    pytest.fail("example-robot-data has no ur_description/urdf/ur5_robot.urdf")


def test_ur5_from_example_robot_data_matches_its_published_dh_parameters():
    """A URDF we did not write: the UR5 of the Pinocchio project's example-robot-data,
    read from ``base`` to ``tool0`` (a ``world`` root, fixed joints, rotated joint
    origins), agrees with the UR5's published Denavit-Hartenberg model (base and tool0
    are the DH frames)."""
    u = read_urdf_chain(_ur5_urdf(), "base", "tool0")
    assert u.joint_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                             "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    d = [89.159, 0, 0, 109.15, 94.65, 82.3]
    a = [0, -425.0, -392.25, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]

    def dh(q):
        T = np.eye(4)
        for i in range(6):
            c, s, ca, sa = math.cos(q[i]), math.sin(q[i]), math.cos(alpha[i]), math.sin(alpha[i])
            T = T @ np.array([[c, -s * ca, s * sa, a[i] * c], [s, c * ca, -c * sa, a[i] * s], [0, sa, ca, d[i]], [0, 0, 0, 1]])
        return T

    Q = np.random.default_rng(5).uniform(-math.pi, math.pi, (200, 6))
    T = u.chain.flange_matrices(Q)
    # the file writes pi as 3.14159265359 (2e-12 rad off): nanometres at the UR5's reach
    assert max(np.abs(T[i] - dh(q)).max() for i, q in enumerate(Q)) < 1e-7
    # and it survives our own round trip
    back = chain_from_urdf(chain_to_urdf(u.chain, "ur5"), "base_link", "tool0")
    assert _max_flange_error_mm(u.chain, back, Q) < TOL_MM


def _bad(text_or_path, *args, **kwargs):
    with pytest.raises(InputError) as info:
        read_urdf_chain(text_or_path, *args, **kwargs)
    return str(info.value)


def test_bad_input_names_the_file_and_the_link_or_joint(nominal, tmp_path):
    good = tmp_path / "good.urdf"
    good.write_text(chain_to_urdf(nominal, "irb2400"))
    msg = _bad(good, "base_link", "flange")
    assert str(good) in msg and "'flange'" in msg and "tool0" in msg  # lists the links there are
    msg = _bad(good, "bse_link", "tool0")
    assert str(good) in msg and "'bse_link'" in msg
    msg = _bad(good, "tool0", "base_link")
    assert "not downstream" in msg
    msg = _bad(good, "base_link", "tool0", joint_names=["a1", "a2", "a3", "a4", "a5", "a6"])
    assert "joint_1" in msg and "a1" in msg

    prismatic = tmp_path / "slide.urdf"
    prismatic.write_text(HAND_WRITTEN.replace('name="j2" type="continuous"', 'name="j2" type="prismatic"').replace(
        '<axis xyz="0.6 0 0.8"/>', '<axis xyz="0.6 0 0.8"/><limit lower="0" upper="1" effort="1" velocity="1"/>'))
    msg = _bad(prismatic, "base", "tcp")
    assert str(prismatic) in msg and "'j2'" in msg and "prismatic" in msg

    not_urdf = tmp_path / "notes.urdf"
    not_urdf.write_text("joint_1 is the base axis\n")
    msg = _bad(not_urdf, "base_link", "tool0")
    assert str(not_urdf) in msg and "not a URDF" in msg
    other_xml = tmp_path / "launch.urdf"
    other_xml.write_text("<launch><node/></launch>")
    assert "<launch>" in _bad(other_xml, "base_link", "tool0")
    missing = tmp_path / "absent.urdf"
    assert str(missing) in _bad(missing, "base_link", "tool0")


def test_inverse_kinematics_reaches_the_pose_from_a_nearby_seed(perturbed):
    rng = np.random.default_rng(11)
    for q in rng.uniform(-2.5, 2.5, (20, 6)):
        if abs(math.sin(q[4])) < 0.1:  # keep away from the wrist singularity
            continue
        T = perturbed.flange_matrices(q)
        sol = chain_inverse_kinematics(perturbed, T, q + rng.normal(0, 0.01, 6))
        assert np.abs(sol - q).max() < 1e-9
        got = perturbed.flange_matrices(sol)
        assert np.linalg.norm(got[:3, 3] - T[:3, 3]) < 1e-9
