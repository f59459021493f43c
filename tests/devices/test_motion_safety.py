"""A robot of its own protocol gets every motion check by deriving from
``spherecal.plugins.MotionSafety``: speed at the tool point, workspace box at both ends,
reach sampled along the path with the inverse kinematics seeded from the current joints,
the first move from where the arm stands, the per-target plan check and the controller's
frame. The robot here speaks no line protocol: its controller is a Python object."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.plugins import (
    DeviceError,
    InputError,
    MotionLimits,
    MotionSafety,
    Pose,
    Robot,
    WorkspaceBox,
    matrix_from_rotvec,
    rotvec_from_matrix,
)

PILLAR_RADIUS_MM = 200.0
#: A tilted flange orientation (away from the half-turn, where a rotation vector flips).
R0 = matrix_from_rotvec(np.radians([170.0, 0.0, 0.0]))


class GantryKinematics:
    """A gantry with a wrist: joints (x, y, z mm, then a rotation vector in deg). Its
    pillar stands on the base's z axis: a flange within ``PILLAR_RADIUS_MM`` of the axis is
    out of reach. Records the seeds it is given."""

    def __init__(self):
        self.seeds: list[np.ndarray] = []

    def flange_pose_from_joints(self, joints_deg, check_limits: bool = True) -> Pose:
        j = np.asarray(joints_deg, dtype=float)
        return Pose.from_rt(matrix_from_rotvec(np.radians(j[3:])), j[:3])

    def joints_from_flange_pose(self, pose: Pose, seed_joints_deg) -> np.ndarray:
        self.seeds.append(np.asarray(seed_joints_deg, dtype=float).copy())
        t = pose.translation
        if np.hypot(t[0], t[1]) < PILLAR_RADIUS_MM:
            raise InputError(f"flange position {[round(v, 1) for v in t]} mm is inside the gantry's pillar")
        return np.concatenate([t, np.degrees(rotvec_from_matrix(pose.rotation_matrix))])


class MemoryController:
    """The robot's controller: it holds the joints, moves when told, and reports poses in
    its own frame (``frame``, controller_from_base)."""

    def __init__(self, joints_deg, frame: Pose | None = None):
        self.joints = np.asarray(joints_deg, dtype=float)
        self.frame = frame or Pose.identity()
        self.moves: list[dict] = []

    def move(self, joints_deg, v_tcp, v_ori, duration_s) -> None:
        self.moves.append({"joints": joints_deg, "v_tcp": v_tcp, "v_ori": v_ori, "duration_s": duration_s})
        self.joints = np.asarray(joints_deg, dtype=float)


class MemoryRobotConfig(MotionLimits):
    """The robot's settings: the core's motion limits, a workspace box by default."""

    workspace: WorkspaceBox = WorkspaceBox(min_mm=(-1000.0, -1000.0, 0.0), max_mm=(1000.0, 1000.0, 1500.0))


class MemoryRobot(MotionSafety):
    """A robot that talks to its controller by method calls: it provides its joints and
    the controller's pose; the checks are MotionSafety's."""

    name = "memory robot"

    def __init__(self, config: MemoryRobotConfig, controller: MemoryController, tool_point_mm=None):
        super().__init__(config, GantryKinematics(), tool_point_mm=tool_point_mm)
        self.controller = controller
        self.closed = False

    def read_joints_deg(self) -> np.ndarray:
        self.last_joints_deg = self.controller.joints.copy()
        return self.last_joints_deg

    def read_controller_pose(self) -> Pose:
        return self.controller.frame @ self.kin.flange_pose_from_joints(self.controller.joints)

    def read_flange_pose(self) -> Pose:
        return self.kin.flange_pose_from_joints(self.read_joints_deg(), check_limits=False)

    def move_linear(self, base_from_flange: Pose, speed_mm_s: float) -> None:
        start, joints = self.check_move_from_here(base_from_flange, speed_mm_s)
        self.controller.move(joints, *self.move_speeds(start, base_from_flange, speed_mm_s))

    def check_open(self) -> None:
        if self.closed:
            raise DeviceError(f"{self.name}: closed; create the robot again")

    def close(self) -> None:
        self.closed = True


def joints_at(x, y, z, R=R0) -> np.ndarray:
    return np.concatenate([[x, y, z], np.degrees(rotvec_from_matrix(R))])


def make_robot(at=(500.0, 0.0, 500.0), tool_point_mm=None, frame=None, **settings) -> MemoryRobot:
    return MemoryRobot(MemoryRobotConfig(**settings), MemoryController(joints_at(*at), frame), tool_point_mm)


def test_a_robot_of_its_own_protocol_honours_the_contract_and_moves():
    robot = make_robot()
    assert isinstance(robot, Robot)
    target = Pose.from_rt(R0, [600.0, 100.0, 450.0])
    robot.check_target(target, 100.0)
    robot.check_move(target, 100.0)
    robot.move_linear(target, 100.0)
    np.testing.assert_allclose(robot.read_flange_pose().translation_mm, [600.0, 100.0, 450.0], atol=1e-9)
    robot.close()
    with pytest.raises(DeviceError, match="memory robot: closed"):
        robot.move_linear(target, 100.0)


@pytest.mark.parametrize("speed, message", [
    (0.0, r"move_linear: speed_mm_s must be a positive number, got 0\.0"),
    (float("nan"), r"speed_mm_s must be a positive number"),
    (300.0, r"speed_mm_s = 300\.0 exceeds the configured max_speed_mm_s = 250\.0; ask for a slower move"),
])
def test_the_speed_is_checked_before_anything_moves(speed, message):
    robot = make_robot()
    with pytest.raises(InputError, match=message):
        robot.move_linear(Pose.from_rt(R0, [600.0, 0.0, 500.0]), speed)
    assert robot.controller.moves == []


def test_the_tool_point_stays_within_the_move_speed():
    """A turning move: the flange alone could go at the move's speed, the sensor 150 mm
    off it would not; the speeds are chosen for the sensor."""
    speed = 100.0
    sensor = (0.0, 20.0, 150.0)
    start = Pose.from_rt(R0, [500.0, 0.0, 500.0])
    target = Pose.from_rt(matrix_from_rotvec(np.radians([0.0, 30.0, 10.0])) @ R0, [540.0, 30.0, 480.0])
    v_tcp, v_ori, duration = make_robot(tool_point_mm=sensor).move_speeds(start, target, speed)
    distance = float(np.linalg.norm(target.translation - start.translation))
    angle = float(np.linalg.norm(rotvec_from_matrix(start.rotation_matrix.T @ target.rotation_matrix)))
    assert (distance + angle * np.linalg.norm(sensor)) / duration <= speed * (1 + 1e-9)  # the sensor's peak
    assert v_tcp < speed and v_ori <= MemoryRobotConfig().orientation_speed_deg_s
    assert duration == pytest.approx(max(distance / v_tcp, np.degrees(angle) / v_ori))
    # without a tool point only the flange (and the reorientation limit) bound the move: faster
    assert make_robot().move_speeds(start, target, speed)[2] < duration


def test_a_target_outside_the_workspace_box_is_refused():
    robot = make_robot()
    with pytest.raises(InputError, match=r"move_linear: target flange position \[600\.0, 0\.0, 1600\.0\] mm is "
                                         r"outside the configured workspace box"):
        robot.move_linear(Pose.from_rt(R0, [600.0, 0.0, 1600.0]), 50.0)
    assert robot.controller.moves == []


def test_the_first_move_from_where_the_arm_stands_is_checked():
    """The arm stands above the box: the straight path to a target inside would leave it."""
    robot = make_robot(at=(500.0, 0.0, 1700.0))
    target = Pose.from_rt(R0, [600.0, 0.0, 500.0])
    robot.check_target(target, 50.0)  # the target alone is fine
    with pytest.raises(InputError, match=r"start flange position \[500\.0, 0\.0, 1700\.0\] mm is outside the "
                                         r"configured workspace box .*jog the arm into the box first"):
        robot.check_move(target, 50.0)
    with pytest.raises(InputError, match="jog the arm into the box first"):
        robot.move_linear(target, 50.0)
    assert robot.controller.moves == []


def test_reach_is_sampled_along_the_path():
    """Both ends are reachable, the straight line between them runs through the pillar."""
    robot = make_robot(at=(-400.0, 0.0, 500.0))
    target = Pose.from_rt(R0, [400.0, 0.0, 500.0])
    with pytest.raises(InputError, match=r"move_linear: point \d+% along the linear path: flange position .* is "
                                         r"inside the gantry's pillar"):
        robot.move_linear(target, 50.0)
    with pytest.raises(InputError, match=r"move_linear: target: .*inside the gantry's pillar"):
        robot.check_move(Pose.from_rt(R0, [0.0, 100.0, 500.0]), 50.0)
    assert robot.controller.moves == []
    # with no samples along the path only the target is checked
    robot = make_robot(at=(-400.0, 0.0, 500.0), path_check_samples=0)
    robot.move_linear(target, 50.0)
    assert len(robot.controller.moves) == 1


def test_the_inverse_kinematics_is_seeded_from_the_current_joints():
    robot = make_robot()
    first, second = Pose.from_rt(R0, [600.0, 0.0, 500.0]), Pose.from_rt(R0, [700.0, 0.0, 500.0])
    robot.check_target(first, 50.0)
    robot.check_target(second, 50.0)
    seeds = robot.kin.seeds
    np.testing.assert_allclose(seeds[0], robot.controller.joints)  # the arm's joints now
    np.testing.assert_allclose(seeds[1], joints_at(600.0, 0.0, 500.0))  # then the previous target's
    with pytest.raises(InputError, match=r"^target: flange position .* inside the gantry's pillar"):
        robot.check_target(Pose.from_rt(R0, [0.0, 0.0, 500.0]), 50.0)


def test_a_controller_in_another_frame_is_refused():
    riser = Pose.from_rt(np.eye(3), [0.0, 0.0, 300.0])
    robot = make_robot(frame=riser)
    off = robot.controller_frame_offset(robot.kin)
    assert off.offset_mm == pytest.approx(300.0) and off.angle_deg == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(DeviceError, match=r"memory robot: the controller reports the flange 300\.0 mm and 0\.00 deg "
                                          r"away .*beyond the tolerance 5 mm / 0\.5 deg.*Nothing was moved\. "
                                          r"Check the riser"):
        robot.check_controller_frame(robot.kin, 5.0, 0.5, advice="Check the riser.")
    assert make_robot().check_controller_frame(GantryKinematics(), 5.0, 0.5).within(1e-9, 1e-9)


#: The controller's flange frame in spherecal's (tool0: z out of the mounting face), as a
#: KUKA's $FLANGE stands (x out of the face): tool0_from_controller_flange, a turn of
#: -90 deg about y (docs/writing-a-robot-plugin.md, "A controller's own flange frame").
TOOL0_FROM_CONTROLLER_FLANGE = Pose.from_rt(matrix_from_rotvec([0.0, -np.pi / 2, 0.0]), [0.0, 0.0, 0.0])


class OwnFlangeController(MemoryController):
    """A controller that reports and takes poses of its own flange frame,
    ``base_from_controller_flange = base_from_tool0 @ TOOL0_FROM_CONTROLLER_FLANGE``."""

    def pose(self, kin) -> Pose:
        return kin.flange_pose_from_joints(self.joints) @ TOOL0_FROM_CONTROLLER_FLANGE


class OwnFlangeRobot(MemoryRobot):
    """The driver converts at its boundary, as the robot guide shows: what it reads from
    the controller times the inverse of tool0_from_controller_flange is tool0's pose; a
    target for the controller is tool0's times it."""

    convert = True

    def read_controller_pose(self) -> Pose:
        reported = self.controller.pose(self.kin)
        return reported @ TOOL0_FROM_CONTROLLER_FLANGE.inverse() if self.convert else reported

    def controller_target(self, base_from_flange: Pose) -> Pose:
        return base_from_flange @ TOOL0_FROM_CONTROLLER_FLANGE if self.convert else base_from_flange


def test_a_controller_whose_flange_frame_is_turned_from_tool0():
    """Unconverted, the controller's poses differ from the model's by 90 deg at the same
    origin: refused, the message naming the flange frame's turn and the fix; converted as
    the guide shows, accepted, and a move's target reaches the controller in its own
    flange frame while the flange (tool0) lands where it was asked."""
    robot = OwnFlangeRobot(MemoryRobotConfig(), OwnFlangeController(joints_at(500.0, 0.0, 500.0)))
    robot.convert = False
    off = robot.controller_frame_offset(robot.kin)
    assert off.offset_mm == pytest.approx(0.0, abs=1e-9) and off.angle_deg == pytest.approx(90.0)
    assert off.flange_turn_deg(5.0) == pytest.approx(90.0)
    with pytest.raises(DeviceError, match=r"The flange's origin agrees: the controller's flange frame is the model's "
                                          r"turned by 90\.0 deg, model_from_controller = quaternion \(w, x, y, z\) "
                                          r"\[0\.7071, 0\.0000, -0\.7071, 0\.0000\] \(a KUKA's \$FLANGE has x out.*"
                                          r"\"A controller's own flange frame\""):
        robot.check_controller_frame(robot.kin, 5.0, 0.5)
    robot.convert = True
    assert robot.check_controller_frame(robot.kin, 5.0, 0.5).within(1e-9, 1e-9)
    target = Pose.from_rt(R0, [600.0, 100.0, 450.0])
    robot.move_linear(target, 100.0)
    np.testing.assert_allclose(robot.read_controller_pose().as_matrix(), target.as_matrix(), atol=1e-9)
    sent = robot.controller_target(target)  # what the controller is told: its own flange's pose
    np.testing.assert_allclose(robot.controller.pose(robot.kin).as_matrix(), sent.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(sent.rotation_matrix[:, 0], target.rotation_matrix[:, 2], atol=1e-12)  # x out
    # a base frame (a riser) is not read as a turned flange
    riser = make_robot(frame=Pose.from_rt(np.eye(3), [0.0, 0.0, 300.0])).controller_frame_offset(robot.kin)
    assert riser.flange_turn_deg(5.0) is None


def test_a_workspace_box_is_required():
    with pytest.raises(InputError, match=r"memory robot: no workspace box configured"):
        MemoryRobot(MotionLimits(), MemoryController(joints_at(500.0, 0.0, 500.0)))
