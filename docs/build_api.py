"""Build the API reference of the plugin API (``spherecal.plugins``: what a plugin author
may rely on) and the modules behind its names, from their docstrings, into a folder of
HTML pages (offline: pdoc, a test dependency, renders the installed package; nothing is
fetched).

    python docs/build_api.py out/api      # then open out/api/index.html

CI runs it (.ci/run); tests/plugins/test_api_reference.py checks what the pages hold."""

from __future__ import annotations

import sys
from pathlib import Path

#: The modules of the reference: the plugin API (``spherecal.plugins``, with its hooks,
#: registries, host and pytest fixtures), then the modules behind its names: poses and
#: data (models), errors, the device protocols and descriptions (devices.contract), the
#: streaming contracts (devices.pose_streaming, the streams in core.streams), robot
#: safety (devices.motion_safety), the value objects (field of view, workspace box),
#: kinematics and URDF, the geometry helpers, the line protocol both ends, the exporters
#: and their formatting helpers, the simulated world (sim: the cell with its arm, time
#: and random streams, the simulated controller and its settings, the device server) and
#: the planner (planning).
API_MODULES = (
    "spherecal.plugins",
    "spherecal.plugins.registry",
    "spherecal.plugins.host",
    "spherecal.plugins.testing",
    "spherecal.core.models",
    "spherecal.core.errors",
    "spherecal.devices.contract",
    "spherecal.devices.pose_streaming",
    "spherecal.core.streams",
    "spherecal.devices.motion_safety",
    "spherecal.core.field_of_view",
    "spherecal.core.workspace",
    "spherecal.core.kinematics",
    "spherecal.core.urdf",
    "spherecal.core.geometry",
    "spherecal.devices.line_protocol",
    "spherecal.devices.line_robot",
    "spherecal.sim.controller",
    "spherecal.sim.settings",
    "spherecal.io.exporters",
    "spherecal.report.export",
    "spherecal.sim",
    "spherecal.sim.cell",
    "spherecal.sim.robot_error",
    "spherecal.sim.timeline",
    "spherecal.sim.rngs",
    "spherecal.sim.device_server",
    "spherecal.motion.planning",
)


def build(out: str | Path) -> Path:
    """Write the reference into ``out`` (created if needed) and return it."""
    import pdoc

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pdoc.pdoc(*API_MODULES, output_directory=out)
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python docs/build_api.py OUTPUT_FOLDER")
    print(f"API reference written to {build(sys.argv[1]) / 'index.html'}")
