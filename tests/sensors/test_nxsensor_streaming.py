"""Profile streams of the nxSensor-I through real pyusb calls, against the simulated device
streaming on simulated time: frames at the sensor's rate on its own clock, each measured
at the true time of its exposure; lost, late and faulty frames."""

import re
import time

import numpy as np
import pytest

from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose
from spherecal.devices.contract import DeviceContext, ProfileStreamCounts, ProfileStreamError, ProfileStreamingSensor
from spherecal.sensors.nxsensor_i import NxSensorConfig, NxSensorDriver, SensorClock, SimTime, \
    SimulatedNxSensorBackend, WireConfig, cell_source
from spherecal.sensors.nxsensor_i.plugin import SIM_NOW_KEY, SIM_PROFILE_SOURCE_KEY, SIM_SENSOR_CLOCK_KEY, \
    create_sensor
from spherecal.sim import NoiseModel, plan_stations, standard_cell
from reference_sensor import reference_fov

RATE_HZ = 400.0
P_S = 1 / RATE_HZ
HALF_COUNT_MM = 0.005 / 2 + 1e-9
U32 = 1 << 32
SPEED_MM_S = 10.0


@pytest.fixture
def cell():
    c = standard_cell("eye_in_hand", seed=11, fov=reference_fov(), noise=NoiseModel(point_noise_mm=0.0))
    stations = plan_stations(c.mounting, c.true_transform, c.sphere_centre_mm, c.sphere_radius_mm, field_of_view=c.fov)
    c.move_flange_to(stations[1][1][4])
    return c


def _pose_at(cell):
    """A sweep: the flange moving along base x at SPEED_MM_S from where it stands at T = 0."""
    pose0 = cell.current_base_from_flange
    return lambda T: Pose.from_rt(pose0.rotation_matrix, pose0.translation + [SPEED_MM_S * T, 0.0, 0.0])


@pytest.fixture
def backend(cell):
    return SimulatedNxSensorBackend(cell, clock=SensorClock(offset_s=1234.5, drift_ppm=50.0),
                                    source=cell_source(cell, pose_at=_pose_at(cell), point_noise_mm=0.0))


@pytest.fixture
def logs():
    return []


@pytest.fixture
def driver(backend, logs):
    d = NxSensorDriver(NxSensorConfig(timeout_ms=50, rate_hz=RATE_HZ), backend=backend, log=logs.append,
                       host_clock_s=backend.now_s)
    yield d
    d.close()


def _take(driver, backend, seconds):
    driver.start_profile_stream()
    backend.advance_s(seconds)  # a simulated move: its frames are due at once
    return driver.stop_profile_stream()


def _wait_until(condition, timeout_s=1.0):
    end = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < end, "the reader thread did not get there in time"
        time.sleep(0.001)


def test_a_stream_through_pyusb_gives_every_frame_on_the_sensor_clock_at_its_exposure(driver, backend, cell):
    """300 frames in 0.75 s of simulated time at 400 Hz: stamps on the sensor's clock
    (offset 1234.5 s, 50 ppm fast), one period apart on that clock, each profile the one
    seen at its exposure's true time."""
    t0 = time.monotonic()
    assert isinstance(driver, ProfileStreamingSensor)
    stream = _take(driver, backend, 0.75)
    assert stream.n == 300  # (k + 1) * 2.5 ms / 1.00005 <= 0.75 s
    assert driver.profile_stream_counts == ProfileStreamCounts(received=300, lost=0, late=0)
    truth = backend.streamed
    assert len(truth) == 300 and all(f.sent for f in truth)
    np.testing.assert_allclose(stream.t_sensor_s, [f.t_sensor_s for f in truth], rtol=0, atol=0.6e-6)
    np.testing.assert_allclose(stream.t_sensor_s, [1234.5 + 1.00005 * f.T_true_s for f in truth], rtol=0, atol=0.6e-6)
    np.testing.assert_allclose(np.diff(stream.t_sensor_s), P_S, rtol=0, atol=1.1e-6)
    assert list(stream.frame) == [f.counter for f in truth]
    pose_at = _pose_at(cell)
    for j in range(0, 300, 37):
        ideal = cell.ideal_profile(pose_at(truth[j].T_true_s))
        assert len(ideal) > 50 and stream.profile(j).shape == ideal.shape
        assert np.max(np.abs(stream.profile(j) - ideal)) <= HALF_COUNT_MM
    assert backend.streaming is False
    assert time.monotonic() - t0 < 2.0


def test_two_streams_continue_one_sensor_clock(driver, backend):
    first = _take(driver, backend, 0.1)
    backend.advance_s(3.0)  # the robot moves to the next sweep, not streaming
    second = _take(driver, backend, 0.1)
    assert first.n == second.n == 40
    # the second stream starts at T = 3.1 s, its first frame one period later; the first
    # stream's last frame was its 40th, at 40 periods of the sensor's clock
    assert second.t_sensor_s[0] - first.t_sensor_s[-1] == pytest.approx(3.1 * 1.00005 + P_S - 40 * P_S, abs=2e-6)
    np.testing.assert_allclose(second.t_sensor_s, [f.t_sensor_s for f in backend.streamed[40:]], rtol=0, atol=0.6e-6)
    assert driver.sensor_clock_session == 1
    assert driver.read_profile() is not None  # single shots again, the counter learnt afresh


def test_the_counter_and_the_timestamp_wrap_within_a_stream(driver, backend):
    backend.wrap_soon(5)
    stream = _take(driver, backend, 0.05)
    truth = backend.streamed
    assert stream.n == 20
    assert list(stream.frame) == [U32 - 5 + k for k in range(20)]  # unwrapped: no gap at the wrap
    assert truth[4].t_sensor_s < U32 * 1e-6 < truth[5].t_sensor_s  # the raw stamp wrapped there
    np.testing.assert_allclose(stream.t_sensor_s, [f.t_sensor_s for f in truth], rtol=0, atol=0.6e-6)
    assert np.all(np.diff(stream.t_sensor_s) > 0)
    assert driver.profile_stream_counts == ProfileStreamCounts(20, 0, 0)


def test_lost_frames_are_counted_and_said(driver, backend, logs):
    backend.drop_frames(3, after=10)
    stream = _take(driver, backend, 0.1)
    assert stream.n == 37 and len(backend.streamed) == 40
    assert list(np.diff(stream.frame)) == [1] * 9 + [4] + [1] * 26
    assert driver.profile_stream_counts == ProfileStreamCounts(received=37, lost=3, late=0)
    assert any(f"3 frame(s) lost before frame {stream.frame[10]}" in m for m in logs)


def test_a_late_frame_is_kept_at_its_late_exposure_and_counted(driver, backend, cell, logs):
    backend.delay_exposures(0.6 * P_S, after=10)
    stream = _take(driver, backend, 0.1)
    assert stream.n == 40 and driver.profile_stream_counts == ProfileStreamCounts(40, 0, 1)
    late = backend.streamed[10]
    assert late.late_s == pytest.approx(0.6 * P_S)
    assert stream.t_sensor_s[10] == pytest.approx(late.t_sensor_s, abs=0.6e-6)
    ideal = cell.ideal_profile(_pose_at(cell)(late.T_true_s))
    assert np.max(np.abs(stream.profile(10) - ideal)) <= HALF_COUNT_MM  # measured when it was exposed
    assert any(f"frame {stream.frame[10]} was exposed 1.500 ms late" in m for m in logs)


@pytest.mark.parametrize("step_s, message", [
    (0.020, r"sensor's clock jumped 20\.000 ms ahead at frame"),
    (-0.004, r"sensor's timestamp went back by 1\.500 ms at frame"),
])
def test_a_clock_step_ends_the_stream_keeping_what_was_taken(driver, backend, step_s, message):
    backend.step_clock(step_s, after=10)
    with pytest.raises(ProfileStreamError, match=message + r".* while streaming profiles; the stream ended there, "
                                                           r"keeping 10 frame\(s\)") as err:
        _take(driver, backend, 0.1)
    assert err.value.taken.n == 10 and err.value.counts == ProfileStreamCounts(10, 0, 0)
    np.testing.assert_allclose(err.value.taken.t_sensor_s, [f.t_sensor_s for f in backend.streamed[:10]], atol=0.6e-6)
    assert backend.streaming is False  # the driver stopped the device


def test_a_stalled_stream_ends_with_a_named_error_keeping_its_frames(driver, backend):
    backend.hang_stream(after_frames=20)
    driver.start_profile_stream()
    backend.advance_s(1.0)
    _wait_until(lambda: driver.profile_stream_error is not None)  # seen while the robot would still move
    assert "stall" in str(driver.profile_stream_error)
    with pytest.raises(ProfileStreamError, match=r"nxSensor-I \(USB 04b4:5a01\): no frame for 9\d\d ms of the stream "
                                                 r"\(stall_timeout_ms = 500\): the stream stalled after 20 frame"):
        driver.stop_profile_stream()
    with pytest.raises(DeviceError, match="no profile stream is running"):
        driver.stop_profile_stream()


def test_a_stream_that_never_starts_is_a_stall(driver, backend):
    backend.hang_stream(after_frames=0)
    driver.start_profile_stream()
    backend.advance_s(0.6)
    with pytest.raises(ProfileStreamError, match=r"stalled after 0 frame\(s\)") as err:
        driver.stop_profile_stream()
    assert err.value.taken is None


def test_a_short_wait_is_no_stall(driver, backend):
    """Half the stall limit without frames (no simulated time passing is no wait at all)."""
    driver.start_profile_stream()
    backend.advance_s(0.3)
    time.sleep(0.02)
    assert driver.profile_stream_error is None
    assert driver.stop_profile_stream().n == 120


def test_a_device_gone_ends_the_stream_keeping_what_was_taken(driver, backend):
    driver.start_profile_stream()
    backend.advance_s(0.05)
    _wait_until(lambda: driver.profile_stream_progress.received == 20)
    backend.disconnect()
    backend.advance_s(0.05)
    with pytest.raises(ProfileStreamError, match=r"the device is gone \(disconnected\).* keeping 20 frame") as err:
        driver.stop_profile_stream()
    assert err.value.taken.n == 20


def test_no_single_reads_or_second_stream_while_streaming(driver, backend):
    driver.start_profile_stream()
    with pytest.raises(DeviceError, match="cannot read a single profile while streaming"):
        driver.read_profile()
    with pytest.raises(DeviceError, match="a profile stream is already running"):
        driver.start_profile_stream()
    backend.advance_s(0.01)
    assert driver.stop_profile_stream().n == 4


def test_a_rate_given_at_the_start_sets_the_period(driver, backend):
    stream = _take_at(driver, backend, 250.0, 0.1)
    assert backend.period_us == 4000 and stream.n == 25
    np.testing.assert_allclose(np.diff(stream.t_sensor_s), 0.004, atol=1.1e-6)


def _take_at(driver, backend, rate_hz, seconds):
    driver.start_profile_stream(rate_hz)
    backend.advance_s(seconds)
    return driver.stop_profile_stream()


def test_a_header_without_timestamp_cannot_stream(cell):
    wire = WireConfig(header_layout=(("magic", "u32"), ("frame_counter", "u32"), ("point_count", "u16")))
    backend = SimulatedNxSensorBackend(cell, wire=wire)
    with NxSensorDriver(NxSensorConfig(wire=wire), backend=backend) as d:
        with pytest.raises(DeviceError, match="header_layout has no timestamp_us field"):
            d.start_profile_stream()


@pytest.mark.parametrize("marks", ["exposure_middle", "exposure_end"])
def test_the_stamp_is_taken_to_the_exposure_middle_whatever_it_marks(cell, marks):
    wire = WireConfig(timestamp_marks=marks, timestamp_us_per_count=2.0, checksum="crc32")
    backend = SimulatedNxSensorBackend(cell, wire=wire)
    with NxSensorDriver(NxSensorConfig(wire=wire, rate_hz=RATE_HZ), backend=backend,
                        host_clock_s=backend.now_s) as d:
        stream = _take(d, backend, 0.02)
    np.testing.assert_allclose(stream.t_sensor_s, [f.t_sensor_s for f in backend.streamed], rtol=0, atol=1.1e-6)


def test_the_factory_takes_the_simulated_time_clock_and_source_from_the_context(cell):
    sim_time = SimTime(10.0)
    seen = []

    def source(T_true_s):
        seen.append(T_true_s)
        return np.array([[0.0, -20.0], [1.0, -20.0]])

    context = DeviceContext(cell=cell, extras={SIM_NOW_KEY: sim_time.now_s, SIM_PROFILE_SOURCE_KEY: source,
                                               SIM_SENSOR_CLOCK_KEY: SensorClock(offset_s=-5.0)})
    with create_sensor(NxSensorConfig(rate_hz=100.0), context) as sensor:
        sensor.start_profile_stream()
        sim_time.advance_s(0.1)
        stream = sensor.stop_profile_stream()
    assert stream.n == 10 and seen == pytest.approx(10.0 + 0.01 * np.arange(1, 11))
    np.testing.assert_allclose(stream.t_sensor_s, 5.0 + 0.01 * np.arange(1, 11), atol=0.6e-6)
    np.testing.assert_allclose(stream.profile(3), [[0.0, -20.0], [1.0, -20.0]], atol=HALF_COUNT_MM)


def test_closing_while_streaming_stops_the_device_and_the_reader(driver, backend):
    driver.start_profile_stream()
    backend.advance_s(0.05)
    reader = driver._reader
    driver.close()
    assert backend.streaming is False and not reader.is_alive()


def _noise(logs):
    return [m for m in logs if "discarded a waiting frame" in m or "lost before frame" in m]


def test_a_stop_interrupted_by_ctrl_c_drops_the_stream_in_one_line(driver, backend, logs):
    """Ctrl-C while the frames in flight are taken (the stop waits for the reader): the
    reader stops at once, what is left is discarded, and one line says how many frames
    went, instead of a line per frame discarded or seen missing (which look like loss)."""
    driver.start_profile_stream()
    backend.advance_s(0.5)  # 200 frames due at once, as after a simulated move
    reader = driver._reader
    join = reader.join

    def interrupted_once(timeout=None):
        reader.join = join
        join(0.002)  # the reader has begun to take them
        raise KeyboardInterrupt

    reader.join = interrupted_once
    with pytest.raises(KeyboardInterrupt):
        driver.stop_profile_stream()
    assert not reader.is_alive() and driver._reader is None and backend.streaming is False
    said = [m for m in logs if "profile stream stopped" in m]
    assert len(said) == 1 and not _noise(logs)
    read, in_flight = map(int, re.search(r"\(interrupted while stopping it\): its (\d+) frame\(s\) read and (\d+) "
                                         r"still in flight discarded", said[0]).groups())
    assert read + in_flight == 200  # every frame measured is accounted for
    driver.close()
    assert len([m for m in logs if "profile stream stopped" in m]) == 1  # closing says nothing more


def test_closing_a_stream_nobody_stopped_says_what_it_dropped_in_one_line(driver, backend, logs):
    driver.start_profile_stream()
    backend.advance_s(0.1)
    driver.close()
    said = [m for m in logs if "profile stream stopped" in m]
    assert len(said) == 1 and "(closed while streaming)" in said[0] and not _noise(logs)
