"""The benchmarks behind ``lfd bench`` (protocols: docs/benchmark.md).

Suites (``lfd.bench.suite.Suite``: units, cells, scores, one report path), by name in ``SUITES``:
``lasa`` (``lfd.bench.lasa``) and ``robottasks`` (``lfd.bench.robottasks``). What they share:
``model`` (the ``Model`` interface), ``fields`` and ``dmp`` (its implementations), ``spaces``
(positions or poses; ``fit``), ``runner`` and ``executor`` (cached, parallel, resumable cells),
``summary`` and ``report``. The reports beside them: ``comparison`` and ``comparison_report``
(the spiral, ``lfd bench comparison``), ``tradeoff`` (``lfd bench tradeoff``), ``obstacles`` and
``obstacles_report`` (``lfd bench obstacles``).

Importing this package imports nothing else (``lfd --help`` reads ``SUITES``); ``get_suite`` imports
a suite's module.
"""

from __future__ import annotations

import importlib
from typing import Any

#: every suite by its name in ``lfd bench NAME``: the module whose ``SUITE`` is its class
SUITES: dict[str, str] = {"lasa": "lfd.bench.lasa", "robottasks": "lfd.bench.robottasks"}


def get_suite(name: str) -> Any:
    """The suite class (a ``lfd.bench.suite.Suite`` subclass) registered under ``name``."""
    return importlib.import_module(SUITES[name]).SUITE


__all__ = ["SUITES", "get_suite"]
