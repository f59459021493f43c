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
