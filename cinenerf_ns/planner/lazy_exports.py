"""A package's public names loaded from their modules on first use (PEP 562): importing the package, or one light
module of it, does not import every module the package exports (torch among them)."""
from __future__ import annotations

import importlib
from typing import Any, Callable, Dict, Tuple


def lazy_exports(package: str, where: Dict[str, str]) -> Tuple[Callable[[str], Any], Callable[[], list], list]:
    """(__getattr__, __dir__, __all__) for ``package``, where ``where`` maps each public name to the module (relative
    to the package) that defines it."""
    def __getattr__(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{where[name]}"), name)

    def __dir__() -> list:
        return sorted(set(vars(importlib.import_module(package))) | set(where))

    return __getattr__, __dir__, sorted(where)
