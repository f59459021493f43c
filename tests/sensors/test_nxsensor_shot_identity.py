"""Shot identity: a profile is only ever the one measured by a trigger of its
own shot, told by the frame counter, however many frames arrive late and however late.

The simulated device records what it measured under each frame counter and where the
robot stood (``measured``, ``measured_poses``); each test moves the simulated robot
between shots and checks every profile against that record."""

import numpy as np
import pytest

from spherecal.core.errors import DeviceError
from spherecal.sensors.nxsensor_i import NxSensorConfig, NxSensorDriver, SimulatedNxSensorBackend, WireConfig
from spherecal.sensors.nxsensor_i.shots import CounterMismatch, FrameCounter
from spherecal.sim import plan_stations, standard_cell
from reference_sensor import reference_fov

HALF_COUNT_MM = 0.005 / 2 + 1e-9


@pytest.fixture
def cell():
    c = standard_cell("eye_in_hand", seed=5, fov=reference_fov())
    stations = plan_stations(c.mounting, c.true_transform, c.sphere_centre_mm, c.sphere_radius_mm,
                             field_of_view=c.fov)
    c.poses = stations[1][1][2:8]  # six poses along one sweep, 1-2 mm apart: each sees another circle
    c.move_flange_to(c.poses[0])
    return c


def own_measurement(backend, profile):
    """The device's record for the profile's frame counter: (points, pose); exactly one."""
    counter = int(profile.shot_id)
    hits = [i for i, (c, _) in enumerate(backend.measured) if c == counter]
    assert len(hits) == 1, f"frame {counter} measured {len(hits)} times"
    return backend.measured[hits[0]][1], backend.measured_poses[hits[0]]


def shoot_at(driver, backend, cell, pose):
    """Move, take one profile, check it is the one measured at this very pose."""
    cell.move_flange_to(pose)
    profile = driver.read_profile()
    points, where = own_measurement(backend, profile)
    assert where is pose, "profile measured at another pose"
    assert len(profile) == len(points) and np.max(np.abs(profile.points_mm - points)) <= HALF_COUNT_MM
    return profile


def test_profiles_carry_their_frame_counter(cell):
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(), backend=backend) as d:
        ids = [shoot_at(d, backend, cell, p).shot_id for p in cell.poses[:3]]
    assert ids == ["0", "1", "2"]


@pytest.mark.parametrize("late", [2, 3])
def test_a_frame_late_beyond_any_wait_is_never_paired_with_a_later_pose(cell, late):
    """The frame of shot 1 stays late for ``late`` reads: longer than a drain with a fixed
    wait allows (one that gives up then leaves a frame queued for good, pairing every later
    profile with the previous pose). With enough retries shot 1 takes its own first frame; the
    leftovers are discarded by their counters at the next shot."""
    backend = SimulatedNxSensorBackend(cell)
    logs = []
    with NxSensorDriver(NxSensorConfig(timeout_ms=20, retries=late), backend=backend, log=logs.append) as d:
        shoot_at(d, backend, cell, cell.poses[0])
        backend.inject_late_frames(late)
        shoot_at(d, backend, cell, cell.poses[1])
        for pose in cell.poses[2:]:
            shoot_at(d, backend, cell, pose)
        assert d.frames_discarded == late  # the re-triggered frames of shot 1
        assert d.counter.exact
    assert sum("measured for an earlier shot" in m for m in logs) == late


def test_a_frame_late_by_more_than_a_whole_shot(cell):
    """Shot 1's frames stay late past its last attempt (a DeviceError, nothing paired);
    they arrive during shot 2 (whose first read is late too), which discards them and
    takes its own first frame; its re-triggered one is discarded at shot 3."""
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(timeout_ms=20, retries=1), backend=backend) as d:
        shoot_at(d, backend, cell, cell.poses[0])
        backend.inject_late_frames(3)
        cell.move_flange_to(cell.poses[1])
        with pytest.raises(DeviceError, match=r"no answer within timeout_ms = 20 ms \(2 attempts\)"):
            d.read_profile()
        for pose in cell.poses[2:]:
            shoot_at(d, backend, cell, pose)
        assert d.frames_discarded == 3


def test_a_frame_left_from_an_earlier_session_is_flushed_on_open(cell):
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(timeout_ms=20), backend=backend) as d:
        d.read_profile()
        d._command_raw(type(backend.commands[-1])("trigger"))  # a trigger whose frame nobody read
    assert len(backend._queue) == 1
    logs = []
    with NxSensorDriver(NxSensorConfig(timeout_ms=20), backend=backend, log=logs.append) as d:
        assert not backend._queue and any("discarded a waiting frame while opening" in m for m in logs)
        for pose in cell.poses[1:4]:
            shoot_at(d, backend, cell, pose)


def test_a_lost_frame_while_synchronising_costs_retries_never_a_wrong_pairing(cell):
    """The first trigger after open loses its frame: the counter is then known only to
    within two, which can cost a discarded frame and a new trigger per shot, but every
    profile is still its own pose's."""
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(timeout_ms=20, retries=1), backend=backend) as d:
        backend.inject_timeouts(1)
        shoot_at(d, backend, cell, cell.poses[0])
        assert (d.counter.lo, d.counter.hi) == (2, 3)  # the device will number 2 next
        for pose in cell.poses[1:]:
            shoot_at(d, backend, cell, pose)
        # the price: each later shot discarded its own first frame and triggered again
        assert d.frames_discarded == len(cell.poses) - 1 and not d.counter.exact


def test_counter_wraps(cell):
    """A u8 counter wraps at 256: shots across the wrap, with a late frame at the wrap."""
    layout = (("magic", "u32"), ("frame_counter", "u8"), ("pad", "u8"), ("pad", "u16"),
              ("timestamp_us", "u32"), ("point_count", "u16"), ("flags", "u16"))
    wire = WireConfig(header_layout=layout)
    assert wire.frame_counter_modulus == 256
    backend = SimulatedNxSensorBackend(cell, wire=wire)
    backend.frame_counter = 253
    with NxSensorDriver(NxSensorConfig(wire=wire, timeout_ms=20, retries=2), backend=backend) as d:
        ids = [shoot_at(d, backend, cell, cell.poses[0]).shot_id]
        backend.inject_late_frames(2)
        ids.append(shoot_at(d, backend, cell, cell.poses[1]).shot_id)
        ids += [shoot_at(d, backend, cell, p).shot_id for p in cell.poses[2:4]]
        assert d.frames_discarded == 2
    assert ids == ["253", "254", "1", "2"]


def test_a_frame_numbered_beyond_every_trigger_is_an_error(cell):
    """A device that numbers frames it never sent (here: five) breaks the assumption the
    pairing rests on: an error naming it, never a profile."""
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(timeout_ms=20), backend=backend) as d:
        shoot_at(d, backend, cell, cell.poses[0])
        backend.frame_counter += 5
        cell.move_flange_to(cell.poses[1])
        with pytest.raises(DeviceError, match=r"nxSensor-I \(USB 04b4:5a01\): frame 6 arrived, but the triggers sent "
                                              r"so far can have numbered frames only up to 1: .*frame_counter"):
            d.read_profile()
        # the next read flushes and learns the counter again: paired by number from there on
        for pose in cell.poses[2:]:
            shoot_at(d, backend, cell, pose)


def test_single_shots_after_a_stream_learn_the_counter_again(cell):
    backend = SimulatedNxSensorBackend(cell)
    with NxSensorDriver(NxSensorConfig(timeout_ms=20), backend=backend) as d:
        shoot_at(d, backend, cell, cell.poses[0])
        d.start_profile_stream()
        backend.advance_s(0.035)
        assert d.stop_profile_stream().n == 3
        assert not d.counter.known
        backend.inject_late_frames(1)
        for pose in cell.poses[1:]:
            shoot_at(d, backend, cell, pose)


def test_a_sensor_that_keeps_sending_is_refused_on_open(cell):
    backend = SimulatedNxSensorBackend(cell)
    backend.stream_unasked()  # left streaming by another program
    backend.advance_s(1.0)
    with pytest.raises(DeviceError, match=r"frames kept arriving unasked \(64 in a row\) while flushing the input "
                                          r"\(opening the device\)"):
        NxSensorDriver(NxSensorConfig(), backend=backend)


# --- the counter logic on its own -----------------------------------------------------

def test_counter_logic_places_frames_by_number_only():
    c = FrameCounter(modulus=16)
    shot = c.begin_shot()
    assert shot.sync
    c.sending_trigger(); c.trigger_sent()
    assert c.place(shot, 14) and (c.lo, c.hi) == (15, 15)
    shot = c.begin_shot()
    c.sending_trigger(); c.trigger_sent()  # numbered 15
    c.sending_trigger(); c.trigger_sent()  # re-triggered: numbered 0 (wrapped)
    assert c.expected(shot) == "15..0"
    assert not c.place(shot, 14)  # an earlier shot's
    assert c.place(shot, 0)  # this shot's re-trigger, across the wrap
    assert c.exact and c.name(c.hi) == 1
    with pytest.raises(CounterMismatch, match="frame 1 arrived"):
        c.place(c.begin_shot(), 1)  # nothing triggered yet: ahead


def test_counter_logic_a_failed_trigger_widens_the_interval_safely():
    c = FrameCounter(modulus=2**32)
    c.forget()
    shot = c.begin_shot()
    c.sending_trigger(); c.trigger_sent()
    c.place(shot, 100)
    shot = c.begin_shot()
    c.sending_trigger()  # its transfer timed out: measured or not, nobody knows
    c.sending_trigger(); c.trigger_sent()
    assert (c.lo, c.hi) == (102, 103)
    assert not c.place(shot, 100)
    assert c.place(shot, 101)  # only this shot's triggers can have numbered 101
    assert (c.lo, c.hi) == (102, 103)  # the next profile is numbered 102 or 103
    shot = c.begin_shot()
    c.sending_trigger(); c.trigger_sent()
    # 102 may be this shot's or the last shot's second frame: discarded (it can cost a
    # frame of this shot, never a wrong pose)
    assert not c.place(shot, 102) and (c.lo, c.hi) == (103, 104)
    assert c.place(shot, 103) and c.exact
    c.sending_trigger(); c.trigger_refused()  # a stalled request measured nothing
    assert c.exact and c.hi == 104
