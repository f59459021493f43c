"""The nxSensor-I plugin as the host sees it: registration, configuration, factory."""

import pytest

import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
from spherecal.devices.contract import DeviceContext
from spherecal.core.errors import ConfigError, DeviceError
from spherecal.sensors.nxsensor_i import NxSensorConfig, NxSensorDriver, SimulatedNxSensorBackend
from spherecal.sensors.nxsensor_i.plugin import create_sensor


def test_registered_through_the_entry_point(spherecal_host):
    st = spherecal_host.registry.sensor_type("nxsensor_i")
    assert st.config_model is NxSensorConfig
    assert st.factory is create_sensor
    assert "assumption" in st.description


def test_it_declares_a_housing_clear_of_its_measuring_range(spherecal_host):
    """The assumed housing (docs/sensor-nxsensor-i.md) lies above the near end of the range,
    where the keep-out check holds it away from the sphere."""
    st = spherecal_host.registry.sensor_type("nxsensor_i")
    assert st.body.min_mm == (-100.0, -35.0, 80.0) and st.body.max_mm == (30.0, 35.0, 165.0)
    assert st.body.min_mm[2] > st.field_of_view.z_near_mm and not st.body.overlap_with_range(st.field_of_view)


def test_simulated_sensor_passes_the_sensor_harness(spherecal_host, spherecal_context, spherecal_sensor_harness):
    sensor = spherecal_host.create_sensor({"type": "nxsensor_i", "timeout_ms": 50}, spherecal_context)
    assert isinstance(sensor, NxSensorDriver)
    assert isinstance(sensor._dev.backend, SimulatedNxSensorBackend)  # the real driver over the simulated device
    report = spherecal_sensor_harness.check(sensor)
    assert report.n_profiles >= 3


def test_simulated_sensor_uses_the_configured_wire_and_serial(spherecal_cell):
    cfg = NxSensorConfig(serial_number="UNIT-7", wire={"vendor_id": 0x1111, "product_id": 0x2222, "checksum": "crc32"})
    with create_sensor(cfg, DeviceContext(cell=spherecal_cell)) as sensor:
        assert sensor._dev.idVendor == 0x1111
        assert sensor.device_name == "nxSensor-I (USB 1111:2222, serial UNIT-7)"


@pytest.mark.parametrize(
    "section, message",
    [
        ({"type": "nxsensor_i", "timeout_msec": 5}, "timeout_msec"),
        ({"type": "nxsensor_i", "wire": {"vendor_id": 70000}}, "vendor_id"),
        ({"type": "nxsensor_i", "exposure_us": 20000, "rate_hz": 100}, "exposure_us = 20000 us does not fit"),
        ({"type": "nxsensor_i", "rate_hz": 0}, "rate_hz"),
        ({"type": "nxsensor_i", "rate_hz": 2, "exposure_us": 200}, r"stall_timeout_ms = 500 ms must exceed two frame "
                                                                   r"periods of rate_hz = 2\.0 Hz \(1000 ms\)"),
        ({"type": "nxsensor_i", "stall_timeout_ms": 0}, "stall_timeout_ms"),
        ({"type": "nxsensor_i", "late_after_periods": 5, "clock_jump_periods": 4},
         "late_after_periods = 5.0 must be below clock_jump_periods = 4.0"),
        ({"type": "nxsensor_i", "late_after_periods": 0}, "late_after_periods"),
        ({"type": "nxsensor_i", "wire": {"timestamp_us_per_count": 0}}, "timestamp_us_per_count"),
        ({"type": "nxsensor_i", "wire": {"timestamp_marks": "exposure_centre"}}, "timestamp_marks"),
    ],
)
def test_bad_configuration_is_a_config_error(spherecal_host, section, message):
    with pytest.raises(ConfigError, match=message):
        spherecal_host.validate_sensor_config("nxsensor_i", section)


def test_config_is_frozen():
    cfg = NxSensorConfig()
    with pytest.raises(ValueError, match="frozen"):
        cfg.timeout_ms = 5
    assert cfg.period_us == 10_000


def test_hardware_without_libusb_says_what_to_install(monkeypatch):
    for module in (usb.backend.libusb1, usb.backend.openusb, usb.backend.libusb0):
        monkeypatch.setattr(module, "get_backend", lambda *a, **k: None)
    with pytest.raises(DeviceError, match=r"nxSensor-I \(USB 04b4:5a01\): no USB backend available.*libusb-1\.0"):
        create_sensor(NxSensorConfig(), DeviceContext(cell=None))


class _EmptyBus(usb.backend.IBackend):
    def enumerate_devices(self):
        return iter(())


def test_hardware_not_connected_says_what_to_check(monkeypatch):
    monkeypatch.setattr(usb.backend.libusb1, "get_backend", lambda *a, **k: _EmptyBus())
    with pytest.raises(DeviceError, match=r"not found on USB \(looked for vendor:product 04b4:5a01\).*"
                                          r"plugged in.*udev rule.*assumptions"):
        create_sensor(NxSensorConfig(), DeviceContext(cell=None))


def test_a_broken_pyusb_stops_the_factory_with_a_device_error_naming_it(spherecal_cell, monkeypatch):
    """The driver loads when a sensor is opened (not when the plugin registers): a pyusb
    that is installed but fails to import is a DeviceError that says what to reinstall,
    not an ImportError from deep inside the run."""
    import sys

    for name in [m for m in sys.modules if m == "usb" or m.startswith("usb.")]:
        monkeypatch.setitem(sys.modules, name, None)  # (None in sys.modules: the import fails)
    monkeypatch.setitem(sys.modules, "usb", None)
    for name in ("spherecal.sensors.nxsensor_i.driver", "spherecal.sensors.nxsensor_i.simbackend"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    with pytest.raises(DeviceError, match=r"USB driver cannot be loaded.*reinstall pyusb"):
        create_sensor(NxSensorConfig(), DeviceContext(cell=spherecal_cell))


def test_the_package_lists_and_loads_its_lazy_names():
    import spherecal.sensors.nxsensor_i as nx

    assert {"NxSensorDriver", "SimulatedNxSensorBackend", "SensorClock", "cell_source"} <= set(dir(nx))
    assert nx.NxSensorDriver is NxSensorDriver
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        nx.Nope
