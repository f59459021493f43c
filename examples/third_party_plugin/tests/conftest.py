"""Every test of the package runs on a cell measured with the example profiler's field of
view and laid out for the example arm's reach; a test's own ``spherecal_cell`` parameter
(a mounting, a dict) goes over it (``request``)."""

import pytest

from spherecal.plugins import testing


@pytest.fixture
def spherecal_cell(request, spherecal_host):
    fov = spherecal_host.registry.sensor_type("example_profiler").field_of_view
    arm = spherecal_host.arm_kinematics({"type": "example_arm"})  # the cell laid out for this arm's reach
    return testing.make_cell({"mounting": "eye_in_hand", "fov": fov, "arm": arm}, request)


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: an end-to-end run of several seconds; left out by -m 'not slow'")
