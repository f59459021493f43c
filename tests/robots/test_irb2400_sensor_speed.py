"""Speed is limited at the sensor, not only at the flange: a MOVL carries the
flange speed and the reorientation speed, chosen by the driver so that the tool point
(the sensor, 176 mm off the flange in the example cell) stays within the move's speed.
Limiting tool0 alone is not enough: with the controller's 500 deg/s reorientation, that
point reaches about 1.4 m/s in a rotating move."""

from importlib import resources

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.simulator import start_simulator

KIN = Irb2400Kinematics()
SENSOR = (44.5, -19.8, 166.2)  # flange_from_sensor translation of the example cell
DOWN = np.diag([1.0, -1.0, -1.0])


@pytest.fixture
def server():
    srv = start_simulator(KIN, SimulatedControllerSettings(single_precision=False, transport="pty"))
    yield srv
    srv.stop()


def peak_tool_speed(start: Pose, target: Pose, duration: float, point) -> float:
    """The largest speed of ``point`` (flange frame) along the controller's path: position
    linear, orientation by slerp, both over ``duration``; sampled finely."""
    s = np.linspace(0.0, 1.0, 2001)
    rot = Slerp([0, 1], Rotation.from_matrix([start.rotation_matrix, target.rotation_matrix]))(s)
    pos = start.translation + s[:, None] * (target.translation - start.translation) + rot.apply(point)
    return float(np.max(np.linalg.norm(np.diff(pos, axis=0), axis=1)) / (duration / (len(s) - 1)))


def turned_target(start: Pose, deg: float, shift_mm) -> Pose:
    R = geo.matrix_from_rotvec(np.radians([deg, 0.0, deg / 2])) @ start.rotation_matrix
    return Pose.from_rt(R, start.translation + np.asarray(shift_mm, float))


@pytest.mark.parametrize("deg, shift", [(30.0, (40.0, -20.0, 10.0)), (45.0, (0.0, 0.0, 0.0)), (0.0, (80.0, 0, 0))])
def test_the_sensor_stays_within_the_move_speed(server, deg, shift):
    speed = 100.0
    with AbbIrb2400Robot(AbbIrb2400Config(timeout_s=0.5), url=server.url, kinematics=KIN,
                         tool_point_mm=SENSOR) as robot:
        robot.move_linear(Pose.from_rt(DOWN, [1000.0, 100.0, 800.0]), 200.0)
        start = robot.read_flange_pose()
        target = turned_target(start, deg, shift)
        robot.move_linear(target, speed)
    move = server.controller.last_move
    assert move["orientation_speed_deg_s"] <= AbbIrb2400Config().orientation_speed_deg_s
    peak = peak_tool_speed(start, target, move["duration_s"], SENSOR)
    assert peak <= speed * 1.001  # the sensor within the speed
    if deg:
        assert peak > 0.5 * speed  # and not needlessly slow (the bound assumes the worst axis)
    else:
        assert move["speed_mm_s"] == pytest.approx(speed)  # a pure translation runs at the speed given


def test_without_the_tool_point_only_the_flange_is_limited(server):
    """A robot given no tool point, for contrast: the flange within the speed, the sensor
    far above it."""
    with AbbIrb2400Robot(AbbIrb2400Config(timeout_s=0.5), url=server.url, kinematics=KIN) as robot:
        robot.move_linear(Pose.from_rt(DOWN, [1000.0, 100.0, 800.0]), 200.0)
        start = robot.read_flange_pose()
        target = turned_target(start, 45.0, (0.0, 0.0, 0.0))
        robot.move_linear(target, 100.0)
    move = server.controller.last_move
    assert peak_tool_speed(start, target, move["duration_s"], SENSOR) > 1.5 * 100.0


def test_the_controller_refuses_a_reorientation_speed_out_of_range(server):
    ctl = server.controller
    assert P.decode_reply(ctl.handle(P.target_request(5, Pose.from_rt(DOWN, [1000.0, 0.0, 800.0])))).kind == "OK"
    for seq, bad in ((6, 0.0), (7, 600.0)):
        reply = P.decode_reply(ctl.handle(P.movl_request(seq, 50.0, 5, bad)))
        assert reply.kind == "ERR" and P.parse_error_reply(reply)[0] == P.ErrorCode.RANGE
    assert P.decode_reply(ctl.handle(P.movl_request(8, 50.0, 5, 20.0))).kind == "OK"


def test_the_movl_line_carries_both_speeds_and_the_server_uses_them():
    msg = P.decode_request(P.movl_request(12, 150.04, 11, 37.26))
    assert P.parse_movl_request(msg) == (150.0, 11) and P.movl_orientation_speed(msg) == 37.3
    text = (resources.files("spherecal.robots.abb_irb2400") / "rapid" / "SpherecalServer.mod").read_text()
    assert "moveSpeed.v_tcp := speed;" in text and "moveSpeed.v_ori := oriSpeed;" in text
    assert "want := 5;" in text.split('CASE "MOVL":')[1]


def test_the_framework_hands_the_sensor_position_to_the_robot(tmp_path):
    from pathlib import Path

    from spherecal.config import load_config
    from spherecal.app.plugin_host import tool_point_mm

    examples = Path(__file__).resolve().parents[2] / "examples"
    eih = load_config(examples / "sim-eye-in-hand.toml").config
    assert tool_point_mm(eih) == tuple(eih.nominal_transform.translation_mm)
    eth = load_config(examples / "sim-eye-to-hand.toml").config
    assert tool_point_mm(eth) == tuple(eth.acquisition.sphere_centre_mm)
