"""The simulated controller's model of the RAPID server's read loop: a line is served
once, when it is read, and a move is never run again without a new request.

The fault guarded against: a server that reads with ``ReadStr`` without ``\\Time``.
After 60 s without a request (ERR_DEV_MAXTIME), or after the program is stopped, the arm
jogged and the program started again, its catch-all ``TRYNEXT`` in ``main`` goes on with
``Serve line`` and serves the previous line again, so the last MOVL drives the arm back
to its target with nothing sent from the PC. :class:`ReplayingServerModel`
reproduces that loop here, inside the tests only, to show that the tests below fail
against it.
"""

import numpy as np
import pytest

from spherecal.core.models import Pose
from spherecal.robots.abb_irb2400 import protocol as P
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedControllerSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.simulator import SimulatedIrb2400, SimulatorServer

KIN = Irb2400Kinematics()
DOWN = np.diag([1.0, -1.0, -1.0])  # flange z along -z of base
TARGET = Pose.from_rt(DOWN, [1000.0, 100.0, 900.0])
JOGGED_TO = Pose.from_rt(DOWN, [950.0, -50.0, 1000.0])
SETTINGS = SimulatedControllerSettings(single_precision=False, transport="pty")


class ReplayingServerModel(SimulatedIrb2400):
    """A server loop with the replay fault, for contrast only. The line is not cleared
    before a read; after a read that ends without a line, ``TRYNEXT`` goes on with
    ``Serve line`` and serves the previous line again; and a MOVL moves to its target
    every time it is served."""

    def _serve_read(self, line):
        if line is None:
            self.reads_without_line += 1
            return self._serve(self.line)  # TRYNEXT: Serve line, with the previous line
        self.line = line
        return self._serve(line)

    def _target_reached(self, target_seq):
        return False


def _reply(ctl, request: bytes) -> P.Message:
    return P.decode_reply(ctl.handle(request))


def _moved_then_jogged(model):
    """A controller that served TGT 10 and MOVL 11 (to TARGET); then the operator jogged
    the arm to JOGGED_TO. Returns the controller and the jogged joints."""
    ctl = model(KIN, SETTINGS)
    assert _reply(ctl, P.target_request(10, TARGET)).kind == "OK"
    assert _reply(ctl, P.movl_request(11, 100.0, 10)).kind == "OK"
    np.testing.assert_allclose(ctl.true_flange_pose().translation_mm, TARGET.translation_mm, atol=1e-6)
    jogged = KIN.joints_from_flange_pose(JOGGED_TO, seed_joints_deg=ctl.joints_deg)
    ctl.jog(jogged)
    return ctl, jogged


EVENTS = {
    "read timeout": lambda ctl: ctl.read_timeout(),
    "stop and start": lambda ctl: ctl.restart(),
    "stop, PP to main, start": lambda ctl: ctl.restart(pp_to_main=True),
}


@pytest.mark.parametrize("event", sorted(EVENTS))
def test_a_served_move_is_never_run_again_without_a_request(event):
    ctl, jogged = _moved_then_jogged(SimulatedIrb2400)
    moves, requests = ctl.moves, list(ctl.requests)
    for _ in range(3):
        assert EVENTS[event](ctl) is None  # nothing is sent to the PC
    assert ctl.reads_without_line == 3 and ctl.line == b""
    assert ctl.requests == requests  # no line was served again
    assert ctl.moves == moves
    np.testing.assert_array_equal(ctl.joints_deg, jogged)  # the arm stays where it was jogged to
    # and the server still serves new requests
    assert _reply(ctl, P.ping_request(12, "5e55")).args == (str(P.PROTOCOL_VERSION), "5e55")


@pytest.mark.parametrize("event", ["read timeout", "stop and start"])
def test_a_replaying_server_model_fails_that_test(event):
    """The same events against the replaying loop: the MOVL is served again, unasked, and
    the arm goes back to that MOVL's target. (A PP to main resets the server's data too,
    so that loop does not replay then; the model is not run for that event.)"""
    ctl, jogged = _moved_then_jogged(ReplayingServerModel)
    moves, requests = ctl.moves, list(ctl.requests)
    sent = EVENTS[event](ctl)
    assert P.decode_reply(sent).seq == 11  # a stale OK to the earlier MOVL
    assert ctl.requests == [*requests, "MOVL"]
    assert ctl.moves == moves + 1
    assert not np.allclose(ctl.joints_deg, jogged)
    np.testing.assert_allclose(ctl.true_flange_pose().translation_mm, TARGET.translation_mm, atol=1e-6)


def test_a_repeated_movl_answers_ok_without_moving_again():
    """A MOVL naming a target already reached (resent after a lost reply, or left in the
    input buffer) answers OK and does not move, even after a jog; a new TGT moves."""
    ctl, jogged = _moved_then_jogged(SimulatedIrb2400)
    moves = ctl.moves
    assert _reply(ctl, P.movl_request(11, 100.0, 10)).kind == "OK"  # the very same line
    assert _reply(ctl, P.movl_request(12, 100.0, 10)).kind == "OK"  # a resend, fresh seq
    assert ctl.moves == moves
    np.testing.assert_array_equal(ctl.joints_deg, jogged)
    # a fresh TGT (a new seq) is a new target: the same pose is moved to again
    assert _reply(ctl, P.target_request(13, TARGET)).kind == "OK"
    assert _reply(ctl, P.movl_request(14, 100.0, 13)).kind == "OK"
    assert ctl.moves == moves + 1
    np.testing.assert_allclose(ctl.true_flange_pose().translation_mm, TARGET.translation_mm, atol=1e-6)
    # the replaying model moves on every MOVL naming the staged target
    replaying, jogged = _moved_then_jogged(ReplayingServerModel)
    assert _reply(replaying, P.movl_request(12, 100.0, 10)).kind == "OK"
    assert replaying.moves == 2 and not np.allclose(replaying.joints_deg, jogged)


def test_after_pp_to_main_no_target_is_staged():
    ctl, _ = _moved_then_jogged(SimulatedIrb2400)
    ctl.restart(pp_to_main=True)
    code, _ = P.parse_error_reply(_reply(ctl, P.movl_request(12, 100.0, 10)))
    assert code == P.ErrorCode.NO_TARGET
    assert ctl.moves == 1


@pytest.mark.parametrize("model", [SimulatedIrb2400, ReplayingServerModel], ids=["server", "replaying-server-model"])
def test_read_timeouts_between_requests_over_the_wire(model):
    """Through the real driver on a pty: a move, a jog, two quiet spells long enough for
    the read to time out, then a PING. The server serves the PING and nothing else; the
    replaying model replays the MOVL twice (its stale OKs reach the driver, which discards
    them) and drives the arm back to the MOVL's target."""
    ctl = model(KIN, SETTINGS)
    config = AbbIrb2400Config(timeout_s=5.0, retries=0, move_timeout_extra_s=0.0)
    with SimulatorServer(ctl, "pty") as srv, AbbIrb2400Robot(config, url=srv.url, kinematics=KIN) as robot:
        robot.move_linear(TARGET, 100.0)
        jogged = KIN.joints_from_flange_pose(JOGGED_TO, seed_joints_deg=ctl.joints_deg)
        ctl.jog(jogged)  # the server thread is idle, waiting for a line
        srv.faults.read_timeouts = 2
        assert robot.ping() == P.PROTOCOL_VERSION
        stale = robot.stale_replies
    assert ctl.reads_without_line == 2 and srv.faults.read_timeouts == 0
    if model is SimulatedIrb2400:
        assert ctl.requests == ["PING", "GETJ", "TGT", "MOVL", "PING"]
        assert ctl.moves == 1 and stale == 0
        np.testing.assert_array_equal(ctl.joints_deg, jogged)
    else:
        assert ctl.requests == ["PING", "GETJ", "TGT", "MOVL", "MOVL", "MOVL", "PING"]
        assert ctl.moves == 3 and stale == 2
        np.testing.assert_allclose(ctl.true_flange_pose().translation_mm, TARGET.translation_mm, atol=1e-6)
