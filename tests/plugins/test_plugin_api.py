"""``spherecal.plugins`` is the plugin API: every name it lists resolves to the object at
its home, importing it loads nothing heavy (its names load on first use), and the
third-party example package imports nothing of spherecal but it."""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

import spherecal.plugins as api

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "third_party_plugin"


@pytest.mark.parametrize("name", api.__all__)
def test_every_listed_name_resolves(name):
    assert getattr(api, name) is not None
    assert name in dir(api)


def test_the_docs_table_names_every_listed_name():
    """docs/plugins.md's table of the API's names is complete (``Vec3`` was once missing)."""
    import re

    text = (REPO / "docs" / "plugins.md").read_text()
    section = text[text.index("## What a plugin may rely on"):text.index("## How plugins are found")]
    table = "\n".join(line for line in section.splitlines() if line.startswith("| "))
    named = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", table))
    assert sorted(set(api.__all__) - named) == []


def test_the_names_are_the_objects_at_their_homes():
    from spherecal.core.field_of_view import SensorFieldOfView
    from spherecal.core.workspace import WorkspaceBox
    from spherecal.devices import contract, line_protocol, line_robot, motion_safety
    from spherecal.plugins import registry

    assert api.RobotType is contract.RobotType and api.SensorFieldOfView is SensorFieldOfView
    assert contract.SensorFieldOfView is SensorFieldOfView  # the contract re-exports the value object
    assert api.WorkspaceBox is WorkspaceBox is line_robot.WorkspaceBox
    assert api.MotionSafety is motion_safety.MotionSafety and issubclass(api.LineRobot, api.MotionSafety)
    assert api.line_protocol is line_protocol and api.DeviceRegistry is registry.DeviceRegistry
    assert api.hookspecs is importlib.import_module("spherecal.plugins.hookspecs")
    assert api.BASE_DIR_CONTEXT_KEY == "base_dir"


#: The DeviceContext.extras keys of a simulated run, and the built-in plugin that reads each.
SIM_EXTRAS_KEYS = {"POSE_STREAM_SOURCE_KEY": "robots/abb_irb2400/plugin.py",
                   "SIM_CLOCK_KEY": "robots/abb_irb2400/plugin.py",
                   "SIM_CONTROLLER_CLOCK_KEY": "robots/abb_irb2400/plugin.py",
                   "SIM_NOW_KEY": "sensors/nxsensor_i/plugin.py",
                   "SIM_SENSOR_CLOCK_KEY": "sensors/nxsensor_i/plugin.py",
                   "SIM_PROFILE_SOURCE_KEY": "sensors/nxsensor_i/plugin.py"}


def test_a_simulated_runs_extras_keys_are_the_plugin_apis():
    """What a simulated run hands the factories (spherecal.sim.live.device_extras) is
    keyed by the plugin API's names, one key each."""
    from reference_sensor import reference_fov
    from spherecal.sim import live, standard_cell

    values = {getattr(api, name) for name in SIM_EXTRAS_KEYS}
    assert len(values) == len(SIM_EXTRAS_KEYS) and all(isinstance(v, str) and v for v in values)
    for name in SIM_EXTRAS_KEYS:
        assert getattr(live, name) == getattr(api, name), name
    assert set(live.device_extras(standard_cell(seed=1, fov=reference_fov()))) == values


def _imported_from_api(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {a.name for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module == "spherecal.plugins" for a in node.names}


def test_the_built_in_plugins_read_the_extras_keys_of_the_plugin_api():
    """The built-in streaming plugins import the keys from spherecal.plugins, and no module
    of robots/ or sensors/ spells a key's value itself (a copy that could drift from what
    a simulated run sets)."""
    for name, module in SIM_EXTRAS_KEYS.items():
        assert name in _imported_from_api(REPO / module), f"{module} does not import {name} from spherecal.plugins"
    values = {getattr(api, name) for name in SIM_EXTRAS_KEYS}
    copies = [f"{path.relative_to(REPO)}:{node.lineno} {node.value!r}"
              for path in sorted([*(REPO / "robots").rglob("*.py"), *(REPO / "sensors").rglob("*.py")])
              for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
              if isinstance(node, ast.Constant) and node.value in values]
    assert copies == []


def test_importing_the_api_loads_only_the_markers():
    code = ("import json, sys\nbefore = set(sys.modules)\nimport spherecal.plugins\n"
            "print(json.dumps(sorted(set(sys.modules) - before)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    loaded = set(json.loads(proc.stdout))
    assert not [m for m in loaded if m.startswith(("numpy", "pydantic", "scipy", "matplotlib", "pinocchio"))]
    assert not [m for m in loaded if m.startswith("spherecal.") and m not in (
        "spherecal._moved", "spherecal.core", "spherecal.core.lazy", "spherecal.plugins", "spherecal.plugins.markers")]


def _spherecal_imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            found.add(node.module or "")
    return {m for m in found if m == "spherecal" or m.startswith("spherecal.")}


@pytest.mark.parametrize("path", sorted((EXAMPLE / "src").rglob("*.py")) + sorted((EXAMPLE / "tests").rglob("*.py")),
                         ids=lambda p: p.relative_to(EXAMPLE).as_posix())
def test_the_example_package_imports_only_the_plugin_api(path):
    assert _spherecal_imports(path) <= {"spherecal.plugins"}


def test_the_example_calibration_adds_only_the_library_calibration():
    assert _spherecal_imports(EXAMPLE / "calibrate_simulated.py") == {"spherecal.plugins", "spherecal.estimation"}
