"""Public names of a package imported on first use (PEP 562), so that importing the package is cheap.

``lfd`` and ``sim`` both keep their programs' first lines (``lfd --help``, ``lfd-demo-arm``) free of
torch and MuJoCo: their top-level names are looked up through ``lazy_getattr``. This module imports
only the standard library.
"""

from __future__ import annotations

import importlib
import sys

TYPE_CHECKING = False  # not typing's: this module is loaded with the packages' first lines
if TYPE_CHECKING:
    from collections.abc import Callable, Collection
    from typing import Any

__all__ = ["lazy_getattr"]


def lazy_getattr(package: str, names: dict[str, str],
                 submodules: Collection[str] | None = None) -> Callable[[str], Any]:
    """The module-level ``__getattr__`` of ``package`` (PEP 562).

    Parameters
    ----------
    package : str
        The package's name, e.g. ``"lfd"``.
    names : dict of str to str
        Public name -> the module that defines it; the first lookup imports that module and keeps
        the value in the package's namespace.
    submodules : collection of str, optional
        The submodules reachable as attributes (``import lfd; lfd.learners``); None: any submodule
        that exists.

    Returns
    -------
    callable
        ``__getattr__(name)``; an unknown name raises AttributeError.
    """
    def __getattr__(name: str) -> Any:
        if name in names:
            value = getattr(importlib.import_module(names[name]), name)
            setattr(sys.modules[package], name, value)
            return value
        if submodules is not None:
            if name in submodules:
                return importlib.import_module(f"{package}.{name}")
        elif not name.startswith("__"):
            try:
                return importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as e:
                if e.name != f"{package}.{name}":
                    raise
        raise AttributeError(f"module '{package}' has no attribute '{name}'")

    return __getattr__
