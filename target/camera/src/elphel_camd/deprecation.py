"""Old import paths kept working: a module-level ``__getattr__`` that warns and forwards.

A module whose names moved sets ``__getattr__ = moved(__name__, {old: "new.module:new"})``;
``from old.module import old`` then returns the new object with a `DeprecationWarning`.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any


def moved(module: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for names that moved.

    Parameters
    ----------
    module
        The old module's name (its ``__name__``).
    names
        Old name -> ``"new.module:new_name"``.
    """

    def forward(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        where, _, new = names[name].partition(":")
        warnings.warn(
            f"{module}.{name} is deprecated; use {where}.{new}", DeprecationWarning, stacklevel=2
        )
        return getattr(importlib.import_module(where), new)

    return forward
