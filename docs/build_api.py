"""Build the API reference of the classes and functions a plugin author uses, from their
docstrings, into a folder of HTML pages (offline: pdoc, a test dependency, renders the
installed package; nothing is fetched).

    python docs/build_api.py out/api      # then open out/api/index.html

CI runs it (.ci/run); tests/core/test_api_reference.py checks what the pages hold."""

from __future__ import annotations

import sys
from pathlib import Path

#: The modules of the reference: poses and data (models), the device protocols and
#: descriptions (devices), the simulated world (sim), the planner (planning), the pytest
#: fixtures and harnesses (plugins.testing), the hooks (plugins.hookspecs), the exporters
#: and the geometry helpers.
API_MODULES = (
    "spherecal.core.models",
    "spherecal.devices.contract",
    "spherecal.sim",
    "spherecal.motion.planning",
    "spherecal.plugins.testing",
    "spherecal.plugins.hookspecs",
    "spherecal.io.exporters",
    "spherecal.core.geometry",
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
