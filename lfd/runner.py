"""A field run from one start: the per-step command that a control loop calls, whatever the field's kind.

Every field hands out its own runner (``Field.runner(start, dt)``), so no caller asks what kind
of field it holds: the runner already knows whether the field takes the time (``FieldKind.TIME_VARYING``)
or carries a phase (``FieldKind.PHASED``, Eqs. (T3)-(T4) of docs/equations.md). A control loop calls
``runner(x, t)`` once per control period dt at the measured x; the runner advances its own state.
``Field.trajectory(x0, t)`` is the matching single-start numpy RK4 rollout (the paper's Eq. (8)).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

from lfd.integrate import rk4, rk4_phase

PointFn = Callable[[np.ndarray], np.ndarray]
TimedFn = Callable[[np.ndarray, float], np.ndarray]
PhaseFn = Callable[[np.ndarray, float], tuple[np.ndarray, float]]


class Runner(ABC):
    """One run of a field at a fixed control period ``dt`` [s].

    ``runner(x, t)`` is dx/dt at the measured point x, shape (d,), task units, at time t [s]; it
    then advances the field's own state (its phase) over dt. ``peek`` gives the same command
    without advancing, ``command_at`` the command at a recorded state.
    """

    dt: float

    @abstractmethod
    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        """dx/dt, shape (d,), at x, shape (d,), and time t [s]; advances the run's state."""

    @abstractmethod
    def peek(self, x: np.ndarray, t: float) -> np.ndarray:
        """dx/dt, shape (d,), at x, shape (d,), and t [s], in the run's current state (not advanced)."""

    @abstractmethod
    def command_at(self, x: np.ndarray, t: float, s: float | None = None) -> np.ndarray:
        """dx/dt, shape (d,), at x, shape (d,), time t [s] and phase s (ignored without a phase)."""

    def phases(self) -> np.ndarray | None:
        """The phase before each call and the current one, shape (calls + 1,); None without a phase."""
        return None

    def path(self, s: np.ndarray) -> np.ndarray | None:
        """The run's reference r(s | start), shape s.shape + (d,), at phases s; None without a phase."""
        return None

    @property
    def duration(self) -> float | None:
        """T [s], the time the phase takes at the demos' pace (ds/dt = 1 / T); None without a phase."""
        return None


class PointRunner(Runner):
    """The run of an autonomous field f(x) (``FieldKind.AUTONOMOUS``): the time is not used."""

    def __init__(self, fn: PointFn, dt: float) -> None:
        self.fn, self.dt = fn, float(dt)

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.fn(x)

    def peek(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.fn(x)

    def command_at(self, x: np.ndarray, t: float, s: float | None = None) -> np.ndarray:
        return self.fn(x)


class TimedRunner(Runner):
    """The run of a time-varying field f(x, t) (``FieldKind.TIME_VARYING``: a moving goal, moving obstacles)."""

    def __init__(self, fn: TimedFn, dt: float) -> None:
        self.fn, self.dt = fn, float(dt)

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.fn(x, t)

    def peek(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.fn(x, t)

    def command_at(self, x: np.ndarray, t: float, s: float | None = None) -> np.ndarray:
        return self.fn(x, t)


class PhaseRunner(Runner):
    """The run of a field with a phase (``FieldKind.PHASED``): each call returns dx/dt of Eq. (T3)
    at the current phase s and advances s by one explicit Euler step of Eq. (T4) over dt,
    s <- min(1, s + dt ds/dt), so the phase waits while the measured tool is held back.

    Parameters
    ----------
    fn : callable
        (x (d,), s) -> (dx/dt (d,), ds/dt), conditioned on the run's start (``phase_point_fn``).
    dt : float
        The control period, s.
    s0 : float
        The initial phase.
    reference : callable
        s (P,) -> r(s | start), shape (P, d).
    duration : float
        T, s.
    """

    def __init__(self, fn: PhaseFn, dt: float, s0: float, reference: Callable[[np.ndarray], np.ndarray],
                 duration: float) -> None:
        self.fn, self.dt, self.s = fn, float(dt), float(s0)
        self._reference, self._duration = reference, float(duration)
        self.trace: list[float] = []

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        v, sdot = self.fn(x, self.s)
        self.trace.append(self.s)
        self.s = min(1.0, self.s + self.dt * sdot)
        return v

    def peek(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.fn(x, self.s)[0]

    def command_at(self, x: np.ndarray, t: float, s: float | None = None) -> np.ndarray:
        return self.fn(x, self.s if s is None else float(s))[0]

    def phases(self) -> np.ndarray:
        return np.asarray(self.trace + [self.s], dtype=np.float64)

    def path(self, s: np.ndarray) -> np.ndarray:
        return self._reference(np.asarray(s, dtype=np.float64))

    @property
    def duration(self) -> float:
        return self._duration


def point_trajectory(fn: PointFn, x0: np.ndarray, t: np.ndarray, substeps: int = 1
                     ) -> tuple[np.ndarray, None]:
    """RK4 of dx/dt = fn(x) from x0 (d,) over t (T,): (x (T, d), None)."""
    return rk4(fn, x0, t, substeps), None


def timed_trajectory(fn: TimedFn, x0: np.ndarray, t: np.ndarray, substeps: int = 1
                     ) -> tuple[np.ndarray, None]:
    """RK4 of dx/dt = fn(x, t) from x0 (d,) over t (T,), from t[0]: (x (T, d), None)."""
    return rk4(fn, x0, t, substeps, timed=True), None


def phase_trajectory(fn: PhaseFn, x0: np.ndarray, t: np.ndarray, substeps: int = 1, s0: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """RK4 of (x, s) under fn from (x0 (d,), s0) over t (T,): (x (T, d), s (T,))."""
    return rk4_phase(fn, x0, t, substeps, s0)
