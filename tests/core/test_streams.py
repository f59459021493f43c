"""The pose stream's interpolation: exact on a constant twist, its velocity the model's
derivative, gaps refused; the clock relation's definition."""

import numpy as np
import pytest

from spherecal.core import geometry as geo
from spherecal.core.streams import PoseStream, ProfileStream, sensor_to_robot_time


def _screw_stream(t):
    """A flange turning at a constant spatial rate about a fixed axis through the origin
    and translating at a constant velocity: the exact poses at stamps t."""
    w = np.array([0.1, -0.2, 0.3])  # rad/s, base axes
    v = np.array([100.0, -50.0, 20.0])  # mm/s
    R0 = geo.matrix_from_rotvec([0.3, 0.2, -0.1])
    R = geo.matrix_from_rotvec(t[:, None] * w) @ R0
    tt = np.array([10.0, 20.0, 30.0]) + t[:, None] * v
    return R, tt, w, v


def test_interpolation_is_exact_for_a_constant_rate_and_gives_the_velocity():
    ts = np.arange(0, 1, 0.004) + 1.7e9  # robot clock counting from 1970
    R, tt, w, v = _screw_stream(ts - 1.7e9)
    stream = PoseStream(ts, R, tt)
    tq = 1.7e9 + np.array([0.0011, 0.5, 0.9951])
    got = stream.at(tq)
    Rt, ttt, _, _ = _screw_stream(tq - 1.7e9)
    assert got.ok.all()
    np.testing.assert_allclose(got.R, Rt, atol=1e-9)
    np.testing.assert_allclose(got.t, ttt, atol=1e-6)
    np.testing.assert_allclose(got.omega_rad_s, np.tile(w, (3, 1)), atol=1e-7)
    np.testing.assert_allclose(got.v_mm_s, np.tile(v, (3, 1)), atol=1e-6)


def test_velocity_is_the_derivative_of_the_interpolated_pose():
    rng = np.random.default_rng(1)
    ts = np.cumsum(rng.uniform(0.003, 0.005, 50))
    R = geo.matrix_from_rotvec(rng.normal(0, 0.3, (50, 3)))
    tt = rng.normal(0, 50, (50, 3))
    stream = PoseStream(ts, R, tt)
    tq = np.array([ts[10] + 0.001, ts[30] + 0.0025])
    h = 1e-7
    a, b = stream.at(tq), stream.at(tq + h)
    np.testing.assert_allclose((b.t - a.t) / h, a.v_mm_s, rtol=1e-5)
    dR = np.einsum("nij,nkj->nik", b.R, a.R)  # R(t+h) R(t)^T = exp(omega h)
    np.testing.assert_allclose(geo.rotvec_from_matrix(dR) / h, a.omega_rad_s, rtol=1e-4, atol=1e-6)


def test_times_in_a_gap_or_outside_the_stream_are_not_ok():
    ts = np.concatenate([np.arange(0, 0.1, 0.004), np.arange(0.2, 0.3, 0.004)])
    n = len(ts)
    stream = PoseStream(ts, np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)))
    assert stream.gaps() == [(pytest.approx(ts[24]), pytest.approx(0.2))]
    ok = stream.at([0.05, 0.15, 0.25, -0.01, 0.31]).ok
    assert ok.tolist() == [True, False, True, False, False]


def test_stamps_that_do_not_increase_are_refused_with_the_sample():
    ts = np.array([0.0, 0.004, 0.004, 0.012])
    with pytest.raises(ValueError, match="do not increase at sample 2"):
        PoseStream(ts, np.tile(np.eye(3), (4, 1, 1)), np.zeros((4, 3)))


def test_sequence_and_sweep_entries_must_match_the_samples():
    ts = np.array([0.0, 0.004, 0.008])
    R, t = np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 3))
    s = PoseStream.from_quaternions(ts, t, np.tile([1.0, 0, 0, 0], (3, 1)), seq=[4, 5, 7], sweep=[-1, 0, 0])
    assert s.sweep.tolist() == [-1, 0, 0] and s.seq.dtype == np.int64
    with pytest.raises(ValueError, match="3 stamps but 2 sweep entries"):
        PoseStream(ts, R, t, sweep=np.array([0, 0]))
    with pytest.raises(ValueError, match="3 stamps but 4 seq entries"):
        PoseStream(ts, R, t, seq=np.arange(4))


def test_clock_relation_is_offset_plus_drift_from_the_first_profile():
    t = np.array([100.0, 160.0])
    np.testing.assert_allclose(sensor_to_robot_time(t, 2.5, 50e-6, 100.0), [102.5, 162.5 + 60 * 50e-6])


def test_profiles_are_stored_flat_and_read_back_one_by_one():
    ps = ProfileStream.from_profiles([0.0, 0.01], [np.ones((3, 2)), 2 * np.ones((5, 2))], frame=[7, 8])
    assert ps.n == 2 and ps.counts.tolist() == [3, 5]
    np.testing.assert_array_equal(ps.profile(1), 2 * np.ones((5, 2)))
