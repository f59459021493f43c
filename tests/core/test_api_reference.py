"""The API reference (docs/build_api.py) builds offline from the docstrings and holds the
public classes a plugin author uses, each with its documentation."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_the_api_reference_builds_and_documents_what_a_plugin_author_uses(tmp_path):
    spec = importlib.util.spec_from_file_location("build_api", DOCS / "build_api.py")
    build_api = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_api)
    out = build_api.build(tmp_path / "api")
    pages = {p.relative_to(out).as_posix(): p.read_text(encoding="utf-8") for p in out.rglob("*.html")}
    expected = {
        "spherecal/core/models.html": ["Pose", "Profile", "Observation", "Dataset"],
        "spherecal/devices/contract.html": ["Robot", "Sensor", "RobotType", "SensorType", "SensorFieldOfView",
                                   "DeviceContext"],
        "spherecal/sim.html": ["SimulatedCell", "standard_cell", "NoiseModel"],
        "spherecal/motion/planning.html": ["SweepPlan", "plan_stations", "with_standoff"],
        "spherecal/plugins/testing.html": ["spherecal_cell", "make_cell", "RobotHarness", "SensorHarness",
                                           "acquire_dataset"],
        "spherecal/plugins/hookspecs.html": ["spherecal_register_devices", "spherecal_register_exporters"],
        "spherecal/io/exporters.html": ["Exporter"],
        "spherecal/core/geometry.html": ["matrix_from_rotvec"],
    }
    for page, names in expected.items():
        assert page in pages, sorted(pages)
        for name in names:
            assert re.search(rf'id="{re.escape(name)}"|>{re.escape(name)}<', pages[page]), f"{name} not in {page}"
    # docstrings, not only names: the Robot protocol's contract and a fixture's parameters are there
    assert "base_from_flange" in pages["spherecal/devices/contract.html"] and "check_target" in pages["spherecal/devices/contract.html"]
    assert "true_transform" in pages["spherecal/plugins/testing.html"]
