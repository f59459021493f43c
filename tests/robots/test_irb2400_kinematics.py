"""IRB 2400 kinematics: known answers, an independent numpy chain, IK round trips."""

import math

import numpy as np
import pytest

from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400.kinematics import (
    Irb2400Geometry,
    Irb2400Kinematics,
    JointLimitError,
    UnreachableError,
    flange_pose_from_joints,
)

S = math.sqrt(0.5)


# --- an independent forward kinematics: plain 4x4 matrices, written from the table ----
def _trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def reference_flange(joints_deg, coupled=True):
    """base_from_flange of the IRB 2400 from the hardware table, without Pinocchio."""
    q1, q2, q3, q4, q5, q6 = np.radians(joints_deg)
    if coupled:
        q3 = q3 - q2  # controller reports axis 3 against the horizontal
    return (
        _rz(q1)
        @ _trans(100, 0, 615) @ _ry(q2)
        @ _trans(0, 0, 705) @ _ry(q3)
        @ _trans(0, 0, 135) @ _rx(q4)
        @ _trans(755, 0, 0) @ _ry(q5)
        @ _trans(85, 0, 0) @ _rx(q6)
        @ _ry(np.pi / 2)  # tool0: z out of the flange
    )


LOWER = np.array([-180, -100, -60, -200, -120, -400.0])
UPPER = np.array([180, 110, 65, 200, 120, 400.0])


def _random_joints(rng, n):
    return rng.uniform(LOWER, UPPER, size=(n, 6))


# --- known answers ---------------------------------------------------------------------
def test_zero_joints_put_the_flange_at_the_published_position():
    pose = flange_pose_from_joints([0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(pose.translation_mm, (940.0, 0.0, 1455.0), atol=1e-9)
    np.testing.assert_allclose(pose.quaternion_wxyz, (0.70711, 0.0, 0.70711, 0.0), atol=1e-5)
    # tool0's z is the base's x at zero joints
    np.testing.assert_allclose(pose.rotation_matrix[:, 2], (1.0, 0.0, 0.0), atol=1e-12)


def test_wrist_bent_down_points_the_flange_down():
    pose = flange_pose_from_joints([0, 0, 0, 0, 90, 0])
    np.testing.assert_allclose(pose.translation_mm, (855.0, 0.0, 1370.0), atol=1e-9)
    np.testing.assert_allclose(pose.rotation_matrix[:, 2], (0.0, 0.0, -1.0), atol=1e-12)


def test_j23_coupling_keeps_the_forearm_horizontal_when_axis_2_moves():
    q = [0, 30, 0, 0, 0, 0]
    coupled = flange_pose_from_joints(q, j23_coupled=True)
    expected_x = 100 + 705 * math.sin(math.radians(30)) + 755 + 85
    expected_z = 615 + 705 * math.cos(math.radians(30)) + 135
    np.testing.assert_allclose(coupled.translation_mm, (expected_x, 0, expected_z), atol=1e-9)
    np.testing.assert_allclose(coupled.quaternion_wxyz, (S, 0, S, 0), atol=1e-12)
    # uncoupled: the same readings tilt the forearm 30 deg down with the upper arm
    serial = flange_pose_from_joints(q, j23_coupled=False)
    np.testing.assert_allclose(serial.rotation_matrix[:, 2], (math.cos(math.radians(30)), 0, -0.5), atol=1e-12)


def test_coupling_conversion_round_trips():
    kin = Irb2400Kinematics()
    q = np.array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])
    np.testing.assert_allclose(np.degrees(kin.model_joints_rad(q)), [10, 20, 10, 40, 50, 60])
    np.testing.assert_allclose(kin.controller_joints_deg(kin.model_joints_rad(q)), q)


@pytest.mark.parametrize("coupled", [True, False])
def test_pinocchio_model_matches_an_independent_matrix_chain(coupled):
    kin = Irb2400Kinematics(j23_coupled=coupled)
    rng = np.random.default_rng(2400)
    for q in _random_joints(rng, 300):
        T = kin.flange_matrix_from_joints(q)
        np.testing.assert_allclose(T, reference_flange(q, coupled), atol=1e-9, err_msg=f"joints {q}")


def test_geometry_is_configuration_not_constants():
    g = Irb2400Geometry()
    longer = g.model_copy(update={"joints": (*g.joints[:4], g.joints[4].model_copy(update={"offset_mm": (800.0, 0, 0)}), g.joints[5])})
    pose = Irb2400Kinematics(longer).flange_pose_from_joints([0] * 6)
    np.testing.assert_allclose(pose.translation_mm, (985.0, 0.0, 1455.0), atol=1e-9)


def test_geometry_the_analytic_ik_cannot_handle_is_refused():
    g = Irb2400Geometry()
    bad = g.joints[4].model_copy(update={"offset_mm": (755.0, 0.0, 10.0)})
    with pytest.raises(ValueError, match=r"joint 5: offset_mm must lie along x \(spherical wrist\)"):
        Irb2400Geometry(joints=(*g.joints[:4], bad, g.joints[5]))


# --- limits ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "joints, message",
    [
        ([0, 0, 70, 0, 0, 0], r"joint 3 = 70\.0000 deg is above its upper limit 65\.0 deg"),
        ([0, -100.5, 0, 0, 0, 0], r"joint 2 = -100\.5000 deg is below its lower limit -100\.0 deg"),
        ([0, 0, 0, 0, 0, 400.01], r"joint 6 = 400\.0100 deg is above its upper limit 400\.0"),
    ],
)
def test_joint_limits_name_joint_value_and_limit(joints, message):
    with pytest.raises(JointLimitError, match=message):
        flange_pose_from_joints(joints)


@pytest.mark.parametrize("joints, message", [([0] * 5, "expected 6 joint values"), ([0, 0, np.nan, 0, 0, 0], "NaN")])
def test_malformed_joints_are_input_errors(joints, message):
    with pytest.raises(ValueError, match=message):
        flange_pose_from_joints(joints)


# --- inverse kinematics ------------------------------------------------------------------
@pytest.mark.parametrize("coupled", [True, False])
def test_ik_recovers_the_joints_nearest_the_seed(coupled):
    kin = Irb2400Kinematics(j23_coupled=coupled)
    rng = np.random.default_rng(7)
    for q in _random_joints(rng, 200):
        pose = kin.flange_pose_from_joints(q)
        got = kin.joints_from_flange_pose(pose, seed_joints_deg=q)
        np.testing.assert_allclose(got, q, atol=1e-6, err_msg=f"joints {q}")


def test_ik_prefers_the_solution_nearest_the_seed():
    kin = Irb2400Kinematics()
    q = np.array([20.0, 10.0, 5.0, 30.0, 60.0, -20.0])
    pose = kin.flange_pose_from_joints(q)
    flipped = kin.joints_from_flange_pose(pose, seed_joints_deg=[20, 10, 5, -150, -60, 160])  # wrist flipped
    np.testing.assert_allclose(flipped, [20, 10, 5, -150, -60, 160], atol=1e-6)
    np.testing.assert_allclose(kin.joints_from_flange_pose(pose, seed_joints_deg=q + 3.0), q, atol=1e-6)
    # axis 6 turns more than once: the turn nearest the seed is chosen
    np.testing.assert_allclose(kin.joints_from_flange_pose(pose, seed_joints_deg=[20, 10, 5, 30, 60, 330])[5], 340.0)


def test_ik_solutions_all_reproduce_the_pose():
    kin = Irb2400Kinematics()
    rng = np.random.default_rng(11)
    for q in _random_joints(rng, 100):
        pose = kin.flange_pose_from_joints(q)
        solutions = kin.joint_solutions(pose, seed_joints_deg=q)
        assert len(solutions) >= 1
        for sol in solutions:
            np.testing.assert_allclose(reference_flange(sol), pose.as_matrix(), atol=1e-6)


def test_ik_without_seed_round_trips_through_fk():
    kin = Irb2400Kinematics()
    pose = Pose.from_rt(np.diag([1.0, -1.0, -1.0]), [1000.0, 200.0, 500.0])  # flange down
    q = kin.joints_from_flange_pose(pose)
    assert kin.within_limits(q)
    back = kin.flange_pose_from_joints(q)
    np.testing.assert_allclose(back.as_matrix(), pose.as_matrix(), atol=1e-9)


def test_ik_at_a_wrist_singularity_keeps_the_seeds_axis_4():
    kin = Irb2400Kinematics()
    pose = flange_pose_from_joints([10, 5, 5, 0, 0, 30])
    q = kin.joints_from_flange_pose(pose, seed_joints_deg=[10, 5, 5, 20, 0, 0])
    np.testing.assert_allclose(q[3], 20.0, atol=1e-9)
    np.testing.assert_allclose(kin.flange_matrix_from_joints(q), pose.as_matrix(), atol=1e-9)


def test_ik_refuses_a_pose_out_of_reach():
    kin = Irb2400Kinematics()
    far = Pose.from_rt(np.eye(3), [2500.0, 0.0, 800.0])
    with pytest.raises(UnreachableError, match=r"translation_mm=\[2500.0, 0.0, 800.0\].*out of reach"):
        kin.joints_from_flange_pose(far)
