"""The learned fields as benchmark ``Model`` objects: one wrapper per field kind.

``field_model`` picks the wrapper once, by the field's declared kind (``lfd.field.by_kind``):

- ``FieldModel`` (``FieldKind.AUTONOMOUS``: node, contraction): accurate rollouts solve
  dx_n/dt = f_n(x_n) in normalised units with torchdiffeq's adaptive dopri5 (rtol = atol = ``TOL``),
  all starts in one batch, with outputs at the requested times (dense output). If dopri5 fails
  (a step underflow on a blow-up, or more than ``MAX_STEPS`` steps) the batch is redone with
  fixed-step rk4 (``rollouts``: a ``FALLBACK_SUBSTEPS``-th of the output grid's step; reproductions
  on several clocks: the demos' mean sample interval); ``integrators`` records which solver ran.
- ``PhaseFieldModel`` (``FieldKind.PHASED``: tracking): (x, s) integrated jointly from the initial
  phase with fixed-step RK4 (the phase stops at 1, a kink adaptive steps dislike), on the output
  grid, or at the demos' mean sample interval for reproductions on several clocks.

The model works in its suite's states; the field in its own coordinates (positions, or the chart
points of a pose field); ``Coordinates`` (a ``lfd.bench.spaces.Space``) maps between them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, cast

import numpy as np
import torch

from lfd import evaluation, integrate
from lfd.bench.model import Model, time_per_call
from lfd.demos import DemoSet
from lfd.equilibria import equilibria_summary
from lfd.field import FieldKind, PhasedField, VelocityField, by_kind
from lfd.threads import torch_threads

#: history entries a record keeps
HISTORY_KEYS = ("iterations", "best_loss", "interrupted", "epochs", "train_cpu_s")
#: the phase at which ``PhaseFieldModel.batch_step`` evaluates a batch
BATCH_PHASE = 0.3
#: the control period of ``control_step``, s (500 Hz)
CONTROL_DT = 0.002


class Coordinates(Protocol):
    """Between a suite's states, shape (..., D), and a field's points, shape (..., d)."""

    def to_field(self, field: VelocityField, x: np.ndarray) -> np.ndarray:
        """The field's points of the states x."""
        ...

    def from_field(self, field: VelocityField, z: np.ndarray) -> np.ndarray:
        """The states of the field's points z (NaN for a non-finite point)."""
        ...

    def state_velocity(self, field: VelocityField) -> Callable[[np.ndarray], np.ndarray]:
        """A state (D,) in, the task's velocity out (a position field: dx/dt; a pose field: its twist)."""
        ...


class FieldModel(Model):
    """A ``FieldKind.AUTONOMOUS`` field as a benchmark ``Model`` (module docstring).

    Parameters
    ----------
    field : VelocityField
        The trained field.
    coords : Coordinates
        Its suite's states (``lfd.bench.spaces.POSITIONS`` or ``POSES``).
    """

    TOL = 1e-6
    MAX_STEPS = 2_000
    FALLBACK_SUBSTEPS = 4

    def __init__(self, field: VelocityField, coords: Coordinates) -> None:
        self.field = field
        self.coords = coords
        self.learner = field.learner
        self.config = dict(field.config)
        self.history = {k: v for k, v in field.history.items() if k in HISTORY_KEYS}
        self.train_time_s = float(field.history.get("train_time_s", float("nan")))
        self.integrators: dict[str, str] = {}

    def _solve(self, z0: np.ndarray, t: np.ndarray, what: str, step: float) -> np.ndarray:
        """z(t) from z0, shape (B, d), at times t, shape (n,) (t[0] = 0): shape (B, n, d), field
        coordinates. ``lfd.integrate.solve`` in normalised units: dopri5, then rk4 at ``step``."""
        norm, module = self.field.norm, self.field.module
        zn0 = torch.tensor(norm.to_norm(z0))
        tt = torch.tensor(np.asarray(t, dtype=np.float64))

        def f(_t: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
            return module(y)

        with torch.no_grad(), np.errstate(all="ignore"):
            try:
                yn = integrate.solve(f, zn0, tt, **integrate.odeint_kwargs(
                    "dopri5", rtol=self.TOL, atol=self.TOL, max_steps=self.MAX_STEPS))
                self.integrators[what] = "dopri5"
            except (AssertionError, RuntimeError):
                yn = integrate.solve(f, zn0, tt, **integrate.odeint_kwargs("rk4", step=step))
                self.integrators[what] = f"rk4 (step {step:.3g} s, dopri5 failed)"
            return norm.from_norm(yn.numpy()).transpose(1, 0, 2)

    def _grid_step(self, t: np.ndarray) -> float:
        """The rk4 step on the output grid t: a ``FALLBACK_SUBSTEPS``-th of its step."""
        return float(t[1] - t[0]) / self.FALLBACK_SUBSTEPS

    def _to(self, x: np.ndarray) -> np.ndarray:
        return self.coords.to_field(self.field, np.asarray(x, dtype=np.float64))

    def _from(self, z: np.ndarray) -> np.ndarray:
        return self.coords.from_field(self.field, z)

    def reproduce(self, x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Demos on one clock in one batch on it (as ``rollouts``); demos on several clocks in
        one batch on the union of their times, each read at its own."""
        rel = t - t[:, :1]
        z0 = self._to(x[:, 0])
        if (rel == rel[0]).all():
            z = self._solve(z0, rel[0], "reproduce", self._grid_step(rel[0]))
        else:
            union = np.unique(rel.ravel())
            z_all = self._solve(z0, union, "reproduce", float(np.mean(np.diff(t, axis=1))))   # (N, U, d)
            idx = np.searchsorted(union, rel)                                                  # (N, T)
            z = np.stack([z_all[i, idx[i]] for i in range(len(x))])
        with np.errstate(all="ignore"):
            return self._from(z), self.field(self._to(x))

    def rollouts(self, x0: np.ndarray, t: np.ndarray, label: str = "rollouts") -> np.ndarray:
        return self._from(self._solve(self._to(x0), t, label, self._grid_step(t)))

    def toward(self, end: np.ndarray) -> Model:
        return type(self)(self.field.toward(end), self.coords)

    def step_time_us(self, points: np.ndarray, calls: int) -> float:
        f = self.field.single_point_evaluator()
        return time_per_call(f, [(np.array(p),) for p in self._to(points[:calls])])

    def state_step_time_us(self, points: np.ndarray, calls: int) -> float:
        f = self.coords.state_velocity(self.field)
        return time_per_call(f, [(np.array(p),) for p in points[:calls]])

    def equilibria(self, demos: DemoSet) -> dict[str, Any] | None:
        """``lfd.equilibria.equilibria_summary`` of the field on its training demos, on one thread."""
        with torch_threads(1):
            return equilibria_summary(self.field, demos)

    def velocities(self, points: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            return self.field(self._to(points))

    def batch_step(self, points: np.ndarray) -> np.ndarray:
        return self.field(self._to(points))

    def simulate(self, x0: np.ndarray, t: np.ndarray, kick_at: int | None = None,
                 kicks: np.ndarray | None = None) -> np.ndarray:
        """The field's own RK4 (``VelocityField.rollout``, Eq. (8)) on the grid; a kick restarts
        it from the kicked state."""
        z0 = self._to(np.atleast_2d(x0))
        with np.errstate(all="ignore"):
            if kick_at is None:
                return self._from(self.field.rollout(z0, t, method="rk4"))
            a = self.field.rollout(z0, t[:kick_at + 1], method="rk4")
            b = self.field.rollout(a[:, -1] + self._kick(kicks), t[kick_at:], method="rk4")
            return self._from(np.concatenate([a, b[:, 1:]], axis=1))

    def _kick(self, kicks: np.ndarray | None) -> np.ndarray:
        return np.zeros(1) if kicks is None else np.asarray(kicks, dtype=np.float64)

    def simulate_demos(self, demos: DemoSet) -> np.ndarray:
        """``lfd.evaluation.reproduce`` (RK4 at each demo's sample interval), demos in the field's
        coordinates."""
        return evaluation.reproduce(self.field, demos)

    def control_step(self, x0: np.ndarray) -> Callable[[np.ndarray], Any]:
        """One call of the field's runner from x0 (``Field.runner``), at ``CONTROL_DT``."""
        runner = self.field.runner(self._to(x0), CONTROL_DT)
        return lambda x: runner(x, 0.0)


class _PhaseVelocity(Protocol):
    def velocity(self, x: np.ndarray, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        ...


class PhaseFieldModel(FieldModel):
    """A ``FieldKind.PHASED`` field (``lfd.learners.tracking``) as a benchmark ``Model``: its runs
    integrate (x, s) jointly from the initial phase with fixed-step RK4 (module docstring)."""

    def __init__(self, field: VelocityField, coords: Coordinates) -> None:
        super().__init__(field, coords)
        self.phased = cast(PhasedField, field)

    def _grid_step(self, t: np.ndarray) -> float:
        """The output grid's own step."""
        return float(t[1] - t[0])

    def _solve(self, z0: np.ndarray, t: np.ndarray, what: str, step: float) -> np.ndarray:
        self.integrators[what] = f"rk4 on (x, s), step {step:.3g} s"
        with np.errstate(all="ignore"):
            return self.phased.rollout_with_phase(z0, t, method="rk4", step=step)[0]

    def batch_step(self, points: np.ndarray) -> np.ndarray:
        """dx/dt of Eq. (T3) at phase ``BATCH_PHASE``, every point at once."""
        x = self._to(points)
        return cast(_PhaseVelocity, self.field).velocity(x, np.full(len(x), BATCH_PHASE))[0]

    def phase_error(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """|x - r(s | x0)| along each run, Eq. (T5)'s in-phase error."""
        z0 = self._to(x0)
        xs, ss = self.phased.rollout_with_phase(z0, t)
        return np.stack([np.linalg.norm(x - self.phased.reference(s, p), axis=-1) for x, s, p in zip(xs, ss, z0)])

    def simulate(self, x0: np.ndarray, t: np.ndarray, kick_at: int | None = None,
                 kicks: np.ndarray | None = None) -> np.ndarray:
        """RK4 of (x, s) on the grid (Eqs. (T3)-(T4)); a kick moves x and keeps the phase."""
        if kick_at is None:
            return super().simulate(x0, t)
        z0 = self._to(np.atleast_2d(x0))
        with np.errstate(all="ignore"):
            a, s = self.phased.rollout_with_phase(z0, t[:kick_at + 1])
            b, _ = self.phased.rollout_with_phase(a[:, -1] + self._kick(kicks), t[kick_at:], s0=s[:, -1], start=z0)
            return self._from(np.concatenate([a, b[:, 1:]], axis=1))


def field_model(field: VelocityField, coords: Coordinates) -> FieldModel:
    """The wrapper of ``field``'s kind (module docstring)."""
    wrapper: type[FieldModel] = by_kind(field, {FieldKind.AUTONOMOUS: FieldModel, FieldKind.PHASED: PhaseFieldModel})
    return wrapper(field, coords)
