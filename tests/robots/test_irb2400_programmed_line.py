"""The programmed-line pose stream of a controller without EGM (an S4C+): the RAPID side
checked offline, the stamps' round trip on the line protocol, and sweeps through the
simulated controller, whose arm moves with its own acceleration (not the one the PC
assumes) and whose stamps come late by a trap's latency with a jitter.

The truth is the simulated controller's motion timeline at the true time of each stamp
(its clock: ``(T - T_reset) (1 + drift)``), less the stamp's constant latency (which a
clock offset absorbs). Figures at 100 mm/s, 100 mm sweeps, 2,000 mm/s^2 assumed, whole-ms
stamps, no jitter: the computed poses off the ramps are within 0.02 mm of the true path
with the true acceleration equal, 0.05 mm with it 20 % lower or higher; on the marked
ramps up to 0.18 mm."""

from __future__ import annotations

import re
from importlib import resources

import numpy as np
import pytest
from pydantic import ValidationError

from spherecal.devices.pose_streaming import pose_stream_assumption
from spherecal.plugins import (PROGRAMMED_LINE_ASSUMPTION, Pose, PoseStreamClockError, PoseStreamError,
                               PoseStreamingRobot)
from spherecal.plugins import line_protocol as P
from spherecal.robots.abb_irb2400 import protocol as SP
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.programmed_line import (ProgrammedLineSettings, ProgrammedMove, line_fraction,
                                                          motion_duration_s, programmed_line_stream,
                                                          time_at_distance_s)
from spherecal.robots.abb_irb2400.rapid_syntax import check_module, check_modules
from spherecal.robots.abb_irb2400.simulator import start_simulator

RAPID_DIR = resources.files("spherecal.robots.abb_irb2400") / "rapid"
CORE = (RAPID_DIR / "SpherecalServer.mod").read_text()
LINE = (RAPID_DIR / "SpherecalLine.mod").read_text()
SERIAL = (RAPID_DIR / "SpherecalSerial.mod").read_text()
ASSUMED = 2000.0


def make_robot(true_acceleration=ASSUMED, jitter_s=0.0, latency_s=0.0, **stream):
    cfg = AbbIrb2400Config(
        pose_stream={"mode": "programmed_line", "acceleration_mm_s2": ASSUMED, **stream},
        simulated={"acceleration_mm_s2": true_acceleration,
                   "line": {"start_jitter_s": jitter_s, "start_latency_s": latency_s, "seed": 4}})
    server = start_simulator(Irb2400Kinematics(), cfg.simulated)
    robot = AbbIrb2400Robot(cfg, url=server.url, on_close=server.stop)
    robot.simulator = server
    return robot


def shifted(pose: Pose, dy_mm: float) -> Pose:
    return Pose.from_xyz_quat_wxyz(pose.translation + [0.0, dy_mm, 0.0], pose.quaternion_wxyz)


def sweeps(robot, speed=100.0, n=2, length=100.0):
    """Forth and back ``n`` times after a move out (the arm stands before the stream)."""
    home = robot.read_flange_pose()
    far = shifted(home, length)
    robot.move_linear(far, 200.0)
    robot.start_pose_stream()
    for _ in range(n):
        robot.move_linear(home, speed)
        robot.move_linear(far, speed)
    return robot.stop_pose_stream()


def path_error_mm(robot, stream, latency_s=0.0) -> np.ndarray:
    """Distance of each computed pose to the simulated arm's true path at its stamp."""
    c = robot.simulator.controller
    T = c.line_clock_true_s(stream.t_robot_s) - latency_s
    _, t_true, _ = c.timeline.reported_at(T)
    return np.linalg.norm(stream.t_mm - t_true, axis=1)


# --- the RAPID side --------------------------------------------------------------------------
def test_the_line_module_passes_with_the_server():
    modules = {"SpherecalServer.mod": CORE, "SpherecalSerial.mod": SERIAL, "SpherecalLine.mod": LINE}
    assert check_modules(modules) == {name: [] for name in modules}


def test_the_server_calls_the_line_module_by_name():
    """The server loads without SpherecalLine.mod: it names the module's routines only in
    late-bound calls (ERR 7 when it is not there), and the module declares them all."""
    for call in ('%"spherecal_line_start"% reset, distance;', '%"spherecal_line_stop"%;',
                 '%"spherecal_line_move"% target, moveSpeed;', '%"spherecal_line_stamps"% n, tStart, tCruiseEnd, tEnd;'):
        assert call in CORE
    assert not re.search(r"^\s*spherecal_line_", CORE, re.M)
    assert "SpherecalLine.mod is not loaded" in CORE
    declared = set(re.findall(r"^  PROC (\w+)", LINE, re.M))
    assert declared == {"spherecal_line_start", "spherecal_line_stop", "spherecal_line_move", "spherecal_line_stamps"}
    assert "TriggInt startTrigg, stampDist \\Start, startInt;" in LINE
    assert "TriggInt cruiseEndTrigg, stampDist, cruiseEndInt;" in LINE  # (no \\Start: before the end)
    assert "TriggL target, speed, startTrigg \\T2:=cruiseEndTrigg, fine," in LINE


@pytest.mark.parametrize("old, new, expected", [
    ("TriggInt startTrigg", "TrigInt startTrigg", "unknown instruction or procedure TrigInt"),
    ("LOCAL VAR triggdata startTrigg;", "LOCAL VAR trigdata startTrigg;", "unknown data type trigdata"),
    ("RETURN Round(ClkRead(lineClock) * 1000);", "RETURN Round(ClkRead(lineClock) * 1000)", "';'"),
])
def test_a_broken_line_module_fails(old, new, expected):
    assert LINE.count(old) == 1
    problems = check_module(LINE.replace(old, new), "SpherecalLine.mod")
    assert any(expected in p for p in problems), problems


# --- the stamps on the line protocol --------------------------------------------------------
def test_the_stamps_round_trip_on_the_line_protocol():
    line = SP.line_time_reply(42, SP.LineStamps(3, 1234, 2034, 8_388_000))
    msg = P.decode_reply(line.rstrip(b"\n"), 6, SP.LINE_REPLY_ARGS)
    assert SP.parse_line_time_reply(msg) == SP.LineStamps(3, 1234, 2034, 8_388_000)
    untaken = SP.line_time_reply(1, SP.LineStamps(1, None, 50, 77)).rstrip(b"\n")
    assert SP.parse_line_time_reply(P.decode_reply(untaken, 6, SP.LINE_REPLY_ARGS)) == SP.LineStamps(1, None, 50, 77)
    start = SP.decode_stream_request(SP.line_start_request(7, True, 12.5))
    assert (start.kind, SP.parse_line_start(start)) == ("LSTART", (True, 12.5))
    longest = SP.line_time_reply(999, SP.LineStamps(9999, SP.MAX_CLOCK_MS, SP.MAX_CLOCK_MS, SP.MAX_CLOCK_MS))
    assert len(longest) <= P.MAX_LINE_CHARS + 1


@pytest.mark.parametrize("body, field", [("T 5 1 12.5 20 30", "start_ms"), ("T 5 -1 2 20 30", "moves"),
                                         ("T 5 1 2 20 x", "end_ms"), ("T 5 1 2 2e1 30", "cruise_end_ms")])
def test_a_bad_stamp_reply_names_its_field(body, field):
    msg = P.decode_reply(P.frame(body).rstrip(b"\n"), 6, SP.LINE_REPLY_ARGS)
    with pytest.raises(P.ProtocolError, match=field):
        SP.parse_line_time_reply(msg)


def test_the_plugin_reply_kinds_cannot_redefine_the_protocol():
    with pytest.raises(P.ProtocolError, match="redefine"):
        P.decode_reply(P.frame("OK 5").rstrip(b"\n"), 6, {"OK": 3})


# --- the PC's model -----------------------------------------------------------------------------
def test_the_trapezoid_passes_its_distances_when_it_says():
    length, v, a = 100.0, 100.0, 2000.0
    total = motion_duration_s(length, v, a)
    assert total == pytest.approx(1.05)
    for d in (1.0, 2.5, 10.0, 50.0, 99.0):
        tau = time_at_distance_s(d, length, v, a)
        assert line_fraction(tau, length, v, a) * length == pytest.approx(d, abs=1e-9)


def test_a_stamp_on_the_ramp_marks_the_whole_move():
    """A stamp 1 mm along a 100 mm/s move lies on the 2.5 mm acceleration ramp: the
    constant-speed part would be timed through the acceleration assumed, so every
    sample of the motion is marked (the stand in position after it is not)."""
    settings = ProgrammedLineSettings(mode="programmed_line", stamp_distance_mm=1.0)
    home = Pose.from_xyz_quat_wxyz([800.0, 0.0, 900.0], [0.0, 0.0, 1.0, 0.0])
    move = ProgrammedMove(home, shifted(home, 100.0), 100.0, 100.0, 10.0, 10.98, 11.2, 1.0)
    stream = programmed_line_stream([move], settings)
    assert stream.on_ramp[stream.t_robot_s <= 11.06].all() and not stream.on_ramp[-1]
    good = programmed_line_stream([ProgrammedMove(home, shifted(home, 100.0), 100.0, 100.0, 10.0, 10.8, 11.2, 10.0)],
                                  ProgrammedLineSettings(mode="programmed_line"))
    assert 0.5 < (~good.on_ramp).mean() < 0.9
    assert not good.at(good.t_robot_s[good.on_ramp][1:2]).ok.any()
    assert good.at(good.t_robot_s[~good.on_ramp][5:6]).ok.all()


# --- sweeps through the simulated controller ------------------------------------------------
def test_a_sweep_gives_a_stream_on_the_controller_clock_that_says_it_is_not_measured():
    robot = make_robot()
    try:
        assert isinstance(robot, PoseStreamingRobot) and robot.can_stream_poses()
        stream = sweeps(robot, n=1)
        c = robot.simulator.controller
        assert [kind for kind in c.requests if kind.startswith("L")] == ["LSTART", "LTIME", "LTIME", "LSTOP"]
        np.testing.assert_allclose(np.diff(stream.t_robot_s), 0.004, atol=1e-9)  # 4 ms of the controller's clock
        assert stream.seq is None and stream.joints_deg is None
        assert stream.assumption.startswith(PROGRAMMED_LINE_ASSUMPTION)
        assert pose_stream_assumption(robot) == stream.assumption == robot.config.pose_stream.assumption()
        assert "2000 mm/s^2" in stream.assumption and "10 mm along" in stream.assumption
        assert robot.pose_stream_counts().received == stream.n
        assert path_error_mm(robot, stream).max() < 0.06  # whole-ms stamps: 0.05 mm at 100 mm/s
    finally:
        robot.close()


@pytest.mark.parametrize("true_acceleration, off_ramp_mm, on_ramp_mm", [(1600.0, 0.06, 0.25), (2400.0, 0.06, 0.25)])
def test_a_true_acceleration_off_the_assumed_one_errs_on_the_ramps_only(true_acceleration, off_ramp_mm, on_ramp_mm):
    """The simulated arm accelerates 20 % slower or faster than assumed: the ramps are
    wrong (marked), the constant-speed part is not (timed from a stamp past the ramp)."""
    robot = make_robot(true_acceleration)
    try:
        stream = sweeps(robot)
        err = path_error_mm(robot, stream)
        assert err[~stream.on_ramp].max() < off_ramp_mm
        assert 0.1 < err[stream.on_ramp].max() < on_ramp_mm  # the ramps do err: the marks are not for nothing
    finally:
        robot.close()


def test_a_late_jittered_stamp_is_a_constant_offset_plus_its_jitter():
    """The trap's latency (12 ms) moves every pose by the same time, which the clock
    offset absorbs; its jitter (1 ms) is what remains, move by move."""
    robot = make_robot(jitter_s=0.001, latency_s=0.012)
    try:
        stream = sweeps(robot)
        late = path_error_mm(robot, stream)
        on_time = path_error_mm(robot, stream, latency_s=0.012)
        assert late[~stream.on_ramp].max() > 1.0  # 12 ms at 100 mm/s
        assert on_time[~stream.on_ramp].max() < 100.0 * (0.0005 + 4 * 0.001)
    finally:
        robot.close()


def test_a_missing_start_stamp_ends_the_data_with_what_was_kept():
    robot = make_robot()
    try:
        home = robot.read_flange_pose()
        robot.start_pose_stream()
        robot.move_linear(shifted(home, 50.0), 100.0)
        robot.simulator.controller.line_faults.miss_start_next = 1
        robot.move_linear(home, 100.0)
        robot.move_linear(shifted(home, 50.0), 100.0)  # after the fault: not used
        with pytest.raises(PoseStreamError, match="no stamp of its start") as info:
            robot.stop_pose_stream()
        kept = info.value.stream
        assert kept is not None and kept.t_robot_s[-1] < 0.8  # the first move alone (0.55 s and its settle)
        assert robot.simulator.controller.line_on is False  # LSTOP was sent all the same
    finally:
        robot.close()


def test_a_move_slower_than_programmed_is_refused():
    """A speed override of 95 %: between the two stamps on the constant-speed part the
    arm takes 42 ms longer than the programmed speed; its poses are not computed."""
    robot = make_robot()
    try:
        home = robot.read_flange_pose()
        robot.start_pose_stream()
        robot.move_linear(shifted(home, 100.0), 100.0)
        c = robot.simulator.controller
        real = c.timeline.move_linear  # the override: the arm moves at 95 % of the speed asked

        def overridden(target, speed, *args, **kwargs):
            return real(target, 0.95 * speed, *args, **kwargs)

        c.timeline.move_linear = overridden
        robot.move_linear(home, 100.0)
        with pytest.raises(PoseStreamClockError, match="did not move at the programmed speed") as info:
            robot.stop_pose_stream()
        assert "duration_tolerance_s" in str(info.value) and info.value.stream is not None
    finally:
        robot.close()


def test_a_stop_far_longer_than_the_settle_is_refused():
    """An arm that decelerates at a tenth of the acceleration assumed arrives late: the
    time from the second stamp to in position exceeds the motion plus settle_max_s
    (both stamps on its constant-speed part, which keeps the programmed speed)."""
    robot = make_robot(true_acceleration=200.0, stamp_distance_mm=30.0, settle_max_s=0.1)
    try:
        with pytest.raises(PoseStreamClockError, match="settle_max_s"):
            sweeps(robot, n=1)
    finally:
        robot.close()


def test_a_stream_without_a_move_has_no_poses():
    robot = make_robot()
    try:
        robot.start_pose_stream()
        with pytest.raises(PoseStreamError, match="no move was made"):
            robot.stop_pose_stream()
    finally:
        robot.close()


def test_the_clock_restarts_once_a_connection():
    robot = make_robot()
    try:
        first = sweeps(robot, n=1)
        second = sweeps(robot, n=1)
        assert second.t_robot_s[0] > first.t_robot_s[-1]  # one clock over both streams
        assert robot.simulator.controller.requests.count("LSTART") == 2
    finally:
        robot.close()


# --- configuration ------------------------------------------------------------------------------
@pytest.mark.parametrize("stream, field", [
    ({"mode": "programmed_line", "acceleration_mm_s2": 0}, "pose_stream.acceleration_mm_s2"),
    ({"mode": "measured"}, "pose_stream.mode"),
    ({"mode": "programmed_line", "stamp_distance_mm": -1}, "pose_stream.stamp_distance_mm"),
    ({"mode": "programmed_line", "ramp_margin": 0.1}, "pose_stream.ramp_margin"),
])
def test_a_bad_stream_setting_names_its_field(stream, field):
    with pytest.raises(ValidationError, match=re.escape(field)):
        AbbIrb2400Config(pose_stream=stream)


def test_egm_and_the_programmed_line_exclude_each_other():
    with pytest.raises(ValidationError, match=r"robot\.pose_stream .* and robot\.egm are both set"):
        AbbIrb2400Config(pose_stream={"mode": "programmed_line"}, egm={"port": 0})
    assert AbbIrb2400Config(egm={"port": 0}).pose_stream is None  # EGM's configuration as before
