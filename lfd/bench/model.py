"""What the benchmarks ask of a trained learner: the ``Model`` interface.

Every learner the benchmarks score is wrapped as a ``Model``: the registered field learners
(``lfd.bench.fields``: one wrapper per field kind, chosen once by ``lfd.field.by_kind``) and the
DMP baselines (``lfd.bench.dmp``, position and Cartesian). A model works on states of its suite's
space (``lfd.bench.spaces``): positions x (d,), or poses (x, y, z, qw, qx, qy, qz) (7,). Two ways
of running it:

- accurate (``reproduce``, ``rollouts``): what the LASA and RoboTasks9 suites score;
- fixed-step (``simulate``, ``simulate_demos``, ``control_step``): RK4 on a given grid, as a
  control loop would run it (the spiral comparison, ``lfd.bench.comparison``).

``toward(end)`` is the same learned motion run toward another end (the held-out split).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np

from lfd.demos import DemoSet

TIMING_REPEATS = 5
WARM_CALLS = 20


def time_per_call(fn: Callable[..., Any], calls: Sequence[tuple[Any, ...]]) -> float:
    """Median over ``TIMING_REPEATS`` of the mean time of one call ``fn(*args)`` over ``calls``,
    in microseconds (the first ``WARM_CALLS`` calls run once before, untimed)."""
    for args in calls[:WARM_CALLS]:
        fn(*args)
    per_call = []
    for _ in range(TIMING_REPEATS):
        t0 = time.perf_counter()
        for args in calls:
            fn(*args)
        per_call.append((time.perf_counter() - t0) / len(calls))
    return float(np.median(per_call) * 1e6)


class Model(ABC):
    """A trained learner as the benchmarks see it (module docstring).

    Attributes
    ----------
    learner : str
        ``dmp`` or a name of ``lfd.learners.LEARNERS``.
    config : dict
        Its resolved options (JSON values).
    history : dict
        What training recorded that the records keep (iterations, loss, times; empty for a DMP).
    train_time_s : float
        The learner's own training time, s.
    integrators : dict of str
        The solver each kind of run used (``reproduce``, ``rollouts``, ...), filled as they run.
    autonomous : bool
        Whether a rollout from any start is evidence of the learned motion (a field: True; the
        time-indexed DMP reaches its goal by construction: False).
    """

    learner: str
    config: dict[str, Any]
    history: dict[str, Any]
    train_time_s: float
    integrators: dict[str, str]
    autonomous: ClassVar[bool] = True

    @abstractmethod
    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each demo's reproduction from its start on its own clock.

        Parameters
        ----------
        x : array, shape (N, T, D)
            The demos' states.
        t : array, shape (N, T)
            Their times, s.

        Returns
        -------
        y : array, shape (N, T, D)
            The reproductions (non-finite where one diverged).
        v : array, shape (N, T, V)
            The model's velocities to compare with the demos': a field's f at the demos' states,
            the DMP's along its reproduction.
        """

    @abstractmethod
    def rollouts(self, x0: np.ndarray, t: np.ndarray, label: str = "rollouts") -> np.ndarray:
        """Rollouts from starts x0, shape (B, D), over the uniform grid t, shape (n,) from 0:
        shape (B, n, D); the solver is recorded in ``integrators[label]``."""

    @abstractmethod
    def toward(self, end: np.ndarray) -> Model:
        """The same learned motion run toward ``end``, shape (D,), a state (a field's
        ``toward``; the DMP's goal)."""

    @abstractmethod
    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        """Median microseconds of one evaluation of the model's own step (a field: its
        single-point evaluator in its own coordinates; a DMP: one step), over the first ``calls``
        of ``points``, shape (P, D)."""

    def state_step_time_us(self, points: np.ndarray, calls: int) -> float:
        """The same for a state in and the task's velocity out (a pose field: a pose in, a twist
        out); by default ``step_time_us``."""
        return self.step_time_us(points, calls)

    def velocities(self, points: np.ndarray) -> np.ndarray | None:
        """The velocity field at points, shape (..., D) (for streamlines), or None (a DMP)."""
        return None

    def equilibria(self, demos: DemoSet) -> dict[str, Any] | None:
        """The search for equilibria and closed orbits other than the goal in the demos' box grown by
        half (``lfd.equilibria.equilibria_summary``), for the model trained on ``demos``; None for a
        model without an autonomous field (the DMP reaches its goal by construction)."""
        return None

    def batch_step(self, points: np.ndarray) -> np.ndarray | None:
        """One batched evaluation of the model's step at points, shape (B, D), as a loop would
        call it, or None (a DMP steps one state at a time)."""
        return None

    def phase_error(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """The distance to the run's own reference along rollouts from x0, shape (B, D), over t,
        shape (n,): shape (B, n); None for a model without a phase."""
        return None

    @abstractmethod
    def simulate(self, x0: np.ndarray, t: np.ndarray, kick_at: int | None = None,
                 kicks: np.ndarray | None = None) -> np.ndarray:
        """Fixed-step runs from starts x0, shape (B, D), over the uniform grid t, shape (n,), with
        ``kicks``, shape (B, D), added to the state at sample ``kick_at``: shape (B, n, D)."""

    @abstractmethod
    def simulate_demos(self, demos: DemoSet) -> np.ndarray:
        """Each demo's fixed-step run from its start on its own clock, shape (N, T, D)."""

    @abstractmethod
    def control_step(self, x0: np.ndarray) -> Callable[[np.ndarray], Any]:
        """The function a control loop calls once per step for the run from x0, shape (D,)."""
