"""Fixtures shared by the test folders."""

import pytest


@pytest.fixture
def irb2400_controllers(monkeypatch):
    """The simulated IRB 2400 controllers the robot plugin's factory starts, in order
    (for tests that check what a controller did, e.g. that nothing moved)."""
    from spherecal.robots.abb_irb2400 import plugin
    from spherecal.robots.abb_irb2400.simulator import start_simulator

    started = []

    def start(*args, **kwargs):
        started.append(start_simulator(*args, **kwargs))
        return started[-1]

    monkeypatch.setattr(plugin, "start_simulator", start)
    return started


@pytest.fixture(params=["eye_in_hand", "eye_to_hand"])
def mounting(request):
    """Both mounting modes."""
    return request.param


@pytest.fixture(params=["orjson", "stdlib"])
def parser(request, monkeypatch):
    """Run a test with the orjson accelerator and with the standard library's json."""
    from spherecal.io import observation_line

    if request.param == "orjson":
        if observation_line._orjson is None:
            pytest.skip("orjson not installed")
    else:
        monkeypatch.setattr(observation_line, "_orjson", None)
    return request.param
