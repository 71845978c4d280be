"""A field run S times faster or slower: the same motion, on the same paths, in 1/S of the time.

``at_speed(field, S)`` wraps any field. Its trajectories are the field's own, re-timed: x_S(t) =
x(S t). For each kind (``lfd.field.FieldKind``):

- autonomous, f_S(x) = S f(x);
- time-varying, f_S(x, t) = S f(x, S t): what moves with time (a moving goal, moving obstacles)
  moves S times faster too, so the whole scene keeps its timing relative to the motion;
- phased (the tracking learner, Eqs. (T3)-(T4)), (dx/dt, ds/dt)_S = S (dx/dt, ds/dt): the phase
  advances S times faster and the reference is the same curve.

What is stated of the field holds for the re-timed one with time scaled: the same equilibria and
attractors, the same Lyapunov function V, with dV/dt multiplied by S (a decrease at rate alpha
becomes one at rate S alpha); a field contracting at rate c in a metric M contracts at rate S c in
the same M, with the same overshoot constant sqrt(b/a) (docs/equations.md). The speeds, and with
them the accelerations (S^2) and jerks (S^3) an arm is asked for, grow: ``robots.limits`` checks them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from lfd.errors import ConfigError
from lfd.field import Field, FieldKind, FieldWrapper, cached_single_point_evaluator
from lfd.runner import Runner

#: the speeds accepted, (lowest, highest)
SPEED_RANGE = (0.05, 20.0)


def check_speed(speed: float) -> float:
    """``speed`` as a float, or ``ConfigError`` unless it is finite and within ``SPEED_RANGE``."""
    s = float(speed)
    if not (math.isfinite(s) and SPEED_RANGE[0] <= s <= SPEED_RANGE[1]):
        raise ConfigError(f"the speed must be a factor between {SPEED_RANGE[0]:g} and {SPEED_RANGE[1]:g}, got {speed}")
    return s


class SpeedRunner(Runner):
    """The run of a field at speed S: the field's own runner at the period S dt (so a phase advances
    S times as far per call), its commands times S, at the time S t."""

    def __init__(self, inner: Runner, speed: float, dt: float) -> None:
        self.inner, self.speed, self.dt = inner, float(speed), float(dt)

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.speed * self.inner(x, self.speed * t)

    def peek(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.speed * self.inner.peek(x, self.speed * t)

    def command_at(self, x: np.ndarray, t: float, s: float | None = None) -> np.ndarray:
        return self.speed * self.inner.command_at(x, self.speed * t, s)

    def phases(self) -> np.ndarray | None:
        return self.inner.phases()

    def path(self, s: np.ndarray) -> np.ndarray | None:
        return self.inner.path(s)

    @property
    def duration(self) -> float | None:
        inner = self.inner.duration
        return None if inner is None else inner / self.speed


class SpeedField(FieldWrapper):
    """``field`` at speed S (module docstring); ``at_speed`` builds the class of the field's kind."""

    kind: ClassVar[FieldKind] = FieldKind.AUTONOMOUS

    def __init__(self, field: Field, speed: float) -> None:
        self.field, self.speed = field, check_speed(speed)

    @property
    def goal(self) -> np.ndarray:
        """The wrapped field's goal, shape (d,)."""
        return np.asarray(self.field.goal)

    @property
    def duration(self) -> float:
        """A phased field's T / S, s."""
        inner: Any = self.field
        return float(inner.duration) / self.speed

    def __call__(self, x: np.ndarray, *args: Any) -> Any:
        """The re-timed field at x (autonomous: f_S(x); phased: at (x, s), both rates times S)."""
        out = self.field(x, *args)
        if isinstance(out, tuple):
            return tuple(self.speed * np.asarray(o) for o in out)
        return self.speed * np.asarray(out)

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The per-point function of the wrapped field's kind, re-timed."""
        fn, s = cached_single_point_evaluator(self.field), self.speed
        return lambda x, *a: s * fn(x, *a)

    def pose_velocity(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The twist of a pose field at the pose (x (3,), q (4,)), times S, shape (6,)."""
        inner: Any = self.field
        return self.speed * np.asarray(inner.pose_velocity(x, q))

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        """A ``SpeedRunner`` around the wrapped field's runner at the period S dt."""
        return SpeedRunner(self.field.runner(start, self.speed * dt), self.speed, dt)

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        """The wrapped field's trajectory over the times S t: x_S(t) = x(S t), shape (T, d), and its phase."""
        return self.field.trajectory(x0, self.speed * np.asarray(t, dtype=np.float64), substeps)

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1) -> np.ndarray:
        """Batched rollouts of the wrapped field over S t, shape (T, N, d)."""
        inner: Any = self.field
        return np.asarray(inner.rollout(x0, self.speed * np.asarray(t, dtype=np.float64), method=method,
                                        substeps=substeps))

    def __repr__(self) -> str:
        return f"SpeedField({self.field!r}, speed={self.speed:g})"


class _TimedSpeedField(SpeedField):
    """A time-varying field re-timed: f_S(x, t) = S f(x, S t)."""

    kind = FieldKind.TIME_VARYING

    def __call__(self, x: np.ndarray, *args: Any) -> Any:
        return self.speed * np.asarray(self.field(x, self.speed * float(args[0]) if args else 0.0))

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        fn, s = cached_single_point_evaluator(self.field), self.speed
        return lambda x, t=0.0: s * fn(x, s * t)


class _PhasedSpeedField(SpeedField):
    kind = FieldKind.PHASED


_BY_KIND: dict[FieldKind, type[SpeedField]] = {FieldKind.AUTONOMOUS: SpeedField,
                                               FieldKind.TIME_VARYING: _TimedSpeedField,
                                               FieldKind.PHASED: _PhasedSpeedField}


def at_speed(field: Field, speed: float) -> Field:
    """``field`` run ``speed`` times faster (slower below 1): x_S(t) = x(S t) (module docstring).

    Parameters
    ----------
    field : Field
        Any field, of any kind and space.
    speed : float
        S, within ``SPEED_RANGE``; 1 gives ``field`` itself.

    Returns
    -------
    Field
        The re-timed field (a ``SpeedField`` of the field's kind), or ``field`` when S = 1.
    """
    s = check_speed(speed)
    if s == 1.0:
        return field
    return _BY_KIND[field.kind](field, s)
