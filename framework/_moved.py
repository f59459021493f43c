"""Import paths of the layout before the layer packages, kept working for one release.

``import spherecal.geometry`` (and every other module path below) still gives the
module, now at its new home, with a :class:`DeprecationWarning` naming that home. The
table is the whole map; :mod:`spherecal` installs the finder on import."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

#: old module path -> the module that now holds it
MOVED = {
    "spherecal.errors": "spherecal.core.errors",
    "spherecal.geometry": "spherecal.core.geometry",
    "spherecal.models": "spherecal.core.models",
    "spherecal.kinematics": "spherecal.core.kinematics",
    "spherecal.urdf": "spherecal.core.urdf",
    "spherecal.mapping": "spherecal.core.mapping",
    "spherecal.metrology": "spherecal.core.metrology",
    "spherecal.lazy": "spherecal.core.lazy",
    "spherecal.safeio": "spherecal.io.files",
    "spherecal.dataio": "spherecal.io.dataset",
    "spherecal.ply": "spherecal.io.ply",
    "spherecal.runlog": "spherecal.io.runlog",
    "spherecal.exporters": "spherecal.io.exporters",
    "spherecal.lineproto": "spherecal.devices.line_protocol",
    "spherecal.linelink": "spherecal.devices.line_robot",
    "spherecal.planning": "spherecal.motion.planning",
    "spherecal.kinplan": "spherecal.motion.kinematic_plan",
    "spherecal.acquisition": "spherecal.motion.acquisition",
    "spherecal.validation": "spherecal.motion.validation",
    "spherecal.scanning": "spherecal.motion.scanning",
    "spherecal.compare": "spherecal.report.compare",
    "spherecal.completion": "spherecal.cli.completion",
    "spherecal.sim.planner": "spherecal.sim.datasets",
}


class _Alias(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:
        pass


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Finds an old module path and hands out the module at its new home."""

    def find_spec(self, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        warnings.warn(f"{fullname} has moved to {new}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    if not any(isinstance(f, MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedModuleFinder())
