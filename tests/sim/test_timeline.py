"""Time in the simulated world (spherecal.sim.timeline): the clock, the arm's motion over
true time, the devices' clocks and the streaming helper, against answers worked out by
hand."""

import numpy as np
import pytest

from spherecal.config import OnTheFlyPlan
from spherecal.core import geometry as geo
from spherecal.core.models import Pose
from spherecal.sim import RobotErrorModel, standard_cell
from spherecal.sim.settings import SimulatedControllerSettings
from spherecal.sim.streams import simulate_recording_with_truth
from spherecal.sim.timeline import (DEFAULT_ACCELERATION_MM_S2, DEFAULT_SETTLE_S, DeviceClock, MotionTimeline,
                                    SimClock, SmoothNoise, trapezoid_duration_s)
from reference_sensor import reference_fov

DOWN = geo.matrix_from_rotvec(np.radians([180.0, 0.0, 0.0]))


def _kin():
    from spherecal.plugins.host import PluginHost

    return PluginHost(autoload=False).arm_kinematics({"type": "abb_irb2400"})


def _timeline(accel=1000.0, settle=0.25, **kw) -> MotionTimeline:
    return MotionTimeline(Pose.from_rt(DOWN, [1000.0, 0.0, 800.0]), acceleration_mm_s2=accel, settle_s=settle, **kw)


# the clock ------------------------------------------------------------------------------------
def test_the_clock_moves_only_when_told_and_never_back():
    clock = SimClock()
    assert clock.now_s == 0.0
    assert clock.advance(1.5) == 1.5 and clock.now_s == 1.5
    assert clock.advance_to(1.0) == 1.5  # an earlier time leaves it
    clock.wait(0.5)
    assert clock.now_s == 2.0
    with pytest.raises(ValueError, match="seconds must be finite and >= 0"):
        clock.advance(-0.1)
    with pytest.raises(ValueError, match="finite"):
        clock.advance_to(float("nan"))


# the motion -----------------------------------------------------------------------------------
@pytest.mark.parametrize("accel", [200.0, 1000.0, 2000.0])
def test_a_100_mm_move_at_100_mm_s_takes_its_trapezoid_then_its_settle(accel):
    """Known answer: 100 mm at 100 mm/s reaches the cruise speed when 100 >= 100^2 / a
    (a >= 100 mm/s^2): 100 / 100 + 100 / a s of motion, then the settle; the clock
    stands at its end."""
    tl = _timeline(accel=accel, settle=0.25)
    start = tl.clock.now_s
    timing = tl.move_linear(Pose.from_rt(DOWN, [1100.0, 0.0, 800.0]), 100.0)
    assert timing.motion_s == pytest.approx(1.0 + 100.0 / accel, rel=1e-12)
    assert timing.settle_s == 0.25 and timing.start_s == start
    assert tl.clock.now_s == pytest.approx(start + 1.0 + 100.0 / accel + 0.25, rel=1e-12)
    assert tl.end_s == pytest.approx(tl.clock.now_s, rel=1e-12)


def test_a_short_move_never_reaches_its_speed():
    """Known answer: 10 mm at 100 mm/s with 200 mm/s^2 (100^2 / 200 = 50 mm > 10 mm) is
    triangular: 2 sqrt(10 / 200) s, its peak sqrt(10 x 200) = 44.7 mm/s at the middle."""
    tl = _timeline(accel=200.0, settle=0.0)
    timing = tl.move_linear(Pose.from_rt(DOWN, [1010.0, 0.0, 800.0]), 100.0)
    assert timing.motion_s == pytest.approx(2.0 * np.sqrt(10.0 / 200.0), rel=1e-12)
    mid = timing.motion_s / 2
    _, t, _ = tl.pose_at([mid - 1e-4, mid + 1e-4])
    assert (t[1, 0] - t[0, 0]) / 2e-4 == pytest.approx(np.sqrt(10.0 * 200.0), rel=1e-3)


def test_pose_at_follows_the_trapezoid_along_the_line():
    """Mid-move (half the motion time) the flange is half-way; in the ramp, at tau, it has
    gone a tau^2 / 2; before the move it stands at the start and after it at the target."""
    tl = _timeline(accel=1000.0, settle=0.25)
    tl.clock.advance(2.0)  # the arm stands still for 2 s first
    timing = tl.move_linear(Pose.from_rt(DOWN, [1100.0, 0.0, 800.0]), 100.0)
    assert timing.start_s == 2.0
    T = np.array([1.0, 2.0 + 0.05, 2.0 + timing.motion_s / 2, 2.0 + timing.motion_s + 0.1, 100.0])
    R, t, q = tl.pose_at(T)
    assert q is None  # no arm, no joints
    np.testing.assert_allclose(t[:, 0] - 1000.0, [0.0, 0.5 * 1000.0 * 0.05**2, 50.0, 100.0, 100.0], atol=1e-9)
    np.testing.assert_allclose(t[:, 1:], np.tile([0.0, 800.0], (5, 1)), atol=1e-12)
    np.testing.assert_allclose(R, np.broadcast_to(DOWN, (5, 3, 3)), atol=1e-12)


def test_a_turn_is_timed_by_the_orientation_speed_and_turns_half_way_mid_move():
    """30 deg at 30 deg/s with a 100 mm/s path speed counts as 100 mm of travel: 1 + 100 /
    a s; half-way in time the flange has turned 15 deg about the fixed axis."""
    tl = _timeline(accel=1000.0, settle=0.0)
    turned = geo.matrix_from_rotvec(np.radians([0.0, 0.0, 30.0])) @ DOWN
    with pytest.raises(ValueError, match="orientation_speed_deg_s"):
        tl.move_linear(Pose.from_rt(turned, [1000.0, 0.0, 800.0]), 100.0)
    timing = tl.move_linear(Pose.from_rt(turned, [1000.0, 0.0, 800.0]), 100.0, 30.0)
    assert timing.motion_s == pytest.approx(1.1, rel=1e-12)
    R, _, _ = tl.pose_at([timing.start_s + timing.motion_s / 2])
    assert geo.rotation_angle_deg(DOWN, R[0]) == pytest.approx(15.0, abs=1e-9)


def test_with_an_arm_the_joints_follow_the_line_and_the_flange_its_true_geometry():
    kin = _kin()
    cell = standard_cell("eye_in_hand", seed=2, fov=reference_fov(), arm=kin, robot_error=RobotErrorModel())
    arm = cell.arm
    start = Pose.from_rt(DOWN, [1000.0, 100.0, 800.0])
    q0 = arm.joints_for(start)
    tl = MotionTimeline(start, joints_deg=q0, arm=arm, acceleration_mm_s2=2000.0, settle_s=0.1)
    timing = tl.move_linear(Pose.from_rt(DOWN, [1000.0, 300.0, 800.0]), 200.0)
    T = timing.start_s + np.linspace(0.0, timing.motion_s, 9)
    R_c, t_c, q = tl.commanded_at(T)
    R_n, t_n, _ = tl.reported_at(T)
    R_a, t_a, q_a = tl.pose_at(T)
    assert q.shape == (9, 6) and np.array_equal(q, q_a)
    np.testing.assert_allclose(t_n, t_c, atol=1e-3)  # the nominal model of the splined joints is on the line
    M = arm.true_flange_matrices(q)
    np.testing.assert_allclose(t_a, M[:, :3, 3], atol=1e-12)
    off = np.linalg.norm(t_a - t_n, axis=1)
    assert 0.2 < off.min() and off.max() < 3.0  # the arm's geometric error, not the path
    np.testing.assert_allclose(q[0], q0, atol=1e-9)


# the devices' clocks ------------------------------------------------------------------------------
def test_a_device_clock_maps_true_time_to_its_stamps_and_back():
    clock = DeviceClock(offset_s=0.3, drift_ppm=35.0, epoch_s=1.77e9, jitter_s=1e-5)
    T = np.array([0.0, 1.0, 3600.0])
    stamps = clock.stamp(T)
    np.testing.assert_allclose(stamps - 1.77e9, 0.3 + (1 + 35e-6) * T, atol=5e-7)  # float64 at 1.77e9: 0.24 us
    np.testing.assert_allclose(clock.true_time(stamps), T, atol=5e-7)
    assert clock.stamp(3600.0) - clock.stamp(0.0) - 3600.0 == pytest.approx(0.126, abs=1e-6)  # 35 ppm of an hour
    with pytest.raises(ValueError, match="jitter_s"):
        DeviceClock(jitter_s=-1.0)


def test_the_cells_device_clocks_are_seeded():
    a, b = standard_cell(seed=4, fov=reference_fov()), standard_cell(seed=4, fov=reference_fov())
    c = standard_cell(seed=5, fov=reference_fov())
    assert (a.controller_clock, a.sensor_clock) == (b.controller_clock, b.sensor_clock)
    assert a.controller_clock != c.controller_clock
    assert a.sensor_clock.epoch_s - a.controller_clock.epoch_s == pytest.approx(1.767e9, rel=1e-3)
    for clock in (a.controller_clock, a.sensor_clock, c.controller_clock, c.sensor_clock):
        assert 10.0 <= abs(clock.drift_ppm) <= 50.0


# sampling a stream -----------------------------------------------------------------------------
def test_samples_tick_on_the_devices_clock_and_consecutive_intervals_join():
    tl = _timeline()
    tl.clock.advance(0.5)
    tl.move_linear(Pose.from_rt(DOWN, [1100.0, 0.0, 800.0]), 100.0)
    clock = DeviceClock(offset_s=0.0013, drift_ppm=20.0, epoch_s=3725.25)
    whole = tl.sample(0.0, 2.0, 0.004, clock, np.random.default_rng(0))
    parts = [tl.sample(a, b, 0.004, clock, np.random.default_rng(0)) for a, b in ((0.0, 0.7), (0.7, 2.0))]
    assert whole.lost == 0
    assert np.array_equal(whole.tick, np.concatenate([p.tick for p in parts]))  # no gap, no repeat
    assert np.array_equal(np.diff(whole.tick), np.ones(len(whole.tick) - 1))
    n = len(whole.tick)
    assert n in (500, 501)  # 2 s x (1 + 20 ppm) / 4 ms
    np.testing.assert_allclose(whole.stamp_s - 3725.25, whole.tick * 0.004, atol=1e-9)  # no jitter
    np.testing.assert_allclose(clock.stamp(whole.T_true_s), whole.stamp_s, atol=1e-9)
    assert whole.T_true_s.min() >= 0.0 and whole.T_true_s.max() < 2.0
    _, t, _ = tl.reported_at(whole.T_true_s)
    np.testing.assert_array_equal(whole.t_mm, t)


def test_samples_are_lost_at_the_stated_rate_and_keep_their_tick_numbers():
    tl = _timeline()
    clock = DeviceClock(jitter_s=2e-5)
    s = tl.sample(0.0, 40.0, 0.004, clock, np.random.default_rng(1), drop_rate=0.1)
    assert s.lost + len(s.tick) == 10_000
    assert 800 < s.lost < 1200
    assert np.all(np.diff(s.tick) >= 1) and np.any(np.diff(s.tick) > 1)  # gaps where samples were lost
    jitter = s.stamp_s - s.tick * 0.004
    assert 1.5e-5 < jitter.std() < 2.5e-5 and np.abs(jitter).max() <= 0.001


def test_smooth_noise_is_the_same_whatever_order_it_is_asked_in():
    T = np.array([3.0, 0.2, 7.5, 0.21])
    a = SmoothNoise(0.02, 0.002, 0.05, np.random.default_rng(3))
    b = SmoothNoise(0.02, 0.002, 0.05, np.random.default_rng(3))
    first = a.at(T)
    again = np.vstack([b.at([t]) for t in T[::-1]])[::-1]
    np.testing.assert_array_equal(first, again)
    long = SmoothNoise(0.02, 0.002, 0.05, np.random.default_rng(4)).at(np.arange(0.0, 200.0, 0.004))
    assert long[:, :3].std() == pytest.approx(0.02, rel=0.15)
    assert long[:, 3:].std() == pytest.approx(np.radians(0.002), rel=0.15)
    x = long[:, 0]
    lag = 12  # 48 ms: about exp(-0.96) = 0.38 of correlation left
    r = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert 0.25 < r < 0.5


def test_the_stream_noise_moves_the_report_smoothly():
    tl = _timeline()
    noise = SmoothNoise(0.02, 0.0, 0.05, np.random.default_rng(5))
    s = tl.sample(0.0, 10.0, 0.004, DeviceClock(), np.random.default_rng(6), noise)
    err = s.t_mm - np.array([1000.0, 0.0, 800.0])
    assert 0.01 < err.std() < 0.03
    # 4 ms apart the steps are sqrt(2 (1 - exp(-4 / 50))) = 0.39 of the noise (white noise: 1.41)
    assert np.diff(err, axis=0).std() < 0.5 * err.std()


# the recordings built on it -------------------------------------------------------------------
@pytest.mark.parametrize("arm, expected", [
    (False, [2209, 2658, 710550, 4185210.054275291, 9776.50953820241, -4811409.301971452, 11770.511004924774,
             2.8376700708111073]),
    (True, [2209, 2658, 702639, 4185210.054307252, 9776.50953820241, -5209477.945985022, 11770.511004924774,
            2.8376700708111073, 325316.8571503494]),
])
def test_a_seeded_on_the_fly_recording_is_the_one_it_always_was(arm, expected):
    """The recording of a seed does not change when its motion is evaluated by the
    timeline: figures of the recording made before the motion moved into it."""
    kin = _kin() if arm else None
    cell = standard_cell("eye_in_hand", seed=3, fov=reference_fov(), arm=kin,
                         robot_error=RobotErrorModel() if arm else None)
    rec, truth = simulate_recording_with_truth(cell, OnTheFlyPlan.quick())
    got = [rec.poses.n, len(rec.profiles.t_sensor_s), len(rec.profiles.points_yz_mm), float(rec.poses.t_mm.sum()),
           float((rec.poses.t_robot_s - rec.poses.t_robot_s[0]).sum()), float(rec.profiles.points_yz_mm.sum()),
           float((rec.profiles.t_sensor_s - rec.profiles.t_sensor_s[0]).sum()), float(truth.sample_noise.sum())]
    if arm:
        got.append(float(rec.poses.joints_deg.sum()))
    assert got == pytest.approx(expected, rel=1e-12, abs=1e-9)


def test_the_simulated_controllers_defaults_are_the_timelines():
    s = SimulatedControllerSettings()
    assert (s.acceleration_mm_s2, s.settle_s) == (DEFAULT_ACCELERATION_MM_S2, DEFAULT_SETTLE_S)
    assert trapezoid_duration_s(0.0, 100.0, 1000.0) == 0.0
