"""Lazy public names for a package: ``name -> defining module``, imported on first use (PEP 562).

A package's ``__init__`` lists its public names in a table and installs the two hooks, so importing the
package stays cheap and each name's module is imported only when the name is first used::

    _PUBLIC = {"LidarLWLR": "sensor_envs.lidar.lwlr", ...}
    __all__ = list(_PUBLIC)
    __getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, table: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package`` whose public names are the keys of ``table``.

    Args:
        package: the package's ``__name__``.
        table: public name -> the module (absolute dotted name) that defines it under that name.

    Returns:
        ``(__getattr__, __dir__)``: the first imports a public name on first use and caches it in the
        package's namespace (later lookups skip it); an unknown name is an ``AttributeError``. The second
        lists the public names.
    """
    names = dict(table)

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(names)

    return __getattr__, __dir__
