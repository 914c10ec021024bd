"""Package attributes imported on first use (a PEP 562 module ``__getattr__``), so that a light
command such as ``rapidds --help`` does not pay for the heavy submodules a package re-exports."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["submodule_attributes"]


def submodule_attributes(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package``: each name in ``where`` is looked up in the submodule
    ``where[name]`` (relative to the package) when it is first asked for."""

    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{where[name]}"), name)

    return __getattr__
