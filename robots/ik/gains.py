"""Checks of the IK back-ends' gains (``DlsGains``, ``QpGains``, ``PinkGains``): a ``RobotError`` of one
line naming the gain, the rule and the value. A bool is never taken for a number."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeGuard

from robots.errors import RobotError

__all__ = ["is_number", "check_gain"]


def is_number(value: object) -> TypeGuard[float]:
    """An int or a float that is not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_gain(owner: str, name: str, value: object, rule: str, ok: Callable[[float], bool]) -> None:
    """``RobotError`` "<owner> gain <name> must be <rule>, got <value>" unless ``value`` is a number for
    which ``ok`` holds (NaN never does)."""
    if not (is_number(value) and ok(value)):
        raise RobotError(f"{owner} gain {name} must be {rule}, got {value!r}")
