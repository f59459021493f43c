"""The layers of ``spherecal`` (docs/architecture.md): each module imports only from its
own layer and the layers below it, the built-in plugins import only the curated plugin
API, and no two modules import each other, directly or round a longer circle. Every
import counts: at the top of a module, inside a function, or under ``TYPE_CHECKING``."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: source folder -> the package it installs as
ROOTS = {"framework": "spherecal", "plugins": "spherecal.plugins", "robots": "spherecal.robots",
         "sensors": "spherecal.sensors"}
#: lowest first; a module may import its own layer and any layer before it
LAYERS = ("spherecal.core", "spherecal.io", "spherecal.config", "spherecal.devices", "spherecal.estimation",
          "spherecal.motion", "spherecal.sim", "spherecal.report", "spherecal.plugins", "spherecal.app",
          "spherecal.cli")
#: modules outside the layers: the package root (its version) and the map of moved paths
ROOT_MODULES = ("spherecal", "spherecal._moved")
PLUGIN_PACKAGES = ("spherecal.robots", "spherecal.sensors")


def _module_name(path: Path) -> str:
    folder = path.relative_to(REPO).parts[0]
    parts = [*ROOTS[folder].split("."), *path.relative_to(REPO / folder).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> dict[str, Path]:
    return {_module_name(p): p for folder in ROOTS for p in (REPO / folder).rglob("*.py")}


MODULES = _sources()


def _imports(name: str, path: Path) -> set[str]:
    """The spherecal modules ``name`` imports (a ``from package import name`` counts as
    the submodule when there is one)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                found.add(sub if sub in MODULES else module)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                found.add(_resolve(node.args[0].value, package))
        elif isinstance(node, ast.Dict) and node.values and all(
                isinstance(v, ast.Constant) and isinstance(v.value, str) for v in node.values):
            # a lazy table of names loaded on first use, {"Name": ".module"}: each value a module
            targets = [_resolve(v.value, package) for v in node.values]
            if all(t in MODULES for t in targets):
                found.update(targets)
    return {m for m in found if m == "spherecal" or m.startswith("spherecal.")}


def _resolve(text: str, package: str) -> str:
    """A module name as ``importlib.import_module(text, package)`` reads it."""
    if not text.startswith("."):
        return text
    dots = len(text) - len(text.lstrip("."))
    base = package.split(".")
    base = base[: len(base) - (dots - 1)]
    return ".".join(base + ([text.lstrip(".")] if text.lstrip(".") else []))


#: The map of moved module paths names every module as data, not as an import.
GRAPH = {name: (_imports(name, path) - {name} if name != "spherecal._moved" else set())
         for name, path in MODULES.items()}


def _layer(module: str) -> int | None:
    for i, layer in enumerate(LAYERS):
        if module == layer or module.startswith(layer + "."):
            return i
    return None


def test_every_framework_module_sits_in_a_layer():
    outside = [m for m in MODULES if _layer(m) is None and m not in ROOT_MODULES
               and not m.startswith(PLUGIN_PACKAGES) and m not in ("spherecal.robots", "spherecal.sensors")]
    assert not outside, f"modules in no layer: {outside}"


def test_each_layer_imports_only_itself_and_the_layers_below():
    upward = []
    for module, imported in GRAPH.items():
        own = _layer(module)
        if own is None:
            continue
        for target in imported:
            other = _layer(target)
            if other is not None and other > own:
                upward.append(f"{module} -> {target}")
    assert not upward, "imports up the layers:\n" + "\n".join(sorted(upward))


def test_built_in_plugins_import_only_the_plugin_api():
    """A plugin package imports itself and ``spherecal.plugins`` (with its modules, the
    hook specifications and the testing fixtures), nothing else of spherecal."""
    outside = []
    for module, imported in GRAPH.items():
        if not module.startswith(PLUGIN_PACKAGES):
            continue
        own_package = ".".join(module.split(".")[:3])
        for target in imported:
            if (target == "spherecal.plugins" or target.startswith("spherecal.plugins.") or target == own_package
                    or target.startswith(own_package + ".") or target in PLUGIN_PACKAGES):
                continue
            outside.append(f"{module} -> {target}")
    assert not outside, "plugins reaching past spherecal.plugins:\n" + "\n".join(sorted(outside))


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH.get(v, ()):
            if w not in GRAPH:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    return components


def test_no_import_cycles():
    cycles = _cycles()
    assert not cycles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


@pytest.mark.parametrize("module", ["spherecal.core.geometry", "spherecal.app", "spherecal.plugins"])
def test_the_checks_see_the_modules(module):
    """The scan finds the tree (a check over nothing would pass)."""
    assert module in MODULES


def test_every_package_folder_is_installed():
    """pyproject.toml lists the packages one by one (several source folders make one
    namespace): a package folder missing from the list is absent from a built wheel,
    though an editable install still finds it."""
    import tomllib

    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["packages"])
    folders = {name for name, path in MODULES.items() if path.name == "__init__.py"}
    assert folders - listed == set(), f"package folders not in pyproject.toml's packages: {sorted(folders - listed)}"
    assert listed - folders == set(), f"pyproject.toml lists packages with no folder: {sorted(listed - folders)}"


def test_a_module_named_in_a_string_counts_as_an_import():
    """The scan reads the lazy tables and ``import_module("...")`` strings too: the
    estimation package's table names its pipeline."""
    assert "spherecal.estimation.pipeline" in GRAPH["spherecal.estimation"]
    assert "spherecal.sim.datasets" in GRAPH["spherecal.sim"]


def test_test_modules_have_unique_basenames():
    """The test folders have no __init__.py: pytest imports each test module by its file
    name, and two of one name stop the whole collection in a fresh clone."""
    from collections import Counter

    tests = Path(__file__).resolve().parent
    names = Counter(p.name for p in tests.rglob("test_*.py"))
    assert not [n for n, k in names.items() if k > 1]
