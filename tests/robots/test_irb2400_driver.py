"""The IRB 2400 driver against the simulated controller over real links, with faults
injected at runtime. Every test that does not name its link runs on both: the serial
server on a pseudo-terminal (pyserial) and the IRC5 socket server over TCP
(``socket://``, the driver's TcpLink): the driver behaves the same on both. Faults only
a socket server has are in test_irb2400_socket.py."""

import socket
import threading

import numpy as np
import pytest

from spherecal.devices.contract import Robot
from spherecal.core.errors import DeviceError, InputError
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics, UnreachableError
from spherecal.robots.abb_irb2400.simulator import SimulatedIrb2400, start_simulator

TIMEOUT_S = 0.2
DOWN = np.diag([1.0, -1.0, -1.0])  # flange z along -z of base
KIN = Irb2400Kinematics()


#: The two links: the serial server on a pseudo-terminal (a real serial device node) and
#: the IRC5 socket server over TCP.
TRANSPORTS = ["pty", "socket"]


@pytest.fixture(params=TRANSPORTS)
def server(request):
    """The simulated controller on each link."""
    srv = start_simulator(KIN, SimulatedControllerSettings(single_precision=False, transport=request.param))
    yield srv
    srv.stop()


def connect(srv, **overrides) -> AbbIrb2400Robot:
    """A robot on ``srv`` with its session open (PING answered, as the plugin's connect
    does), and the controller's request log cleared: faults set after this apply to the
    test's own requests."""
    settings = dict(timeout_s=TIMEOUT_S, retries=1, move_timeout_extra_s=0.0)
    settings.update(overrides)
    robot = AbbIrb2400Robot(AbbIrb2400Config(**settings), url=srv.url, kinematics=KIN)
    try:
        robot.ping()
    except BaseException:
        robot.close()
        raise
    srv.controller.requests.clear()
    return robot


# --- normal operation --------------------------------------------------------------------
def test_reads_joints_and_pose(server):
    with connect(server) as robot:
        assert isinstance(robot, Robot)
        assert robot.ping() == P.PROTOCOL_VERSION
        np.testing.assert_allclose(robot.read_joints_deg(), [0, 0, 0, 0, 90, 0], atol=1e-4)
        pose = robot.read_flange_pose()
        np.testing.assert_allclose(pose.translation_mm, [855, 0, 1370], atol=1e-3)
        np.testing.assert_allclose(pose.rotation_matrix[:, 2], [0, 0, -1], atol=1e-6)
    assert server.controller.requests == ["PING", "GETJ", "GETP"]


def test_pose_from_joints_uses_forward_kinematics(server):
    server.controller.joints_deg = np.array([10.0, 20.0, 5.0, 30.0, 40.0, 50.0])
    with connect(server, pose_source="joints") as robot:
        pose = robot.read_flange_pose()
    np.testing.assert_allclose(pose.as_matrix(), KIN.flange_matrix_from_joints([10, 20, 5, 30, 40, 50]), atol=1e-3)
    assert server.controller.requests == ["GETJ"]


def test_linear_move_lands_on_the_target(server):
    target = Pose.from_rt(DOWN, [1000.0, 150.0, 800.0])
    with connect(server) as robot:
        robot.move_linear(target, 100.0)
        joints = robot.read_joints_deg()
    assert server.controller.requests == ["GETJ", "TGT", "MOVL", "GETJ"]
    true = server.controller.true_flange_pose()
    np.testing.assert_allclose(true.translation_mm, target.translation_mm, atol=1e-3)
    np.testing.assert_allclose(KIN.flange_matrix_from_joints(joints), target.as_matrix(), atol=1e-3)


@pytest.mark.parametrize("transport", ["tcp", "socket"])
def test_tcp_transports_serve_the_same_protocol(transport):
    """The serial line carried over TCP and the socket server: both socket://, both served
    by the driver's TCP link."""
    srv = start_simulator(KIN, SimulatedControllerSettings(transport=transport))
    try:
        assert srv.url.startswith("socket://127.0.0.1:")
        with connect(srv) as robot:
            assert robot.transport == "socket"
            robot.move_linear(Pose.from_rt(DOWN, [900.0, -100.0, 900.0]), 50.0)
            np.testing.assert_allclose(robot.read_flange_pose().translation_mm, [900, -100, 900], atol=1e-3)
    finally:
        srv.stop()
    assert not srv.running


# --- injected faults ----------------------------------------------------------------------
def test_reply_delay_within_the_timeout_is_fine(server):
    with connect(server) as robot:
        server.faults.reply_delay_s = 0.1
        robot.read_joints_deg()
        assert robot.resends == 0


def test_reply_delay_over_the_timeout_is_a_device_error(server):
    with connect(server) as robot:
        server.faults.reply_delay_s = 0.3
        with pytest.raises(DeviceError, match=r"no valid reply to GETJ after 2 attempt\(s\); last problem: "
                                              r"no reply within 0.2 s.*SpherecalServer is running"):
            robot.read_joints_deg()


def test_a_late_reply_is_discarded_as_stale(server):
    server.controller.joints_deg = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    with connect(server) as robot:
        server.faults.late_replies = 1
        server.faults.late_reply_delay_s = 0.3
        np.testing.assert_allclose(robot.read_joints_deg(), [1, 2, 3, 4, 5, 6])
        assert (robot.resends, robot.stale_replies) == (1, 1)
        robot.read_joints_deg()  # nothing left over: the next exchange is clean
        assert (robot.resends, robot.stale_replies) == (1, 1)


@pytest.mark.parametrize("fault", ["drop_replies", "drop_requests", "truncate_replies", "corrupt_replies",
                                   "corrupt_requests"])
def test_a_lost_or_damaged_line_is_resent(server, fault):
    with connect(server) as robot:
        setattr(server.faults, fault, 1)
        np.testing.assert_allclose(robot.read_joints_deg(), [0, 0, 0, 0, 90, 0], atol=1e-4)
        assert robot.resends == 1
    assert getattr(server.faults, fault) == 0


@pytest.mark.parametrize(
    "fault, message",
    [
        ("corrupt_replies", "checksum mismatch in line"),
        ("truncate_replies", "discarded a partial line"),
        ("corrupt_requests", "controller could not read the request: ERR 1 bad checksum"),
    ],
)
def test_without_retries_the_error_says_what_happened(server, fault, message):
    with connect(server, retries=0) as robot:
        setattr(server.faults, fault, 1)
        with pytest.raises(DeviceError, match=message):
            robot.read_joints_deg()


@pytest.mark.parametrize("kind", ["TGT", "MOVL"])
def test_a_move_survives_a_lost_reply(server, kind):
    start = Pose.from_rt(DOWN, [1000.0, 0.0, 900.0])
    server.controller.joints_deg = KIN.joints_from_flange_pose(start)
    target = Pose.from_rt(DOWN, [1010.0, 0.0, 900.0])
    with connect(server) as robot:
        server.faults.only_kinds = (kind,)
        server.faults.drop_replies = 1
        robot.move_linear(target, 200.0)
        assert robot.resends == 1
    expected = {"TGT": ["GETJ", "TGT", "TGT", "MOVL"], "MOVL": ["GETJ", "TGT", "MOVL", "MOVL"]}[kind]
    assert server.controller.requests == expected
    # a repeated MOVL names the same staged target: the robot ends where commanded
    np.testing.assert_allclose(server.controller.true_flange_pose().translation_mm, [1010, 0, 900], atol=1e-3)


@pytest.mark.parametrize("transport", ["pty", "tcp", "socket"])
def test_disconnect_is_a_clear_device_error(transport):
    server = start_simulator(KIN, SimulatedControllerSettings(transport=transport))
    with server, connect(server) as robot:
        robot.read_joints_deg()
        server.disconnect()
        with pytest.raises(DeviceError, match=r"connection lost .*create the robot again"):
            robot.read_joints_deg()
        with pytest.raises(DeviceError, match="the connection is closed"):
            robot.read_joints_deg()


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_controller_refusal_is_reported_not_retried(transport):
    srv = start_simulator(KIN, SimulatedControllerSettings(max_controller_speed_mm_s=50.0, transport=transport))
    try:
        with connect(srv) as robot:
            with pytest.raises(DeviceError, match=r"controller refused MOVL .*ERR 3 range: speed 100.0 outside"):
                robot.move_linear(Pose.from_rt(DOWN, [1000.0, 0.0, 900.0]), 100.0)
            assert robot.resends == 0
    finally:
        srv.stop()


def test_unreachable_port_is_a_device_error():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nobody listens there
    with pytest.raises(DeviceError, match=r"cannot open 'socket://127.0.0.1:\d+' \(.*refused.*\); check "
                                          r"robot.port and that SpherecalSocket runs on the controller"):
        AbbIrb2400Robot(AbbIrb2400Config(timeout_s=TIMEOUT_S), url=f"socket://127.0.0.1:{port}")


# --- limits: refused before anything is sent ------------------------------------------------
def test_speed_over_the_limit_is_refused_before_sending(server):
    with connect(server, max_speed_mm_s=100.0) as robot:
        with pytest.raises(InputError, match=r"speed_mm_s = 150.0 exceeds the configured max_speed_mm_s = 100.0"):
            robot.move_linear(Pose.from_rt(DOWN, [1000.0, 0.0, 900.0]), 150.0)
        with pytest.raises(InputError, match="speed_mm_s must be a positive number, got 0"):
            robot.move_linear(Pose.from_rt(DOWN, [1000.0, 0.0, 900.0]), 0)
    assert server.controller.requests == []


def test_target_outside_the_workspace_is_refused_before_sending(server):
    box = {"min_mm": (0.0, -500.0, 200.0), "max_mm": (1500.0, 500.0, 1500.0)}
    with connect(server, workspace=box) as robot:
        with pytest.raises(InputError, match=r"target flange position \[1000.0, 600.0, 900.0\] mm is outside"):
            robot.move_linear(Pose.from_rt(DOWN, [1000.0, 600.0, 900.0]), 50.0)
    assert server.controller.requests == []


def test_unreachable_target_is_refused_before_the_move_is_sent(server):
    with connect(server) as robot:
        with pytest.raises(UnreachableError, match=r"target: flange pose translation_mm=\[1500.0, 1400.0, 300.0\]"):
            robot.move_linear(Pose.from_rt(DOWN, [1500.0, 1400.0, 300.0]), 50.0)
    assert server.controller.requests == ["GETJ"]  # the start joints, nothing more


def test_a_linear_path_through_unreachable_space_is_refused(server):
    server.controller.joints_deg = KIN.joints_from_flange_pose(Pose.from_rt(DOWN, [1000.0, 0.0, 500.0]))
    target = Pose.from_rt(DOWN, [-1000.0, 0.0, 500.0])
    KIN.joints_from_flange_pose(target)  # the end alone is reachable
    with connect(server) as robot:
        with pytest.raises(UnreachableError, match=r"point \d+% along the linear path"):
            robot.move_linear(target, 50.0)
    assert "TGT" not in server.controller.requests


# --- the simulated controller itself ----------------------------------------------------------
def test_simulator_answers_bad_requests_with_error_codes():
    ctl = SimulatedIrb2400(KIN)
    assert P.decode_reply(ctl.handle(b"GETJ 1*00\n")).args[:1] == ("1",)  # bad checksum
    code, _ = P.parse_error_reply(P.decode_reply(ctl.handle(P.movl_request(2, 50.0, 1))))
    assert code == P.ErrorCode.NO_TARGET
    ctl.handle(P.target_request(3, Pose.from_rt(DOWN, [2500.0, 0.0, 500.0])))
    code, text = P.parse_error_reply(P.decode_reply(ctl.handle(P.movl_request(4, 50.0, 3))))
    assert (code, text) == (P.ErrorCode.UNREACHABLE, "target out of reach or beyond a joint limit")
    body = "FOO 1"
    code, text = P.parse_error_reply(P.decode_reply(ctl.handle(f"{body}*{P.checksum(body)}\n".encode())))
    assert code == P.ErrorCode.SYNTAX and "unknown request kind 'FOO'" in text


def test_simulator_noise_is_drawn_per_move_not_per_read():
    """At a standstill the controller reports one pose; each move draws a new error."""
    settings = SimulatedControllerSettings(pose_noise="settings", pose_translation_noise_mm=0.05, joint_noise_deg=0.01)
    ctl = SimulatedIrb2400(KIN, settings)
    target = ctl.true_flange_pose()
    poses, joints = [], []
    for i in range(150):
        seq = 3 * i
        P.decode_reply(ctl.handle(P.target_request(seq, target)))
        P.decode_reply(ctl.handle(P.movl_request(seq + 1, 100.0, seq)))
        a = P.parse_pose_reply(P.decode_reply(ctl.handle(P.getp_request(seq + 2))))
        b = P.parse_pose_reply(P.decode_reply(ctl.handle(P.getp_request(seq + 2))))
        assert a.translation_mm == b.translation_mm  # same standstill, same reading
        poses.append(a.translation)
        joints.append(P.parse_joints_reply(P.decode_reply(ctl.handle(P.getj_request(seq + 2)))))
    np.testing.assert_allclose(np.std(poses, axis=0), 0.05, rtol=0.25)
    np.testing.assert_allclose(np.std(joints, axis=0), 0.01, rtol=0.3)


def test_simulator_stops_cleanly():
    before = threading.active_count()
    srv = start_simulator(KIN)
    robot = connect(srv)
    robot.read_joints_deg()
    url = srv.url
    robot.close()
    srv.stop()
    srv.stop()  # twice is fine
    assert not srv.running
    assert threading.active_count() == before
    host, port = url.removeprefix("socket://").split(":")
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection((host, int(port)), timeout=0.2).close()


def test_a_stream_of_garbage_is_a_clear_device_error():
    import os
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        robot = AbbIrb2400Robot(AbbIrb2400Config(timeout_s=TIMEOUT_S, retries=0), url=os.ttyname(slave))
        with robot:
            os.write(master, b"\x00\xffnoise" * 60)  # no LF anywhere
            # the first exchange opens the session
            with pytest.raises(DeviceError, match=r"no valid reply to PING after 1 attempt\(s\); "
                                                  r"last problem: received non-ASCII bytes"):
                robot.read_joints_deg()
    finally:
        os.close(master)
        os.close(slave)
