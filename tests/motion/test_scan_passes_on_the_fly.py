"""Mapping a pass scanned on the fly: each profile through the pose stream at the robot
time of its exposure by the clock relation (offset and drift), never outside the pose
samples nor across a gap, never with a stamp off the pass's frame grid (a step of the
sensor's clock); lost and late frames keep their stamps; the clock relation's
uncertainty at the pass's speed is stated and bounds what is mapped."""

import json

import numpy as np
import pytest

from spherecal.core.clock import ClockRelation
from spherecal.core.models import Pose
from spherecal.core.streams import PoseStream, ProfileStream
from spherecal.io.ply import PlyWriter, read_ply
from spherecal.motion.on_the_fly import PlannedSweep
from spherecal.core.streams import SweepInfo
from spherecal.motion.scan_on_the_fly import PassMapper, PassTaken, map_pass, off_frame_grid, plan_passes

SPEED_MM_S = 100.0
#: robot clock = sensor clock + OFFSET_S + DRIFT (t_sensor - T0_S)
OFFSET_S, DRIFT, T0_S = 1234.5, 80e-6, 40.0
PERIOD_S = 0.0025  # 400 Hz on the sensor's clock
RELATION = ClockRelation(OFFSET_S, DRIFT, T0_S, 20e-6, 1e-6, 0.0, "test")


def flange_x_mm(t_robot_s):
    """The true flange: along base x at SPEED_MM_S from x = 0 at robot time 1300 s."""
    return SPEED_MM_S * (np.asarray(t_robot_s) - 1300.0)


def pose_stream(t0=1300.0, t1=1301.0, period=0.004, drop=()):
    t = np.arange(t0, t1 + 1e-9, period)
    t = np.delete(t, list(drop))
    xyz = np.zeros((len(t), 3))
    xyz[:, 0] = flange_x_mm(t)
    return PoseStream(t, np.repeat(np.eye(3)[None], len(t), axis=0), xyz)


def sensor_time(t_robot_s):
    """The sensor stamp of an exposure at robot time ``t_robot_s`` (the relation inverted)."""
    return (np.asarray(t_robot_s) - OFFSET_S + DRIFT * T0_S) / (1.0 + DRIFT)


def profile_stream(t_robot_first=1299.99, n=420, frame=None, stamp_shift=None):
    """Profiles of one point (y, z) = (0, 0) every PERIOD_S of the sensor's clock; the
    point maps to the flange origin (X = identity)."""
    t = sensor_time(t_robot_first) + PERIOD_S * np.arange(n)
    if stamp_shift is not None:
        t = t + stamp_shift
    frames = np.arange(100, 100 + n) if frame is None else frame
    return ProfileStream.from_profiles(t, [np.zeros((1, 2))] * n, frame=frames)


def test_each_profile_gets_the_pose_at_its_exposure_by_offset_and_drift():
    prof = profile_stream()
    m = map_pass(pose_stream(), prof, RELATION)
    t_robot = prof.t_sensor_s + OFFSET_S + DRIFT * (prof.t_sensor_s - T0_S)  # the definition, written out
    assert np.allclose(m.t_robot_s, t_robot, atol=1e-9)
    assert len(m.mapped) > 390
    assert np.allclose(m.t_mm[:, 0], flange_x_mm(t_robot[m.mapped]), atol=1e-6)
    # the drift matters here: 80 ppm x 25 s after t_sensor0 is 2 ms, 0.2 mm at this speed
    assert DRIFT * (prof.t_sensor_s[0] - T0_S) * SPEED_MM_S > 0.15


def test_profiles_before_the_first_sample_and_after_the_last_are_never_mapped():
    prof = profile_stream(t_robot_first=1299.99, n=420)  # 10 ms before the stream, 40 ms after it
    m = map_pass(pose_stream(), prof, RELATION)
    before = m.t_robot_s < 1300.0
    after = m.t_robot_s > 1300.0 + 250 * 0.004
    assert m.counts() == {"before": int(before.sum()), "after": int(after.sum())}
    assert before.sum() == 4 and after.sum() > 10
    assert not set(m.mapped) & set(np.flatnonzero(before | after))


def test_a_gap_in_the_pose_stream_leaves_its_profiles_out_and_a_lost_sample_does_not():
    lost_one = map_pass(pose_stream(drop=[100]), profile_stream(), RELATION)
    assert "gap" not in lost_one.counts()  # 8 ms between two samples: interpolated
    gap = map_pass(pose_stream(drop=range(100, 110)), profile_stream(), RELATION)
    inside = (gap.t_robot_s > 1300.0 + 99 * 0.004) & (gap.t_robot_s < 1300.0 + 110 * 0.004)
    assert gap.counts()["gap"] == int(inside.sum()) > 10
    assert not set(gap.mapped) & set(np.flatnonzero(inside))


def test_a_frame_exposed_late_keeps_its_stamp_and_a_step_of_the_sensor_clock_ends_the_grid():
    t = 5.0 + PERIOD_S * np.arange(60)
    frames = np.arange(60)
    assert not off_frame_grid(t, frames).any()
    late = t.copy()
    late[10] += 0.4 * PERIOD_S  # one trigger slipped
    late[30:33] += 1.5 * PERIOD_S  # three in a row, then back on schedule
    assert not off_frame_grid(late, frames).any()
    lost = np.delete(t, [20, 21, 22])  # frames lost: the counter's gap keeps the grid
    assert not off_frame_grid(lost, np.delete(frames, [20, 21, 22])).any()
    stepped = t.copy()
    stepped[25:] += 2.0 * PERIOD_S  # the clock stepped 5 ms ahead and stayed there
    assert np.flatnonzero(off_frame_grid(stepped, frames)).tolist() == list(range(25, 60))
    back = t.copy()
    back[40:] -= 0.6 * PERIOD_S
    assert np.flatnonzero(off_frame_grid(back, frames)).tolist() == list(range(40, 60))
    at_end = t.copy()
    at_end[-2:] += PERIOD_S  # off the grid when the stream ends: cannot be told from a step
    assert off_frame_grid(at_end, frames)[-2:].all()
    assert not off_frame_grid(stepped, None).any()  # no counters: nothing can be told


def test_profiles_stamped_after_a_clock_step_are_not_mapped():
    shift = np.zeros(420)
    shift[200:] = 0.005  # the sensor's clock 5 ms ahead from frame 200: 0.5 mm at 100 mm/s
    m = map_pass(pose_stream(), profile_stream(stamp_shift=shift), RELATION)
    assert m.counts()["off_grid"] > 150
    assert m.mapped.max() < 200 and np.all(m.reason[200:] != "")


def test_the_clock_relations_uncertainty_is_stated_at_the_passs_speed():
    prof = profile_stream()
    m = map_pass(pose_stream(), prof, RELATION)
    d = prof.t_sensor_s[m.mapped] - T0_S
    expected = 2 * np.sqrt(20e-6 ** 2 + (1e-6 * d) ** 2) * SPEED_MM_S
    assert m.timing_error_mm == pytest.approx(expected.max(), rel=1e-6)
    given = ClockRelation(OFFSET_S, DRIFT, T0_S, None, None, 0.0, "given")
    assert map_pass(pose_stream(), prof, given).timing_error_mm is None


def _pass():
    start, end = Pose.from_rt(np.eye(3), [0.0, 0, 0]), Pose.from_rt(np.eye(3), [100.0, 0, 0])
    return PlannedSweep(0, "pass1", start, end, SPEED_MM_S, SweepInfo("pass1", SPEED_MM_S, (1.0, 0, 0)), False)


def test_the_mapper_streams_mapped_points_to_the_ply_and_a_line_per_pass(tmp_path):
    X = Pose.from_rt(np.eye(3), [0.0, 0.0, 0.0])
    with PlyWriter(tmp_path / "s.ply", with_profile=True) as w:
        mapper = PassMapper(X, "eye_in_hand", RELATION, w, tmp_path / "s.ply.passes.jsonl", 0.1, fsync=False)
        taken = PassTaken(0, "pass1", SPEED_MM_S, profiles=420)
        m = mapper.add(_pass(), pose_stream(), profile_stream(), taken)
    v = read_ply(tmp_path / "s.ply")
    assert len(v) == len(m.mapped) == taken.mapped
    assert np.allclose(v["x"], flange_x_mm(m.t_robot_s[v["profile"]]), atol=1e-3)  # float32 PLY
    line = json.loads((tmp_path / "s.ply.passes.jsonl").read_text())
    assert line["mapped"] == len(m.mapped) and line["unmapped"] == m.counts()


def test_a_pass_beyond_max_timing_error_is_not_mapped_at_all(tmp_path):
    X = Pose.from_rt(np.eye(3), [0.0, 0.0, 0.0])
    loose = ClockRelation(OFFSET_S, DRIFT, T0_S, 1e-3, 0.0, 0.0, "loose")  # 1 ms: 0.2 mm at 100 mm/s (k = 2)
    with PlyWriter(tmp_path / "s.ply", with_profile=True) as w:
        mapper = PassMapper(X, "eye_in_hand", loose, w, tmp_path / "j.jsonl", 0.1, fsync=False)
        taken = PassTaken(0, "pass1", SPEED_MM_S)
        mapper.add(_pass(), pose_stream(), profile_stream(), taken)
    assert len(read_ply(tmp_path / "s.ply")) == 0 and taken.mapped == 0
    assert taken.unmapped["timing"] > 390 and taken.timing_error_k2_mm == pytest.approx(0.2, rel=1e-3)


def test_passes_alternate_so_each_starts_beside_where_the_last_ended():
    from spherecal.motion.acquisition import Target

    def t(i, label, x, y):
        return Target(i, label, Pose.from_rt(np.eye(3), [x, y, 0.0]), i == 0, 50.0)

    targets = [t(0, "pass1", 0, 0), t(1, "pass1", 10, 0), t(2, "pass2", 0, 5), t(3, "pass2", 10, 5)]
    p1, p2 = plan_passes(targets, 50.0)
    assert p1.end.translation.tolist() == [10, 0, 0] and p2.start.translation.tolist() == [10, 5, 0]
    assert p2.back and p2.info.direction == (-1.0, 0.0, 0.0)
