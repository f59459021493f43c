"""Names a package defines on first use (PEP 562): a package whose contents are costly
to import, and which is imported for one light part of it, names the rest here, so
that ``from package import Name`` and ``dir(package)`` work as with eager imports."""

from __future__ import annotations

import importlib
from typing import Any, Callable, Mapping


def lazy_attributes(package: str, where: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of ``package`` (its
    ``__name__``) for the names in ``where`` (name -> the module, relative to the
    package, that defines it). A name is imported on its first use and then kept in
    the package's namespace."""
    namespace = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(where))

    return __getattr__, __dir__
