"""A stream's frame counters and timestamps placed on the sensor's time line (pure logic)."""

import numpy as np
import pytest

from spherecal.sensors.nxsensor_i.stamps import StampFault, StreamStamps

U32 = 1 << 32
P_S = 0.0025  # 400 Hz
P_US = 2500


def _stamps(stamp_modulus=U32, counter_modulus=U32, shift_s=0.0):
    s = StreamStamps(counter_modulus, stamp_modulus, 1e-6)
    s.begin_stream(P_S, shift_s)
    return s


def test_a_u16_microsecond_stamp_wrapping_every_26_frames_unwraps_to_known_times():
    """65,536 us wrap every 26.2 frames at 400 Hz: 100 frames cross it 3 times; the times
    are the stamps' true microseconds (known answer), moved to the exposure's middle."""
    s = _stamps(stamp_modulus=1 << 16, shift_s=100e-6)
    true_us = 60_000 + P_US * np.arange(100)
    placed = [s.add(k, int(us) % (1 << 16)) for k, us in enumerate(true_us)]
    t = np.array([p.t_sensor_s for p in placed])
    np.testing.assert_allclose(t, true_us * 1e-6 + 100e-6, rtol=0, atol=1e-12)
    assert np.all(np.diff(t) > 0)
    assert [p.frame for p in placed] == list(range(100))
    assert all(p.lost_before == 0 and p.late_s == 0 for p in placed)


def test_the_frame_counter_and_a_u32_stamp_wrap_together():
    s = _stamps()
    first_counter, first_us = U32 - 3, U32 - 2 * P_US - 7
    placed = [s.add((first_counter + k) % U32, (first_us + k * P_US) % U32) for k in range(6)]
    assert [p.frame for p in placed] == [U32 - 3 + k for k in range(6)]  # grows past the wrap
    np.testing.assert_allclose([p.t_sensor_s for p in placed], [(first_us + k * P_US) * 1e-6 for k in range(6)],
                               rtol=0, atol=1e-9)


def test_counter_gaps_are_lost_frames():
    s = _stamps()
    s.add(10, 1000)
    p = s.add(14, 1000 + 4 * P_US)  # 11, 12, 13 never arrived
    assert (p.frame, p.lost_before, p.late_s) == (14, 3, 0.0)
    assert s.add(15, 1000 + 5 * P_US).lost_before == 0


def test_a_frame_stamped_late_is_kept_and_marked_and_the_next_is_on_time():
    s = _stamps()
    s.add(0, 0)
    late = s.add(1, P_US + int(0.6 * P_US))
    assert late.late_s == pytest.approx(0.6 * P_S) and late.t_sensor_s == pytest.approx(1.6 * P_S)
    back = s.add(2, 2 * P_US)  # back on its slot: a short step is not late
    assert back.late_s == 0.0
    assert s.add(3, 3 * P_US + int(0.4 * P_US)).late_s == 0.0  # within late_after (half a period)


def test_a_clock_going_back_is_refused_naming_the_frame():
    s = _stamps()
    s.add(0, 50_000)
    s.add(1, 50_000 + P_US)
    with pytest.raises(StampFault, match=r"timestamp went back by 0\.010 ms at frame 2 \(stamp 52490 after 52500.*"
                                         r"not a wrap") as err:
        s.add(2, 52_490)
    assert err.value.kind == "clock_backwards"
    with pytest.raises(StampFault, match="timestamp did not advance at frame 2"):
        _stamps_at(50_000).add(2, 50_000)  # a stamp that does not advance is no later frame either


def _stamps_at(us):
    s = _stamps()
    s.add(1, us)
    return s


def test_a_clock_jump_ends_the_time_line():
    s = _stamps()
    s.add(0, 0)
    with pytest.raises(StampFault, match=r"clock jumped 20\.000 ms ahead at frame 1") as err:
        s.add(1, P_US + 20_000)
    assert err.value.kind == "clock_jump"


@pytest.mark.parametrize("counter, words", [(7, "repeated"), (5, "went back by 2")])
def test_a_counter_that_repeats_or_goes_back_is_refused(counter, words):
    s = _stamps()
    s.add(7, 0)
    with pytest.raises(StampFault, match=f"frame counter {words}: frame {counter} after frame 7") as err:
        s.add(counter, P_US)
    assert err.value.kind == "counter"


def test_a_second_stream_continues_the_clock_and_not_the_counter():
    s = _stamps()
    s.add(100, U32 - 500_000)
    s.begin_stream(P_S)
    p = s.add(900, (U32 - 500_000 + 2_000_000) % U32, max_elapsed_s=3.0)  # 2 s later, across the wrap
    assert (p.frame, p.lost_before) == (900, 0)  # a gap between streams is no loss
    assert p.t_sensor_s == pytest.approx((U32 + 1_500_000) * 1e-6, abs=1e-9)
    # a clock that went back (or restarted) between streams: more than can have passed
    s.begin_stream(P_S)
    with pytest.raises(StampFault, match=r"did not continue between two streams: .* at most 3\.000 s can have passed"):
        s.add(950, 1_000, max_elapsed_s=3.0)


def test_a_second_stream_after_too_long_starts_a_new_time_line():
    s = _stamps()
    s.add(0, 123)
    s.begin_stream(P_S)
    p = s.add(5, 777, max_elapsed_s=3600.0)  # over half the 71.6 min wrap: cannot be followed
    assert p.t_sensor_s == pytest.approx(777e-6, abs=1e-12)


def test_limits_that_cannot_tell_a_wrap_are_refused():
    s = StreamStamps(U32, 1 << 8, 1e-6)  # a 256 us wrap
    with pytest.raises(ValueError, match="not well below half the timestamp's wrap"):
        s.begin_stream(P_S)
    with pytest.raises(ValueError, match="late_after_s < clock_jump_s"):
        StreamStamps(U32, U32, 1e-6).begin_stream(P_S, 0.0, 0.01, 0.005)
