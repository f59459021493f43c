"""The EGM receiver's per-message logic, driven without a socket: datagrams fed with a
PC clock the test sets. Stamps are the controller's, sequence numbers count the lost,
late and duplicated samples across the uint32 wrap, and a stall or a clock jump ends the
stream with what came before it kept."""

from __future__ import annotations

import numpy as np
import pytest

from spherecal.plugins import PoseStreamClockError, PoseStreamError, PoseStreamStalled
from spherecal.robots.abb_irb2400.config import EgmSettings
from spherecal.robots.abb_irb2400.egm_messages import EgmSample, encode_egm_robot
from spherecal.robots.abb_irb2400.egm_receiver import EgmReceiver

T0 = 1_700_000_000.0
Q = (0.0, 0.0, 1.0, 0.0)


def datagram(seqno, t_s=None, *, x_mm=None, tm_ms=None, mtype=2, quat=Q):
    """An EgmRobot datagram: stamp ``t_s`` (feedBack.time) and x = seqno mm unless given."""
    sec = usec = None
    if t_s is not None:
        sec = int(np.floor(t_s))
        usec = int(round((t_s - sec) * 1e6))
    x = float(seqno % 2**32) if x_mm is None else x_mm
    return encode_egm_robot(EgmSample(seqno=seqno % 2**32, tm_ms=tm_ms, mtype=mtype, translation_mm=(x, 0.0, 1000.0),
                                      quaternion_wxyz=quat, joints_deg=(0, 10, 20, 0, 60, float(seqno % 7)),
                                      time_sec=sec, time_usec=usec))


def receiver(**settings) -> EgmReceiver:
    return EgmReceiver(EgmSettings(port=0, **settings), name="test robot")


def feed(rx, seqnos, *, base=T0, start=None, now=0.0):
    """Feed samples stamped ``base + (seqno - start) * 4 ms`` (the unwrapped seqno)."""
    start = seqnos[0] if start is None else start
    for s in seqnos:
        rx.feed(datagram(s, base + (s - start) * 0.004), now)


def test_lost_samples_are_counted_across_the_uint32_wrap():
    rx = receiver()
    wrap = 2**32
    seqnos = [wrap - 3, wrap - 2, wrap, wrap + 1, wrap + 4]  # lost: wrap - 1, wrap + 2, wrap + 3
    feed(rx, seqnos)
    stream = rx.stream()
    assert rx.counts() == rx.counts().__class__(received=5, lost=3, late=0, duplicates=0, rejected=0)
    assert stream.seq.tolist() == seqnos  # unwrapped: a wrap adds 2**32
    np.testing.assert_allclose(stream.t_robot_s - T0, [0, 0.004, 0.012, 0.016, 0.028], atol=1e-6)
    assert stream.t_mm[:, 0].tolist() == [float(s % wrap) for s in seqnos]
    assert stream.joints_deg.shape == (5, 6)


def test_late_samples_take_their_place_and_duplicates_are_dropped():
    rx = receiver()
    for s in (10, 11, 13, 12, 14, 14, 15):
        rx.feed(datagram(s, T0 + (s - 10) * 0.004), 0.0)
    stream = rx.stream()
    assert stream.seq.tolist() == [10, 11, 12, 13, 14, 15]
    c = rx.counts()
    assert (c.received, c.lost, c.late, c.duplicates, c.rejected) == (6, 0, 1, 1, 0)


def test_a_late_sample_whose_stamp_does_not_fit_is_rejected():
    rx = receiver()
    for s, t in ((10, 0.0), (11, 0.004), (13, 0.012), (12, 0.013), (14, 0.016)):
        rx.feed(datagram(s, T0 + t), 0.0)
    assert rx.stream().seq.tolist() == [10, 11, 13, 14]
    c = rx.counts()
    assert (c.received, c.lost, c.late, c.rejected) == (4, 0, 0, 1)


def test_what_no_controller_sends_is_rejected():
    rx = receiver()
    feed(rx, [1, 2, 3])
    rx.feed(datagram(4, T0 + 0.012, mtype=3), 0.0)  # a sensor's correction message
    rx.feed(datagram(5, T0 + 0.016, quat=(1.0, 0.1, 0.0, 0.0)), 0.0)  # not a unit quaternion
    rx.feed(b"\x01\x02garbage", 0.0)
    c = rx.counts()
    assert (c.received, c.rejected) == (3, 3)


def test_stamps_come_from_header_tm_when_there_is_no_feedback_clock():
    """header.tm (ms, uint32) wraps too; the stamps stay on the controller's count."""
    rx = receiver()
    for k, tm in enumerate((2**32 - 8, 2**32 - 4, 0, 4)):
        rx.feed(datagram(100 + k, None, tm_ms=tm), 0.0)
    stream = rx.stream()
    assert rx.clock_field == "header.tm"
    np.testing.assert_allclose(np.diff(stream.t_robot_s), 0.004, atol=1e-9)
    assert stream.t_robot_s[0] == pytest.approx((2**32 - 8) * 1e-3)


def test_a_stall_ends_the_stream_keeping_what_came():
    rx = receiver(stall_timeout_s=0.1)
    feed(rx, list(range(20)), now=5.0)
    rx.check_stall(5.09)  # within the stall time: nothing
    assert rx.error is None
    rx.check_stall(5.11)
    rx.feed(datagram(20, T0 + 0.080), 5.2)  # after the fault: not used
    with pytest.raises(PoseStreamStalled, match=r"no sample for 0\.110 s .*stall_timeout_s = 0\.1 s\) after seqno "
                                                r"19") as info:
        rx.stream()
    assert info.value.stream.n == 20 and info.value.counts.received == 20


def test_silence_while_the_stream_is_being_stopped_is_no_stall():
    rx = receiver(stall_timeout_s=0.1)
    feed(rx, [1, 2, 3], now=1.0)
    rx.finish(quiet_s=0.0)  # the stop command is on its way
    rx.check_stall(10.0)
    assert rx.stream().n == 3


@pytest.mark.parametrize("step_s, what", [(-0.5, "went backwards"), (0.0, "went backwards"),
                                          (0.5, "jumped")])
def test_a_clock_jump_ends_the_stream_keeping_the_samples_before(step_s, what):
    rx = receiver()
    feed(rx, [1, 2, 3, 4])
    rx.feed(datagram(5, T0 + 0.012 + step_s), 0.0)
    rx.feed(datagram(6, T0 + 0.016 + step_s), 0.0)
    with pytest.raises(PoseStreamClockError, match=f"clock {what} at EGM seqno 5") as info:
        rx.stream()
    assert info.value.stream.seq.tolist() == [1, 2, 3, 4]


def test_a_burst_of_losses_on_a_steady_clock_is_no_jump():
    rx = receiver()
    feed(rx, [1, 2, 3, 104, 105])  # 100 samples lost, the stamps 101 periods apart
    assert rx.counts().lost == 100 and rx.stream().n == 5


def test_a_jump_within_the_tolerance_is_kept_and_one_beyond_is_not():
    rx = receiver(clock_jump_tolerance_ms=1.0)
    feed(rx, [1, 2])
    rx.feed(datagram(3, T0 + 0.008 + 0.0009), 0.0)
    assert rx.error is None
    rx.feed(datagram(4, T0 + 0.0129 + 0.0011), 0.0)
    assert isinstance(rx.error, PoseStreamClockError)


def test_fewer_than_two_samples_is_an_error_naming_the_count():
    rx = receiver()
    feed(rx, [7])
    with pytest.raises(PoseStreamError, match="delivered 1 sample"):
        rx.stream()
