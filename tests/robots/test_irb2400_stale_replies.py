"""Replies of an earlier session never pass for replies of this one: the driver flushes
its input on open and starts its sequence numbers at a random value.

The cases with the protection taken away (no flush, the old fixed start) show what these
tests guard against: there the stale reply is taken and the driver returns old joints.
"""

import numpy as np
import pytest
import serial.serialposix

from spherecal.errors import DeviceError
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


def test_without_any_flush_that_stale_reply_would_be_taken(server, monkeypatch):
    pyserial_does_not_flush_on_open(monkeypatch)
    monkeypatch.setattr(serial.serialposix.Serial, "reset_input_buffer", lambda self: None)
    start_sessions_at(monkeypatch, 41)
    server.send_unsolicited(P.joints_reply(42, OLD))
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), OLD)  # the hazard: old joints


@pytest.mark.parametrize(
    "starts, stale_taken",
    [((100, 600), False), ((0, 0), True)],
    ids=["different-starts", "same-fixed-start-as-before"],
)
def test_a_late_reply_of_an_earlier_session(server, monkeypatch, starts, stale_taken):
    """Session A asks for the joints and gives up before the (late) reply comes; session
    B opens at once and asks too. The late reply reaches B: with different starts (what
    the random start gives, but for a 1-in-1000 chance) it is discarded as stale; with
    the fixed start of the old driver both sessions used seq 1 and B took A's reply."""
    start_sessions_at(monkeypatch, *starts)
    server.faults.late_replies = 1
    server.faults.late_reply_delay_s = 0.4
    server.controller.jog(OLD)
    with connect(server) as robot_a:
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
    start_sessions_at(monkeypatch, P.SEQ_MODULUS - 1)
    with connect(server) as robot:
        np.testing.assert_allclose(robot.read_joints_deg(), HOME, atol=1e-4)
        assert robot._seq == 0
