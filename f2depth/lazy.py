"""Packages whose names are imported from their module on first use (PEP 562), so that importing one module
of a package loads no other: a package's ``__init__`` holds ``_HOMES`` (name → submodule, read as it stands
by tools/dvc_deps.py) and ``__getattr__ = lazy_getattr(__name__, _HOMES)``."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_getattr(package: str, homes: dict[str, str]) -> Callable[[str], object]:
    """The module ``__getattr__`` of ``package`` that imports each name of ``homes`` from its submodule."""

    def __getattr__(name: str) -> object:
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{homes[name]}"), name)

    return __getattr__
