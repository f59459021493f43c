"""The IRC5 socket server (SpherecalSocket.mod) as the simulated controller serves it, and
what only a socket link has: connections that the controller closes, sessions, a second
client waiting in the listen backlog. The driver never reconnects or resends by itself:
a closed connection stops the run with what was taken kept, and a new robot object
starts a new connection, in which the controller has no staged target.

(The tests that hold on every link run on the socket server too, in
test_irb2400_driver.py.)"""

import socket
import threading

import numpy as np
import pytest

from spherecal.io import dataset as dataio
from spherecal.cli import EXIT_DEVICE, EXIT_OK, main
from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.simulator import SimulatedIrb2400, start_simulator

KIN = Irb2400Kinematics()
DOWN = np.diag([1.0, -1.0, -1.0])  # flange z along -z of base
START = Pose.from_rt(DOWN, [1000.0, 0.0, 900.0])
TARGET = Pose.from_rt(DOWN, [1020.0, 30.0, 880.0])


@pytest.fixture
def server():
    srv = start_simulator(KIN, SimulatedControllerSettings(single_precision=False, transport="socket"))
    srv.controller.joints_deg = KIN.joints_from_flange_pose(START)
    yield srv
    srv.stop()


def connect(srv, timeout_s=0.2, retries=1) -> AbbIrb2400Robot:
    config = AbbIrb2400Config(port=srv.url, timeout_s=timeout_s, retries=retries, move_timeout_extra_s=0.0)
    return AbbIrb2400Robot(config, kinematics=KIN)


def test_the_socket_port_selects_the_tcp_link(server):
    with connect(server) as robot:
        assert robot.transport == "socket" and robot.config.transport == "socket"
        assert robot.ping() == P.PROTOCOL_VERSION
    assert AbbIrb2400Config().transport == "serial"


def test_the_controller_closes_the_connection_during_a_move(server):
    """The controller drops the connection after the MOVL was served (the move is made)
    and before its reply: the driver says so at once and sends nothing again."""
    server.faults.only_kinds = ("MOVL",)
    server.faults.close_before_reply = 1
    robot = connect(server, timeout_s=1.0, retries=2)
    with pytest.raises(DeviceError, match=r"connection lost \(.*the controller closed the connection\); "
                                          r"nothing is sent again: check the network"):
        robot.move_linear(TARGET, 200.0)
    assert robot.resends == 0
    assert server.controller.requests == ["PING", "GETJ", "TGT", "MOVL"]  # the MOVL once, nothing after it
    np.testing.assert_allclose(server.controller.true_flange_pose().translation_mm, TARGET.translation_mm,
                               atol=1e-3)
    with pytest.raises(DeviceError, match="the connection is closed; create the robot again"):
        robot.read_joints_deg()
    assert server.connections == 1  # the driver did not reconnect


def test_a_new_connection_is_a_new_session_without_a_target(server):
    """Session 1 stages a target and loses its connection before the MOVL; a MOVL of
    session 2 naming that target is refused, so no move from an earlier connection can
    be started by a later one."""
    with connect(server) as robot:
        robot._exchange("TGT", lambda seq: P.target_request(seq, TARGET), "OK")
        staged = robot._seq
    with connect(server) as robot:
        with pytest.raises(DeviceError, match=r"refused MOVL .*ERR 4 no_target: target \d+ was staged over an "
                                              r"earlier connection"):
            robot._exchange("MOVL", lambda seq: P.movl_request(seq, 50.0, staged, 10.0), "OK")
        robot.move_linear(TARGET, 200.0)  # a move of its own works
    assert server.controller.moves == 1 and server.connections == 2
    np.testing.assert_allclose(server.controller.true_flange_pose().translation_mm, TARGET.translation_mm,
                               atol=1e-3)


def test_a_serial_line_has_no_sessions():
    """Contrast: the serial server (here over TCP) keeps its staged target when the PC
    reconnects; the socket server does not."""
    ctl = SimulatedIrb2400(KIN, SimulatedControllerSettings(single_precision=False))
    ctl.joints_deg = KIN.joints_from_flange_pose(START)
    assert P.decode_reply(ctl.handle(P.target_request(5, TARGET))).kind == "OK"
    ctl.new_session()  # what the socket server does on a new connection
    reply = P.decode_reply(ctl.handle(P.movl_request(6, 50.0, 5, 10.0)))
    assert P.parse_error_reply(reply) == (P.ErrorCode.NO_TARGET, "target 5 was staged over an earlier connection")
    assert ctl.moves == 0
    srv = start_simulator(KIN, SimulatedControllerSettings(single_precision=False, transport="tcp"))
    try:
        srv.controller.joints_deg = KIN.joints_from_flange_pose(START)
        with connect(srv) as robot:
            robot._exchange("TGT", lambda seq: P.target_request(seq, TARGET), "OK")
            staged = robot._seq
        with connect(srv) as robot:
            robot._exchange("MOVL", lambda seq: P.movl_request(seq, 50.0, staged, 10.0), "OK")
        assert srv.controller.moves == 1 and srv.controller.session == 1
    finally:
        srv.stop()


def test_a_late_reply_never_reaches_the_next_connection(server, monkeypatch):
    """Session A gives up on a late reply and closes; session B, even with the same seq
    (as a fixed start would give), never sees A's reply: it went to A's connection. On a serial
    line only the seq protects B (test_irb2400_stale_replies.py)."""
    from spherecal.robots.abb_irb2400 import driver as driver_module

    monkeypatch.setattr(driver_module, "_initial_seq", lambda: 0)
    server.faults.late_replies = 1
    server.faults.late_reply_delay_s = 0.4
    server.controller.jog([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    with connect(server, retries=0) as robot_a:
        with pytest.raises(DeviceError, match="no valid reply to PING"):  # the session's first exchange
            robot_a.read_joints_deg()
    server.controller.jog([6.0, 5.0, 4.0, 3.0, 2.0, 1.0])
    with connect(server, timeout_s=1.5, retries=0) as robot_b:
        np.testing.assert_allclose(robot_b.read_joints_deg(), [6, 5, 4, 3, 2, 1])
        assert robot_b.stale_replies == 0
    assert server.running and server.error is None  # the reply to a closed connection did no harm


def test_a_second_client_waits_until_the_first_closes(server):
    """The server serves one connection at a time: a second client is connected by TCP
    (the listen backlog) but gets no reply, with a message that says why; once the first
    closes, the second is served, and its unanswered requests come back as stale."""
    first = connect(server)
    second = connect(server, retries=1)
    try:
        with pytest.raises(DeviceError, match=r"no valid reply to PING after 2 attempt\(s\).*serves no other "
                                              r"connection \(it serves one at a time\)"):
            second.ping()
        first.read_joints_deg()
        first.close()
        assert second.ping() == P.PROTOCOL_VERSION
        assert second.stale_replies == 2  # the replies to its two unanswered PINGs
    finally:
        first.close()
        second.close()
    assert server.connections == 2


def test_garbage_from_a_socket_is_a_clear_device_error():
    """A peer that sends bytes without an LF: the driver resynchronises exactly as on a
    serial line (the same code)."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]

    def babble():
        conn, _ = listener.accept()
        with conn:
            conn.recv(100)
            conn.sendall(b"\x00\xffnoise" * 60)
            conn.recv(100)  # until the driver closes

    thread = threading.Thread(target=babble, daemon=True)
    thread.start()
    try:
        config = AbbIrb2400Config(port=f"socket://127.0.0.1:{port}", timeout_s=0.2, retries=0)
        with AbbIrb2400Robot(config) as robot:
            with pytest.raises(DeviceError, match=r"no valid reply to PING after 1 attempt\(s\); "
                                                  r"last problem: received non-ASCII bytes"):
                robot.read_joints_deg()
    finally:
        thread.join(timeout=2)
        listener.close()


@pytest.mark.parametrize("port, message", [
    ("socket://robot", "write a TCP port as socket://host:port"),
    ("socket://robot:0", "the TCP port '0' must be a number 1..65535"),
    ("socket://robot:5000?logging=debug", "write a TCP port as socket://host:port"),
])
def test_a_bad_socket_port_is_refused_by_the_configuration(port, message):
    with pytest.raises(ValueError, match=message):
        AbbIrb2400Config(port=port)


@pytest.mark.slow
def test_a_run_stops_when_the_controller_closes_the_connection(tmp_path, monkeypatch, capsys):
    """A calibration over the socket server; the controller closes the connection during
    the 5th move. The run stops with the device exit code and --resume advice, the journal
    keeps every shot taken, nothing was sent after the dropped request, and --resume
    finishes over a new connection."""
    import re
    from pathlib import Path

    import spherecal.robots.abb_irb2400.plugin as plugin

    servers = []
    real_start = plugin.start_simulator

    def start(kin, settings, cell, **kw):
        srv = real_start(kin, settings, cell, **kw)
        servers.append(srv)
        if len(servers) == 1:  # the first run: drop the connection during the 5th move
            real_move = srv.controller._move

            def move(msg):
                reply = real_move(msg)
                if srv.controller.moves == 5:
                    srv.faults.close_before_reply = 1
                return reply

            srv.controller._move = move
        return srv

    monkeypatch.setattr(plugin, "start_simulator", start)
    text = (Path(__file__).resolve().parents[2] / "examples" / "sim-eye-in-hand.toml").read_text()
    text = re.sub(r"(?m)^output_dir = .*$", 'output_dir = "out"', text)
    text, n = re.subn(r"(?m)^profiles_per_station = 10$", "profiles_per_station = 5", text)  # 20 shots
    assert n == 1
    text = re.sub(r"(?m)^\[sensor\]$", '[robot.simulated]\ntransport = "socket"\n\n[sensor]', text)
    cfg = tmp_path / "socket.toml"
    cfg.write_text(text)
    assert main(["calibrate", str(cfg), "--no-report", "--yes"]) == EXIT_DEVICE
    err = capsys.readouterr().err
    assert "the controller closed the connection" in err and "--resume" in err
    first = servers[0].controller
    journal = cfg.parent / "out" / "journal.jsonl"
    assert len(dataio.read_dataset(journal).observations) == 4  # the shots of the 4 moves answered
    assert first.requests[-1] == "MOVL" and first.requests.count("MOVL") == 5  # nothing after the drop
    assert servers[0].connections == 1
    assert main(["calibrate", str(cfg), "--resume", "--no-report", "--yes"]) == EXIT_OK
    resumed = dataio.read_dataset(journal)
    assert sorted(o.target for o in resumed.observations) == list(range(20))
