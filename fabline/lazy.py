"""Stage packages whose public surface loads its modules on first use (PEP 562 module `__getattr__`).

A command that needs only a stage's file format (export reads parts.json and nesting.json) then does not
pay for importing the stage's solvers and their libraries (scipy.signal, trimesh, ...).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable


def lazy_surface(package: str, exports: dict[str, tuple[str, ...]]) -> tuple[Callable[[str], Any], list[str]]:
    """`__getattr__` and `__all__` for `package`; `exports` maps each submodule to the public names it provides."""
    owner = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str) -> Any:
        if name not in owner:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{owner[name]}"), name)
        setattr(sys.modules[package], name, value)  # later lookups find it without this hook
        return value

    return __getattr__, sorted(owner)
