"""A plugin written against the module paths before the plugin API
(tests/plugins/old_paths_plugin.py) still loads, registers, drives a simulated run to a
calibration and exports, and each old path it imports warns, naming the new home."""

from __future__ import annotations

import importlib
import sys
import warnings

import numpy as np

from spherecal.estimation import calibrate
from spherecal.io.exporters import write_exports
from spherecal.plugins import DeviceContext, PluginHost, standard_cell
from spherecal.plugins.testing import acquire_dataset, planned_stations

#: The old paths the plugin imports -> their new homes.
OLD_PATHS = {
    "spherecal.errors": "spherecal.core.errors",
    "spherecal.models": "spherecal.core.models",
    "spherecal.linelink": "spherecal.devices.line_robot",
    "spherecal.lineproto": "spherecal.devices.line_protocol",
    "spherecal.planning": "spherecal.motion.planning",
    "spherecal.exporters": "spherecal.io.exporters",
    "spherecal.geometry": "spherecal.core.geometry",
}


def load_old_plugin(monkeypatch):
    """Import the plugin afresh (an old path warns on its first import in a process),
    returning it and the warnings seen."""
    for name in [*OLD_PATHS, "old_paths_plugin"]:
        monkeypatch.delitem(sys.modules, name, raising=False)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        module = importlib.import_module("old_paths_plugin")
    return module, [str(w.message) for w in seen if issubclass(w.category, DeprecationWarning)]


def test_each_old_path_warns_with_its_new_home(monkeypatch):
    _, messages = load_old_plugin(monkeypatch)
    for old, new in OLD_PATHS.items():
        assert f"{old} has moved to {new}; the old path goes in the next release" in messages, messages
    assert not [m for m in messages if m.startswith("spherecal.devices ")]  # a package now, holding the contract


def test_a_plugin_on_the_old_paths_still_calibrates_and_exports(monkeypatch, tmp_path):
    plugin, _ = load_old_plugin(monkeypatch)
    host = PluginHost([("old_paths", plugin)], load_entry_points=False)
    assert plugin.ROBOT in host.registry.robots and plugin.SENSOR in host.registry.sensors
    cell = standard_cell("eye_in_hand", seed=2, fov=host.registry.sensor_type(plugin.SENSOR).field_of_view)
    context = DeviceContext(cell=cell)
    robot = host.create_robot({"type": plugin.ROBOT, "max_speed_mm_s": 200.0}, context)
    sensor = host.create_sensor({"type": plugin.SENSOR}, context)
    stations = planned_stations(cell, plugin.PLAN)
    dataset = acquire_dataset(robot, sensor, stations, cell.mounting, cell.sphere_radius_mm, host=host)
    result = calibrate(dataset)
    true = cell.true_transform
    assert np.linalg.norm(result.transform.translation - true.translation) < 0.25
    plan = host.export_plan(None, cell.mounting, plugin.ROBOT)
    assert plan.names == [plugin.EXPORTER]
    paths = write_exports(result, tmp_path, plan)
    numbers = [float(v) for v in paths["flange_from_sensor_rotvec.txt"].read_text().split()]
    np.testing.assert_allclose(numbers[:3], result.transform.translation_mm, atol=1e-6)
