"""Checks of option values, shared by the learners' configs and the LASA benchmark protocol.

Each check reads the named attributes of a config object (a dataclass in its ``__post_init__``)
and raises ``error`` (ValueError unless given; ``Learner.make_config`` turns it into a
ConfigError) with one line naming the option, the rule and the value. A bool is never taken for a
number.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any


def is_int(value: Any) -> bool:
    """An int that is not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_real(value: Any) -> bool:
    """A finite int or float that is not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_ints(obj: Any, bounds: Iterable[tuple[str, int, int | None]],
               error: type[Exception] = ValueError) -> None:
    """Each attribute ``name`` of ``obj`` must be an integer in [low, high] (high None: no upper bound).

    bounds : (name, low, high) triples; the message reads ``name must be an integer >= low`` or
    ``... from low to high``, then the value.
    """
    for name, low, high in bounds:
        value = getattr(obj, name)
        if not is_int(value) or value < low or (high is not None and value > high):
            rule = f">= {low}" if high is None else f"from {low} to {high}"
            raise error(f"{name} must be an integer {rule}, got {value!r}")


def check_numbers(obj: Any, names: Iterable[str], rule: str, ok: Callable[[float], bool], to_float: bool = False,
                  allow_inf: bool = False) -> None:
    """Each attribute of ``obj`` in ``names`` must be a finite number (or +inf with ``allow_inf``) for
    which ``ok`` holds, else ValueError ``name must be <rule>, got <value>``; with ``to_float`` it is
    stored back as a float."""
    for name in names:
        value = getattr(obj, name)
        inf = allow_inf and isinstance(value, float) and value == math.inf
        if not (inf or is_real(value)) or not ok(value):
            raise ValueError(f"{name} must be {rule}, got {value!r}")
        if to_float:
            setattr(obj, name, float(value))


def check_positive(obj: Any, names: Iterable[str], to_float: bool = False, allow_inf: bool = False) -> None:
    """Each attribute of ``obj`` in ``names`` must be a finite number > 0 (ValueError), or +inf
    with ``allow_inf``; with ``to_float`` it is stored back as a float."""
    check_numbers(obj, names, f"a positive number{' (or inf)' if allow_inf else ''}", lambda v: v > 0,
                  to_float, allow_inf)


def check_bools(obj: Any, names: Iterable[str]) -> None:
    """Each attribute of ``obj`` in ``names`` must be True or False (ValueError)."""
    for name in names:
        value = getattr(obj, name)
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
