"""Replies of an earlier session never pass for replies of this one: the driver flushes
its input on open, and opens each session with a PING carrying a token of its own; until
the PONG that echoes it, every line is discarded. The server answers in order, so a late
reply of an earlier session comes before that PONG, whatever seq it carries.

The cases with the protection taken away (no flush and no session handshake) show what
these tests guard against: there the stale reply is taken and the driver returns old
joints.
"""

import numpy as np
import pytest
import serial.serialposix

from spherecal.core.errors import DeviceError
from spherecal.robots.abb_irb2400 import driver as driver_module
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.simulator import start_simulator

KIN = Irb2400Kinematics()
HOME = [0.0, 0.0, 0.0, 0.0, 90.0, 0.0]
OLD = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]  # where an earlier session saw the arm
NOW = [6.0, 5.0, 4.0, 3.0, 2.0, 1.0]  # where it is when the new session asks


@pytest.fixture
def server():
    """The simulated controller on a pseudo-terminal, which keeps its device open: bytes
    written to it wait in the device's input queue until a driver opens it."""
    srv = start_simulator(KIN, SimulatedControllerSettings(single_precision=False, transport="pty"))
    yield srv
    srv.stop()


def connect(srv, timeout_s=0.2) -> AbbIrb2400Robot:
    config = AbbIrb2400Config(timeout_s=timeout_s, retries=0, move_timeout_extra_s=0.0)
    return AbbIrb2400Robot(config, url=srv.url, kinematics=KIN)


def start_sessions_at(monkeypatch, *starts):
    """The sessions opened next start from these seqs (their first request carries the
    next one), instead of random ones."""
    it = iter(starts)
    monkeypatch.setattr(driver_module, "_initial_seq", lambda: next(it))


def pyserial_does_not_flush_on_open(monkeypatch):
    """pyserial's posix backend flushes the input itself when it opens a device; take
    that away (as a backend that does not would), so that only the driver's flush
    counts."""
    Serial = serial.serialposix.Serial
    real_open, real_flush = Serial.open, Serial._reset_input_buffer

    def open_(self):
        self._opening = True
        try:
            real_open(self)
        finally:
            self._opening = False

    def flush(self):
        if not getattr(self, "_opening", False):
            real_flush(self)

    monkeypatch.setattr(Serial, "open", open_)
    monkeypatch.setattr(Serial, "_reset_input_buffer", flush)


def test_a_stale_reply_waiting_before_open_is_flushed(server, monkeypatch):
    pyserial_does_not_flush_on_open(monkeypatch)
    start_sessions_at(monkeypatch, 41)
    server.send_unsolicited(P.joints_reply(42, OLD))  # carries the seq of the first request
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), HOME, atol=1e-4)
        assert robot.stale_replies == 0


def without_the_session_handshake(monkeypatch):
    """The driver of protocol version 2: no PING opens the session, so the first reply
    that carries the request's seq is taken."""
    from spherecal.devices import line_robot as linelink

    real = linelink.LineRobot.__init__

    def init(self, *args, **kwargs):
        real(self, *args, **kwargs)
        self._session_open = True

    monkeypatch.setattr(linelink.LineRobot, "__init__", init)


def test_without_any_flush_that_stale_reply_would_be_taken(server, monkeypatch):
    pyserial_does_not_flush_on_open(monkeypatch)
    monkeypatch.setattr(serial.serialposix.Serial, "reset_input_buffer", lambda self: None)
    without_the_session_handshake(monkeypatch)
    start_sessions_at(monkeypatch, 41)
    server.send_unsolicited(P.joints_reply(42, OLD))
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), OLD)  # the hazard: old joints


def test_without_a_flush_the_handshake_alone_discards_it(server, monkeypatch):
    pyserial_does_not_flush_on_open(monkeypatch)
    monkeypatch.setattr(serial.serialposix.Serial, "reset_input_buffer", lambda self: None)
    start_sessions_at(monkeypatch, 41)
    server.send_unsolicited(P.joints_reply(42, OLD))  # the seq the PING will carry
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), HOME, atol=1e-4)
        assert robot.stale_replies == 1


def test_every_seq_of_every_kind_from_an_earlier_session_is_discarded(server, monkeypatch):
    """The worst an earlier session can leave on a serial line, arriving after the flush:
    a reply of every kind under every seq, PONGs included (with that session's token).
    None is taken: the session opens at the PONG with this session's token, and every
    reply after it is this session's."""
    start_sessions_at(monkeypatch, 500)
    old_pose = P.pose_reply(0, KIN.flange_pose_from_joints(OLD)).decode()
    stale = bytearray()
    for seq in range(P.SEQ_MODULUS):
        stale += P.joints_reply(seq, OLD) + P.pong_reply(seq, "0dd5e5510000")
        stale += P.ok_reply(seq) + P.pose_reply(seq, KIN.flange_pose_from_joints(OLD))
    assert old_pose  # (the poses are the old arm's)
    server.faults.reply_delay_s = 0.3  # the stale lines arrive while the PING waits
    server.controller.jog(NOW)
    with connect(server, timeout_s=5.0) as robot:
        import threading

        threading.Timer(0.05, server.send_unsolicited, [bytes(stale)]).start()
        robot.ping()
        assert robot.stale_replies == 4 * P.SEQ_MODULUS
        server.faults.reply_delay_s = 0.0
        np.testing.assert_allclose(robot.read_joints_deg(), NOW, atol=1e-4)
        np.testing.assert_allclose(robot.read_flange_pose().as_matrix(),
                                   KIN.flange_matrix_from_joints(NOW), atol=1e-3)
        assert robot.stale_replies == 4 * P.SEQ_MODULUS


@pytest.mark.parametrize(
    "starts, handshake, stale_taken",
    [((100, 600), True, False), ((0, 0), True, False), ((0, 0), False, True)],
    ids=["different-starts", "same-start", "same-start-without-handshake"],
)
def test_a_late_reply_of_an_earlier_session(server, monkeypatch, starts, handshake, stale_taken):
    """Session A asks for the joints and gives up before the (late) reply comes; session
    B opens at once and asks too. The late reply reaches B and is discarded, even when
    both sessions use the same seqs (the seq alone would let it through 1 time in 1000):
    it comes before the PONG that opens B's session. Without the handshake (the driver of
    protocol version 2) and with the same seqs, B took A's reply."""
    start_sessions_at(monkeypatch, *starts)
    if not handshake:
        without_the_session_handshake(monkeypatch)
    server.controller.jog(OLD)
    with connect(server) as robot_a:
        if handshake:
            robot_a.ping()  # A's session is open; its GETJ carries seq start + 2
            start_sessions_at(monkeypatch, starts[1] + 1)  # B's PING carries that seq too
        server.faults.late_replies = 1
        server.faults.late_reply_delay_s = 0.4
        with pytest.raises(DeviceError, match="no valid reply to GETJ"):
            robot_a.read_joints_deg()
    server.controller.jog(NOW)  # the reply to A, already made, says OLD
    with connect(server, timeout_s=1.0) as robot_b:
        joints = robot_b.read_joints_deg()
        stale = robot_b.stale_replies
    if stale_taken:
        np.testing.assert_allclose(joints, OLD)
    else:
        np.testing.assert_allclose(joints, NOW)
        assert stale == 1


def test_sessions_start_at_random_seqs():
    starts = {driver_module._initial_seq() for _ in range(50)}
    assert len(starts) > 1  # 50 equal draws of 1000 values: never
    assert all(0 <= s < P.SEQ_MODULUS for s in starts)


def test_the_seq_wraps_from_the_last_value(server, monkeypatch):
    start_sessions_at(monkeypatch, P.SEQ_MODULUS - 2)
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), HOME, atol=1e-4)  # PING 999, GETJ 0
        assert robot._seq == 0


def test_no_request_goes_before_the_session_is_open(server):
    with connect(server) as robot:
        robot.read_joints_deg()
        robot.read_flange_pose()
    assert server.controller.requests == ["PING", "GETJ", "GETP"]


def test_a_server_of_protocol_2_is_told_to_update(server, monkeypatch):
    """A server that knows no session token refuses the PING's extra field."""
    monkeypatch.setitem(P.REQUEST_ARGS, "PING", 0)  # the table of a protocol-2 server
    with connect(server) as robot:
        with pytest.raises(DeviceError, match=r"PING.*takes 0 arguments.*protocol version 2 or older refuses "
                                              r"the session token, or answers PING without it; this driver "
                                              r"speaks version 3"):
            robot.read_joints_deg()


# --- a scripted controller: what an earlier session, or a wrong server, leaves before the PONG
class ScriptedServer:
    """A TCP controller that answers each PING with ``before(seq, token)`` lines, then
    ``answer(seq, token)`` (None: nothing), and GETJ with NOW."""

    def __init__(self, before, answer):
        import socket
        import threading

        self.before, self.answer = before, answer
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.listener.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        conn, _ = self.listener.accept()
        with conn, conn.makefile("rb") as lines:
            for line in lines:
                msg = P.decode_request(line)
                if msg.kind == "PING":
                    token = P.ping_token(msg)
                    out = b"".join(self.before(msg.seq, token))
                    reply = self.answer(msg.seq, token)
                    conn.sendall(out + (reply or b""))
                elif msg.kind == "GETJ":
                    conn.sendall(P.joints_reply(msg.seq, NOW))

    def close(self):
        self.listener.close()


def _frame(text: str) -> bytes:
    return P.frame(text)


STALE_BEFORE_PONG = {
    "ok-j-err-under-the-seq": lambda s, t: [P.ok_reply(s), P.joints_reply(s, OLD), P.error_reply(s, 5, "old")],
    "pong-of-another-session": lambda s, t: [P.pong_reply(s, "0123456789ab")],
    "err-dash-and-checksum-err": lambda s, t: [P.error_reply(None, 1, "bad checksum"), P.error_reply(s, 1, "bad")],
    "garbage": lambda s, t: [b"\x00\xffnoise\n", b"J 12 1 2*00\n"],
}


@pytest.mark.parametrize("case", sorted(STALE_BEFORE_PONG))
def test_whatever_comes_before_the_pong_is_discarded(case):
    """Lines of an earlier session before this session's PONG, of any kind and under the
    PING's own seq (an ERR too), are discarded: the session opens at the PONG, at once
    (no resend), and the joints read are the arm's now."""
    before = STALE_BEFORE_PONG[case]
    srv = ScriptedServer(before, lambda s, t: P.pong_reply(s, t))
    try:
        config = AbbIrb2400Config(port=srv.url, timeout_s=1.0, retries=0)
        with AbbIrb2400Robot(config, kinematics=KIN) as robot:
            np.testing.assert_allclose(robot.read_joints_deg(), NOW)
            assert robot.resends == 0 and robot.stale_replies == len(before(0, ""))
    finally:
        srv.close()


@pytest.mark.parametrize(
    "answer, message",
    [
        (lambda s, t: P.pong_reply(s, "0123456789ab"),
         r"answered PING \d+ with the token '0123456789ab', not this session's '[0-9a-f]{12}': its PING handling is "
         r"wrong \(it must echo the token as it came"),
        (lambda s, t: _frame(f"PONG {s} 2"), r"PONG takes 2 arguments, got 1.*protocol version 2 or older"),
        (lambda s, t: P.error_reply(s, 2, "wrong number of fields"),
         r"controller refused PING \(seq \d+\): ERR 2 syntax: wrong number of fields.*protocol version 2 or older"),
        (lambda s, t: None, r"no valid reply to PING after 2 attempt\(s\); last problem: no reply within 0.3 s"),
    ],
    ids=["wrong-token", "protocol-2-pong", "refused", "silent"],
)
def test_a_server_that_does_not_open_the_session_is_named_for_what_it_does(answer, message):
    srv = ScriptedServer(lambda s, t: [], answer)
    try:
        config = AbbIrb2400Config(port=srv.url, timeout_s=0.3, retries=1)
        with AbbIrb2400Robot(config, kinematics=KIN) as robot:
            with pytest.raises(DeviceError, match=message):
                robot.ping()
    finally:
        srv.close()
