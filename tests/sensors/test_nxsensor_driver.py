"""The nxSensor-I pyusb driver against the simulated device behind a real pyusb backend."""

import numpy as np
import pytest
import usb.core
import usb.util

from spherecal.devices.contract import Sensor
from spherecal.core.errors import DeviceError
from spherecal.core.models import Pose, Profile
from spherecal.sensors.nxsensor_i import NxSensorConfig, NxSensorDriver, SimulatedNxSensorBackend, WireConfig
from spherecal.sim import NoiseModel, plan_stations, standard_cell
from reference_sensor import reference_fov

HALF_COUNT_MM = 0.005 / 2 + 1e-9


def _in_view_pose(cell):
    stations = plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm,
                             field_of_view=cell.fov)
    return stations[1][1][4]


@pytest.fixture
def cell():
    c = standard_cell("eye_in_hand", seed=11, fov=reference_fov())
    c.move_flange_to(_in_view_pose(c))
    return c


@pytest.fixture
def backend(cell):
    return SimulatedNxSensorBackend(cell)


@pytest.fixture
def logs():
    return []


@pytest.fixture
def driver(backend, logs):
    d = NxSensorDriver(NxSensorConfig(timeout_ms=50), backend=backend, log=logs.append)
    yield d
    d.close()


def test_pyusb_finds_the_simulated_device(backend):
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x5A01, backend=backend)
    assert dev is not None
    assert (dev.idVendor, dev.idProduct) == (0x04B4, 0x5A01)
    assert usb.util.get_string(dev, dev.iSerialNumber) == "NXS-SIM-0001"
    intf = dev[0][(0, 0)]
    assert [ep.bEndpointAddress for ep in intf] == [0x01, 0x82]
    assert usb.core.find(idVendor=0x04B4, idProduct=0x0001, backend=backend) is None
    usb.util.dispose_resources(dev)


def test_read_profile_equals_what_the_cell_measured(driver, backend, cell):
    assert isinstance(driver, Sensor)
    profile = driver.read_profile()
    assert isinstance(profile, Profile)
    counter, measured = backend.measured[-1]
    assert len(profile) == len(measured) > 100
    assert np.max(np.abs(profile.points_mm - measured)) <= HALF_COUNT_MM
    # it is the sphere, seen from the sensor at the cell's current pose
    c = cell.sphere_centre_in_sensor(cell.current_base_from_flange)
    rho = np.sqrt(cell.sphere_radius_mm**2 - c[0] ** 2)
    d = np.hypot(profile.y_mm - c[1], profile.z_mm - c[2]) - rho
    assert np.max(np.abs(d)) < 6 * cell.noise.point_noise_mm + HALF_COUNT_MM


def test_noise_free_profile_equals_the_ideal_one():
    cell = standard_cell("eye_in_hand", seed=2, noise=NoiseModel(point_noise_mm=0.0,
                                                                 pose_translation_noise_mm=0.0), fov=reference_fov())
    pose = _in_view_pose(cell)
    cell.move_flange_to(pose)
    with NxSensorDriver(NxSensorConfig(), backend=SimulatedNxSensorBackend(cell)) as d:
        profile = d.read_profile()
    ideal = cell.ideal_profile(pose)
    assert profile.points_mm.shape == ideal.shape
    assert np.max(np.abs(profile.points_mm - ideal)) <= HALF_COUNT_MM


def test_out_of_view_gives_none(driver, cell):
    pose = cell.current_base_from_flange
    cell.move_flange_to(Pose.from_rt(pose.rotation_matrix, pose.translation + [0.0, 0.0, 400.0]))
    assert driver.read_profile() is None


def test_settings_are_sent_on_open_and_on_configure(driver, backend):
    assert (backend.period_us, backend.exposure_us) == (10_000, 200)
    driver.configure(exposure_us=300, rate_hz=1000)
    assert (backend.period_us, backend.exposure_us) == (1000, 300)
    with pytest.raises(DeviceError, match=r"exposure_us = 3000 us does not fit the frame period"):
        driver.configure(exposure_us=3000)
    assert driver.config.exposure_us == 300


def test_recovers_from_a_transient_timeout(driver, backend, logs):
    backend.inject_timeouts(1)
    profile = driver.read_profile()
    assert profile is not None
    assert np.max(np.abs(profile.points_mm - backend.measured[-1][1])) <= HALF_COUNT_MM
    assert [c.name for c in backend.commands].count("trigger") == 2  # re-triggered
    assert any("timeout while reading a profile; retrying" in m for m in logs)


def test_a_late_frame_is_never_paired_with_the_next_pose(driver, backend, cell):
    """A read times out but its frame arrives later: the driver discards it before the
    next trigger, so the profile of the next shot is measured at the next pose."""
    backend.inject_late_frames(1)
    first = driver.read_profile()
    assert first is not None  # recovered by re-triggering at the same pose
    pose = cell.current_base_from_flange
    cell.move_flange_to(Pose.from_rt(pose.rotation_matrix, pose.translation + [3.0, 0.0, 0.0]))
    second = driver.read_profile()
    assert np.max(np.abs(second.points_mm - backend.measured[-1][1])) <= HALF_COUNT_MM
    assert not np.allclose(second.points_mm[:5], first.points_mm[:5], atol=0.1)


def test_persistent_timeout_is_a_clear_device_error(driver, backend):
    backend.inject_timeouts(3)  # the first read, then the retry's wait for a late frame and its read
    with pytest.raises(DeviceError, match=r"nxSensor-I \(USB 04b4:5a01\): no answer within timeout_ms = 50 ms "
                                          r"\(2 attempts\) while reading a profile"):
        driver.read_profile()
    assert driver.read_profile() is not None  # the device itself is fine afterwards


def test_disconnect_is_a_clear_device_error(driver, backend):
    backend.disconnect()
    with pytest.raises(DeviceError, match=r"nxSensor-I \(USB 04b4:5a01\): the device is gone \(disconnected\) "
                                          r"while reading a profile\. Check the USB cable"):
        driver.read_profile()
    with pytest.raises(DeviceError, match="lost earlier; cannot proceed with reading a profile"):
        driver.read_profile()
    driver.close()
    driver.close()


def test_reconnected_device_is_found_again(driver, backend, logs):
    backend.disconnect()
    backend.reconnect()  # new address, firmware restarted with default settings
    assert backend.exposure_us == 0
    assert driver.read_profile() is not None
    assert backend.exposure_us == 200 and backend.period_us == 10_000  # settings sent again
    assert any("reappeared" in m for m in logs)


def test_reset_reopens_the_device(driver, backend):
    driver.reset()
    assert backend.exposure_us == 200
    assert driver.read_profile() is not None


def test_stalled_endpoint_is_cleared(driver, backend, logs):
    backend.inject_stalls(1)
    assert driver.read_profile() is not None
    assert any("clearing the halt" in m for m in logs)


def test_corrupt_frames(driver, backend):
    backend.inject_corrupt_frames(1, kind="magic")
    assert driver.read_profile() is not None  # retried
    backend.inject_corrupt_frames(2, kind="count")
    with pytest.raises(DeviceError, match=r"malformed frame: point count mismatch.* while reading a profile.*"
                                          r"sensor\.wire does not match"):
        driver.read_profile()


def test_no_retries_means_first_error_is_raised(cell, backend):
    with NxSensorDriver(NxSensorConfig(timeout_ms=20, retries=0), backend=backend) as d:
        backend.inject_timeouts(1)
        with pytest.raises(DeviceError, match=r"timeout_ms = 20 ms \(1 attempt\)"):
            d.read_profile()


def test_bulk_command_transport_and_other_layout(cell):
    wire = WireConfig(command_transport="bulk", byte_order="big", count_type="i32", checksum="crc32",
                      vendor_id=0x1234, product_id=0x0042, bulk_in_endpoint=0x81, bulk_out_endpoint=0x02)
    backend = SimulatedNxSensorBackend(cell, wire=wire)
    with NxSensorDriver(NxSensorConfig(wire=wire), backend=backend) as d:
        profile = d.read_profile()
        assert d.device_name == "nxSensor-I (USB 1234:0042)"
    assert np.max(np.abs(profile.points_mm - backend.measured[-1][1])) <= HALF_COUNT_MM


def test_serial_number_selection(cell, backend):
    with NxSensorDriver(NxSensorConfig(serial_number="NXS-SIM-0001"), backend=backend) as d:
        assert d.read_profile() is not None
    with pytest.raises(DeviceError, match=r"none has serial number 'NX-42' \(found: 'NXS-SIM-0001'\)"):
        NxSensorDriver(NxSensorConfig(serial_number="NX-42"), backend=backend)


def test_device_not_found_says_what_to_check(backend):
    cfg = NxSensorConfig(wire=WireConfig(product_id=0x0777))
    with pytest.raises(DeviceError, match=r"not found on USB \(looked for vendor:product 04b4:0777\).*cable.*udev"):
        NxSensorDriver(cfg, backend=backend)


def test_closed_driver_refuses_work(driver):
    driver.close()
    with pytest.raises(DeviceError, match="closed; cannot proceed with reading a profile"):
        driver.read_profile()
