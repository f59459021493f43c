"""The "Writing a ... plugin" pages end with a TOML configuration that calibrates with the
new device on the simulated cell: each page's configuration, taken from the page, runs
`spherecal calibrate` with the example plugins and recovers the cell's true transform."""

from __future__ import annotations

import importlib
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLE_SRC = REPO / "examples" / "third_party_plugin" / "src"


def page_toml(page: str) -> str:
    text = (REPO / "docs" / page).read_text()
    last = text[text.index("Calibrate from a configuration"):]
    return re.search(r"```toml\n(.*?)```", last, re.S)[1]


@pytest.fixture
def example_plugins_host(monkeypatch):
    """The run's plugin host: the installed plugins plus the example package's two."""
    from spherecal.app import plugin_host
    from spherecal.plugins.host import PluginHost

    monkeypatch.syspath_prepend(str(EXAMPLE_SRC))
    mods = [importlib.import_module(f"spherecal_example_plugins.{m}") for m in ("arm", "profiler")]
    host = lambda enable=None: PluginHost(plugins=[("example_arm", mods[0]),  # noqa: E731
                                                   ("example_profiler", mods[1])])
    monkeypatch.setattr(plugin_host, "make_host", host)
    return host


@pytest.mark.parametrize("page, device", [("writing-a-robot-plugin.md", "example_arm"),
                                          ("writing-a-sensor-plugin.md", "example_profiler")])
@pytest.mark.slow
def test_the_pages_configuration_calibrates_on_the_simulated_cell(page, device, example_plugins_host, tmp_path,
                                                                  capsys):
    from spherecal.cli import EXIT_OK, main
    from spherecal.config import load_config
    from spherecal.app.cell import configured_for_sensor, make_cell
    from spherecal.app.plugin_host import robot_arm

    text = page_toml(page)
    assert f'type = "{device}"' in text and "[simulation]" in text and "[simulation.fov]" not in text
    path = tmp_path / "page.toml"
    path.write_text(text)
    assert main(["calibrate", str(path)]) == EXIT_OK
    result = json.loads((tmp_path / re.search(r'output_dir = "(.*)"', text)[1] / "result.json").read_text())
    # the cell the run used: the same configuration, plugins and field of view
    host = example_plugins_host()
    loaded, fov = configured_for_sensor(load_config(path), host)
    cell = make_cell(loaded.config, robot_arm(loaded, host), fov)
    true = cell.true_transform
    t = np.asarray(result["transform"]["translation_mm"])
    assert np.linalg.norm(t - true.translation_mm) < 0.2  # mm; the cell's noise is 0.01-0.02 mm
    q = np.asarray(result["transform"]["quaternion_wxyz"])
    assert abs(abs(float(q @ np.asarray(true.quaternion_wxyz))) - 1.0) < 1e-6  # well under 0.2 deg


def test_the_robot_pages_plugin_listing_is_what_the_host_prints(example_plugins_host):
    """The sample of `spherecal plugins` in "Install it and see it": the built-in plugins' lines and the
    example robot's are those the host prints today (the example's plugin lines say
    "entry point" when installed; registered here, they are checked by name)."""
    text = (REPO / "docs" / "writing-a-robot-plugin.md").read_text()
    start = text.index("Install it and see it")
    section = text[start:text.index("\n## ", start)]
    sample = re.findall(r"```\n(plugins:\n.*?)```", section, re.S)[0].splitlines()
    listing = example_plugins_host().format_description().splitlines()
    builtins = [line for line in listing if ": built-in, " in line]
    assert [line for line in sample if ": built-in, " in line] == builtins
    assert [line.split(":")[0] for line in sample if ": entry point, " in line] == [
        "  example_arm", "  example_profiler"]
    start = listing.index("robot type 'example_arm' (plugin 'example_arm'): "
                          "six-axis arm on the XA/1 TCP protocol, simulated on a simulated cell (example plugin)")
    end = next(i for i in range(start + 1, len(listing)) if not listing[i].startswith("    "))
    block = listing[start:end]
    assert sample[sample.index(block[0]):sample.index(block[0]) + len(block)] == block
