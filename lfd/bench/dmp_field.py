"""The DMP baseline as a field the arm can run: a DMP's rollout from the run's start, tracked.

A DMP is time-indexed: its canonical system, not the state, says where along the motion it is. Robots
run one the way this field does: the DMP (``lfd.bench.dmp.fit_dmp``, ``movement_primitives.dmp.DMP``,
fitted to the demos' mean) is integrated once from the run's start at rest, with tau the demos' mean
duration, on a grid of ``REFERENCE_DT``; the commanded velocity is the rollout's velocity plus a
proportional pull toward it (``FieldKind.TIME_VARYING``):

    v(x, t) = yd(t) + k (y(t) - x),       k = ``GAIN`` 1/s,

with y and yd linear in t between grid points, and y(t) = g, yd = 0 after the rollout's end (the DMP
has settled at the goal g). A pushed run returns to the rollout at rate k and never waits for it: the
DMP's clock runs on. Poses run in the chart of Eq. (P1) (``lfd.pose``): the DMP is fitted to the
demos' chart points z = (p, l log(R_g^T R)), a 6-D DMP; the benchmarks' CartesianDMP is the same
baseline on (p, q).

``dmp_field(demos)`` fits it (milliseconds; nothing is cached). It states no guarantee
(``stability_constants`` is None).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from lfd.bench.dmp import DMPModel, fit_dmp
from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.field import FieldKind, StateSpace
from lfd.pose import PoseChart, chart_demos
from lfd.runner import Runner, TimedRunner, timed_trajectory

__all__ = ["GAIN", "DMPField", "dmp_field"]

#: the pull toward the rollout, 1/s
GAIN = 10.0
#: the rollout's grid, s
REFERENCE_DT = 0.002


class DMPField:
    """The field of the module docstring: ``model`` fitted on the task points (positions, or chart
    points with ``chart``); ``start`` (d,) the default run's start (the demos' mean start);
    ``demo_box`` the demos' bounding box."""

    kind: ClassVar[FieldKind] = FieldKind.TIME_VARYING
    learner: ClassVar[str] = "dmp"

    def __init__(self, model: DMPModel, start: np.ndarray, chart: PoseChart | None = None,
                 demo_box: tuple[np.ndarray, np.ndarray] | None = None, gain: float = GAIN) -> None:
        self.model, self.chart, self.demo_box, self.gain = model, chart, demo_box, float(gain)
        self.start = np.asarray(start, dtype=np.float64).copy()
        self._refs: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def space(self) -> StateSpace:
        return StateSpace.POSE if self.chart is not None else StateSpace.POSITION

    @property
    def dim(self) -> int:
        return len(self.model.goal)

    @property
    def goal(self) -> np.ndarray:
        return np.asarray(self.model.goal, dtype=np.float64).copy()

    @property
    def duration(self) -> float:
        """tau: the demos' mean duration, s."""
        return float(self.model.duration)

    @property
    def history(self) -> dict[str, Any]:
        return {"train_time_s": self.model.train_time_s}

    @property
    def config(self) -> Any:
        return {**self.model.config, "gain": self.gain}

    def goal_at(self, t: float) -> np.ndarray:
        return self.goal

    def goal_samples(self) -> np.ndarray:
        return self.goal[None]

    def stability_constants(self) -> dict[str, Any] | None:
        return None

    def reference(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rollout from x0, shape (d,), at rest: y and yd, each (K, d), on the grid of
        ``REFERENCE_DT`` over tau (kept per start)."""
        key = tuple(np.round(np.asarray(x0, dtype=np.float64), 12).tolist())
        if key not in self._refs:
            n = int(math.ceil(self.duration / REFERENCE_DT)) + 1
            y, yd = self.model.run(np.asarray(x0, dtype=np.float64), self.duration, REFERENCE_DT, n)
            self._refs[key] = (np.ascontiguousarray(y), np.ascontiguousarray(yd))
        return self._refs[key]

    def command(self, x0: np.ndarray) -> Callable[[np.ndarray, float], np.ndarray]:
        """v(x, t) of the run from x0, shape (d,) (module docstring): x (d,) -> (d,)."""
        y, yd = self.reference(x0)
        goal, gain, last = self.goal, self.gain, len(y) - 1

        def v(x: np.ndarray, t: float) -> np.ndarray:
            u = t / REFERENCE_DT
            if not u < last:   # settled (a NaN t lands here too, and gives NaN through x)
                return gain * (goal - x)
            k = int(u) if u > 0 else 0
            a = u - k if u > 0 else 0.0
            return (1 - a) * yd[k] + a * yd[k + 1] + gain * ((1 - a) * y[k] + a * y[k + 1] - x)
        return v

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        return TimedRunner(self.command(self.start if start is None else start), dt)

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        x0 = np.asarray(x0, dtype=np.float64)
        return timed_trajectory(self.command(x0), x0, np.asarray(t, dtype=np.float64), substeps)

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        return self.command(self.start)

    def __call__(self, x: np.ndarray, *args: Any) -> np.ndarray:
        fn, t = self.command(self.start), float(args[0]) if args else 0.0
        x = np.asarray(x, dtype=np.float64)
        return fn(x, t) if x.ndim == 1 else np.stack([fn(p, t) for p in x.reshape(-1, self.dim)]).reshape(x.shape)

    def toward(self, goal: np.ndarray) -> DMPField:
        """The same DMP toward ``goal``: the transformation system's goal parameter. A pose field takes
        a position (3,) (its orientation goal kept); positions take d values."""
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        new = self.goal
        if self.chart is None and g.shape == (self.dim,):
            new = g
        elif self.chart is not None and g.shape == (3,):
            new[:3] = g
        else:
            want = "x,y,z (its orientation goal is the demos')" if self.chart is not None else f"{self.dim} values"
            raise ConfigError(f"the DMP baseline's goal is {want}, got {g.shape[0]} values")
        if not np.isfinite(new).all():
            raise ConfigError(f"the goal must be finite, got {g.tolist()}")
        shift = new - self.goal
        box = None if self.demo_box is None else (self.demo_box[0] + shift, self.demo_box[1] + shift)
        return DMPField(DMPModel.toward(self.model, new), self.start + shift, self.chart, box, self.gain)  # type: ignore[arg-type]

    def __repr__(self) -> str:
        return f"DMPField(dim={self.dim}, tau={self.duration:.2f} s, gain={self.gain:g}/s)"


def dmp_field(demos: DemoSet, gain: float = GAIN, **options: Any) -> DMPField:
    """The DMP baseline of ``demos`` (positions, or poses in their chart) as a field (module docstring);
    ``options`` are ``lfd.bench.dmp.DMPConfig``'s."""
    chart = PoseChart.of(demos) if demos.has_orientation else None
    points = chart_demos(demos, chart) if chart is not None else demos
    model = fit_dmp(points, **options)
    box = (points.x.reshape(-1, points.dim).min(0), points.x.reshape(-1, points.dim).max(0))
    return DMPField(model, points.x[:, 0].mean(axis=0), chart, box, gain)
