"""EGM pose streaming end to end over localhost UDP: the IRB 2400 driver, its receiver and
the simulated controller's stream, through SSTART / MOVL / SSTOP on the line protocol.

Moves happen in simulated time: a MOVL's samples (one per 4 ms of the controller's
clock over the move's duration) are all sent before its OK, so a one-second move takes
milliseconds here. The truth is the controller's own pose source at the true time each
stamp maps back to (``t = epoch + T (1 + drift)``)."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest
from pydantic import ValidationError

from spherecal.plugins import Pose, PoseStreamClockError, PoseStreamError, PoseStreamingRobot, PoseStreamStalled
from spherecal.robots.abb_irb2400.config import AbbIrb2400Config, SimulatedEgmSettings
from spherecal.robots.abb_irb2400.driver import AbbIrb2400Robot
from spherecal.robots.abb_irb2400.egm_messages import decode_egm_robot
from spherecal.robots.abb_irb2400.egm_sim import SimulatedEgmServer
from spherecal.robots.abb_irb2400.kinematics import Irb2400Kinematics
from spherecal.robots.abb_irb2400.simulator import start_simulator

EPOCH, DRIFT_PPM = 1.7e9, 30.0


def make_robot(egm=None, simulated=None, egm_source=None, **config):
    egm = {"port": 0, "stall_timeout_s": 0.1, "first_sample_timeout_s": 0.3} if egm is None else egm
    sim = {"egm": {"clock_epoch_s": EPOCH, "clock_drift_ppm": DRIFT_PPM, "stamp_jitter_s": 0.0, "seed": 3},
           **(simulated or {})}
    cfg = AbbIrb2400Config(egm=egm, simulated=sim, **config)
    server = start_simulator(Irb2400Kinematics(), cfg.simulated, egm_source=egm_source)
    robot = AbbIrb2400Robot(cfg, url=server.url, on_close=server.stop)
    robot.simulator = server
    return robot


@pytest.fixture
def robot():
    r = make_robot()
    yield r
    r.close()


def shifted(pose: Pose, dy_mm: float) -> Pose:
    return Pose.from_xyz_quat_wxyz(pose.translation + [0.0, dy_mm, 0.0], pose.quaternion_wxyz)


def true_translation(robot, stream) -> np.ndarray:
    """The controller's pose source at the true time of each stamp."""
    T = (stream.t_robot_s - EPOCH) / (1.0 + DRIFT_PPM * 1e-6)
    return robot.simulator.controller.egm_motion(T)[1]


def test_a_sweep_forth_and_back_streams_every_sample_on_the_controller_clock(robot):
    assert isinstance(robot, PoseStreamingRobot) and robot.can_stream_poses()
    start = robot.read_flange_pose()
    robot.start_pose_stream()
    wall = time.perf_counter()
    robot.move_linear(shifted(start, 100.0), 100.0)  # 1 s of simulated time
    wall = time.perf_counter() - wall
    robot.move_linear(start, 200.0)  # 0.5 s back
    stream = robot.stop_pose_stream()
    counts = robot.pose_stream_counts()
    assert stream.n >= 375 and counts.received == stream.n and counts.lost == counts.late == 0
    assert wall < 0.5, wall  # the move's 250 samples come at once, not in real time
    assert np.all(np.diff(stream.seq) == 1)
    np.testing.assert_allclose(np.diff(stream.t_robot_s), 0.004, atol=1.5e-6)  # the controller's period
    assert stream.t_robot_s[0] > EPOCH  # its own clock, not the PC's
    np.testing.assert_allclose(stream.t_mm, true_translation(robot, stream), atol=2e-3)
    y = stream.t_mm[:, 1] - start.translation[1]
    assert y.max() == pytest.approx(100.0, abs=1e-6) and abs(y[-1]) < 1e-6
    moving = np.flatnonzero((y > 1.0) & (y < 99.0))
    v = np.diff(y[moving]) / np.diff(stream.t_robot_s[moving])  # 100 mm/s out, 200 back (controller clock)
    assert np.isclose(np.abs(v), 100.0 / (1 + DRIFT_PPM * 1e-6), rtol=1e-3).sum() > 200
    assert np.isclose(np.abs(v), 200.0 / (1 + DRIFT_PPM * 1e-6), rtol=1e-3).sum() > 100
    assert stream.joints_deg.shape == (stream.n, 6)


def test_lost_late_and_duplicated_samples_are_counted(robot):
    start = robot.read_flange_pose()
    robot.start_pose_stream()
    robot.simulator.controller.egm.set_faults(drop_next=20, swap_next=1, duplicate_next=1)
    robot.move_linear(shifted(start, 50.0), 100.0)
    stream = robot.stop_pose_stream()
    c = robot.pose_stream_counts()
    assert (c.lost, c.late, c.duplicates) == (20, 1, 1)
    assert robot.simulator.controller.egm.lost == 20
    assert np.all(np.diff(stream.seq) >= 1) and np.diff(stream.seq).max() == 21


def test_a_stalled_stream_ends_with_the_samples_before_kept(robot):
    start = robot.read_flange_pose()
    robot.start_pose_stream()
    sent = robot.simulator.controller.egm.set_faults(stall_after=50)
    robot.move_linear(shifted(start, 50.0), 100.0)
    time.sleep(0.2)  # the stall time (0.1 s) passes on the PC's clock
    with pytest.raises(PoseStreamStalled, match="stalled: no sample for") as info:
        robot.stop_pose_stream()
    assert info.value.stream.n == sent + 50 and info.value.counts.received == info.value.stream.n
    assert robot.simulator.controller.egm.streaming is False  # the controller was told to stop


def test_a_clock_jump_ends_the_stream_and_later_samples_are_not_kept(robot):
    start = robot.read_flange_pose()
    robot.start_pose_stream()
    n_before = robot.simulator.controller.egm.set_faults(clock_jump_s=-0.25)
    robot.move_linear(shifted(start, 50.0), 100.0)
    with pytest.raises(PoseStreamClockError, match="clock went backwards") as info:
        robot.stop_pose_stream()
    assert info.value.stream is None or info.value.stream.n == n_before


def test_poses_come_from_the_streamed_joints_when_the_robot_reads_joints():
    robot = make_robot(pose_source="joints")
    try:
        start = robot.read_flange_pose()
        robot.start_pose_stream()
        robot.move_linear(shifted(start, 30.0), 100.0)
        stream = robot.stop_pose_stream()
    finally:
        robot.close()
    kin = Irb2400Kinematics()
    for k in (0, stream.n // 2, stream.n - 1):
        np.testing.assert_allclose(stream.t_mm[k], kin.flange_pose_from_joints(stream.joints_deg[k]).translation,
                                   atol=1e-9)


# --- refusals ---------------------------------------------------------------------------------------
def test_a_robot_without_an_egm_section_refuses_clearly():
    cfg = AbbIrb2400Config()
    server = start_simulator(Irb2400Kinematics(), cfg.simulated)
    robot = AbbIrb2400Robot(cfg, url=server.url, on_close=server.stop)
    try:
        assert not robot.can_stream_poses()
        with pytest.raises(PoseStreamError, match=r"not configured: add a \[robot.egm\] section"):
            robot.start_pose_stream()
        with pytest.raises(PoseStreamError, match="no pose stream is running"):
            robot.stop_pose_stream()
    finally:
        robot.close()


def test_a_controller_that_cannot_stream_is_refused_before_anything_moves(robot):
    server, robot.simulator = robot.simulator, None  # no UDPUC device leads to the PC
    try:
        with pytest.raises(PoseStreamError, match=r"ERR 7 .*no UDPUC destination.*SpherecalEgm\.mod"):
            robot.start_pose_stream()
    finally:
        robot.simulator = server
    assert server.controller.moves == 0


def test_no_sample_within_the_first_sample_time_is_refused(robot):
    server, robot.simulator = robot.simulator, None
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    server.controller.egm.destination = sink.getsockname()  # the device leads elsewhere
    try:
        with pytest.raises(PoseStreamError, match=r"no sample reached UDP .* within 0\.3 s.*remote address"):
            robot.start_pose_stream()
        assert server.controller.egm.streaming is False and "SSTOP" in server.controller.requests
    finally:
        robot.simulator = server
        sink.close()


def test_a_stream_in_another_frame_is_refused():
    def offset_source(T):
        R = np.broadcast_to(np.diag([-1.0, 1.0, -1.0]), (len(T), 3, 3))
        return R, np.tile([855.0, 0.0, 1380.0], (len(T), 1)), None  # 10 mm above tool0 in wobj0

    robot = make_robot(egm_source=offset_source)
    try:
        with pytest.raises(PoseStreamError, match="10.00 mm and 0.000 deg away from the controller's tool0 in wobj0"):
            robot.start_pose_stream()
        assert robot.simulator.controller.egm.streaming is False
    finally:
        robot.close()


@pytest.mark.parametrize("egm, field", [
    ({"sample_period_ms": 6}, "egm.sample_period_ms"),
    ({"port": 70000}, "egm.port"),
    ({"stall_timeout_s": 0}, "egm.stall_timeout_s"),
    ({"prot": 6510}, "egm.prot"),
])
def test_configuration_errors_name_the_field(egm, field):
    with pytest.raises(ValidationError) as info:
        AbbIrb2400Config(egm=egm)
    assert field in str(info.value)


# --- the simulated stream on a caller's source and clock ----------------------------------------------
def test_the_simulated_stream_follows_a_given_source_on_a_given_clock():
    """What a motion timeline plugs in: source(T) and clock() -> T; samples every 4 ms of
    the controller's clock, stamped epoch + T (1 + drift)."""
    now = {"T": 10.0}

    def source(T):
        T = np.asarray(T)
        return np.broadcast_to(np.eye(3), (len(T), 3, 3)), np.stack([T * 100.0, 0 * T, 0 * T], axis=1), None

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    egm = SimulatedEgmServer(SimulatedEgmSettings(stamp_jitter_s=0.0, clock_drift_ppm=100.0), source,
                             clock=lambda: now["T"])
    egm.destination = sink.getsockname()
    try:
        egm.start(4)
        now["T"] = 10.1
        egm.stop()
        sink.settimeout(1.0)
        samples = [decode_egm_robot(sink.recv(4096)) for _ in range(egm.sent)]
    finally:
        egm.close()
        sink.close()
    assert 25 <= len(samples) <= 26
    t = np.array([s.time_s for s in samples])
    np.testing.assert_allclose(np.diff(t), 0.004, atol=1.5e-6)
    T = (t - 1.7e9) / (1 + 100e-6)
    np.testing.assert_allclose([s.translation_mm[0] for s in samples], T * 100.0, atol=2e-4)
    assert [s.seqno for s in samples] == list(range(len(samples)))
