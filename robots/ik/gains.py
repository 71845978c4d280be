"""The IK back-ends' gains: ``JointGains``, what every back-end keeps of the joints (``DlsGains``,
``QpGains`` and ``PinkGains`` add their own), and their checks, a ``RobotError`` of one line naming the
gain, the rule and the value. A bool is never taken for a number."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeGuard

from robots.errors import RobotError

__all__ = ["JointGains", "is_number", "check_gain"]


def is_number(value: object) -> TypeGuard[float]:
    """An int or a float that is not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_gain(owner: str, name: str, value: object, rule: str, ok: Callable[[float], bool]) -> None:
    """``RobotError`` "<owner> gain <name> must be <rule>, got <value>" unless ``value`` is a number for
    which ``ok`` holds (NaN never does)."""
    if not (is_number(value) and ok(value)):
        raise RobotError(f"{owner} gain {name} must be {rule}, got {value!r}")


@dataclass(frozen=True)
class JointGains:
    """posture_gain: k_p [1/s] of the null-space pull toward q_home; limit_margin: kept distance to
    joint limits [rad|m]; speed_fraction: the IK commands at most this fraction of each joint's v_max,
    in (0, 1]: the joint servo overshoots its command slightly, so at 1 a joint can exceed its v_max
    a little."""

    posture_gain: float = 1.0
    limit_margin: float = 0.02
    speed_fraction: float = 0.97

    def __post_init__(self) -> None:
        check_gain("IK", "speed_fraction", self.speed_fraction, "a number in (0, 1]", lambda x: 0.0 < x <= 1.0)
