"""Fixtures for the plugin-host tests."""

from __future__ import annotations

import importlib.metadata
import sys
import types

import pytest


@pytest.fixture
def fake_entry_points(monkeypatch):
    """Replace the installed "spherecal" entry points with fake ones.

    Call it with ``{entry_point_name: (module_name, module_or_None)}``; a module object is
    put into ``sys.modules`` under ``module_name`` (None leaves the name unimportable)."""

    def install(table: dict[str, tuple[str, types.ModuleType | None]]):
        eps = []
        for ep_name, (module_name, module) in table.items():
            if module is not None:
                monkeypatch.setitem(sys.modules, module_name, module)
            eps.append(importlib.metadata.EntryPoint(name=ep_name, value=module_name, group="spherecal"))

        def entry_points(**selection):
            group = selection.get("group")
            return [ep for ep in eps if group is None or ep.group == group]

        monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)

    return install
