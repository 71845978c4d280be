"""The states a suite scores its learners in, and its learners fitted there: positions or poses.

A suite picks its space once and passes it down (``lfd.bench.suite``):

- ``POSITIONS``: a state is a position x, shape (d,), task units; the baseline is the position DMP;
- ``POSES``: a state is a pose (x, y, z, qw, qx, qy, qz), shape (7,), metres and a unit quaternion;
  a field learner learns it on the chart points of ``lfd.pose`` (``lfd.train`` on a pose set), so
  the field's declared chart (``field.chart``) maps states to its points and back, Eqs. (P1)-(P2);
  the baseline is the Cartesian DMP.

``fit`` trains any learner of ``bench_learners()`` (the registry's and ``dmp``) in a space and wraps
it as a ``lfd.bench.model.Model``; ``resolve_config`` gives its full options.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, cast

import numpy as np

from lfd.bench import dmp
from lfd.bench.fields import field_model
from lfd.bench.model import Model
from lfd.demos import DemoSet
from lfd.field import VelocityField, cached_single_point_evaluator
from lfd.fingerprint import code_fingerprint
from lfd.learners import LEARNERS, get_learner, learner_module, train
from lfd.pose import PoseChart

#: the baseline's name beside the registry's learners
DMP = "dmp"


def bench_learners() -> tuple[str, ...]:
    """Every learner the benchmarks score: ``lfd.learners.LEARNERS``, then ``dmp``."""
    return (*LEARNERS, DMP)


def learner_code(learner: str) -> str:
    """The fingerprint of a bench learner's code (``lfd.fingerprint``): its module and all it imports."""
    return code_fingerprint(dmp.__name__ if learner == DMP else learner_module(learner))


class Space(ABC):
    """A suite's states (module docstring): what they are of a demo set, and how a field meets them."""

    name: str

    @abstractmethod
    def states(self, demos: DemoSet) -> np.ndarray:
        """The demos' states, shape (N, T, D)."""

    @abstractmethod
    def goal(self, demos: DemoSet) -> np.ndarray:
        """The demos' common goal, shape (D,)."""

    def ends(self, demos: DemoSet) -> np.ndarray:
        """Each demo's own last state, shape (N, D)."""
        return self.states(demos)[:, -1]

    @abstractmethod
    def to_field(self, field: VelocityField, x: np.ndarray) -> np.ndarray:
        """The field's points of states x, shape (..., D) -> (..., d)."""

    @abstractmethod
    def from_field(self, field: VelocityField, z: np.ndarray) -> np.ndarray:
        """The states of the field's points z, shape (..., d) -> (..., D); NaN for a non-finite point."""

    @abstractmethod
    def state_velocity(self, field: VelocityField) -> Callable[[np.ndarray], np.ndarray]:
        """A state (D,) in, the task's velocity out."""

    @abstractmethod
    def fit_dmp(self, demos: DemoSet, options: dict[str, Any]) -> Model:
        """The DMP baseline fitted to ``demos``."""

    @abstractmethod
    def dmp_config(self, options: dict[str, Any]) -> dict[str, Any]:
        """The baseline's full options (ConfigError if invalid)."""


class Positions(Space):
    """A state is a position (the demos' ``x``); fields take it as it is."""

    name = "positions"

    def states(self, demos: DemoSet) -> np.ndarray:
        return demos.x

    def goal(self, demos: DemoSet) -> np.ndarray:
        return demos.goal

    def to_field(self, field: VelocityField, x: np.ndarray) -> np.ndarray:
        return x

    def from_field(self, field: VelocityField, z: np.ndarray) -> np.ndarray:
        return z

    def state_velocity(self, field: VelocityField) -> Callable[[np.ndarray], np.ndarray]:
        return cached_single_point_evaluator(field)

    def fit_dmp(self, demos: DemoSet, options: dict[str, Any]) -> Model:
        return dmp.fit_dmp(demos, **options)

    def dmp_config(self, options: dict[str, Any]) -> dict[str, Any]:
        return dataclasses.asdict(dmp.make_config(**options))


class Poses(Space):
    """A state is a pose (x, y, z, qw, qx, qy, qz); a field takes its chart point (Eq. (P1))."""

    name = "poses"

    def states(self, demos: DemoSet) -> np.ndarray:
        return np.concatenate([demos.x, self._q(demos.q)], axis=-1)

    def goal(self, demos: DemoSet) -> np.ndarray:
        return np.concatenate([demos.goal, self._q(demos.goal_q)])

    @staticmethod
    def _q(q: np.ndarray | None) -> np.ndarray:
        if q is None:
            raise ValueError("a pose suite needs demos of poses")
        return q

    @staticmethod
    def _chart(field: VelocityField) -> PoseChart:
        return cast(PoseChart, field.chart)   # a field trained on poses declares its chart

    def to_field(self, field: VelocityField, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return self._chart(field).to_chart(x[..., :3], x[..., 3:])

    def from_field(self, field: VelocityField, z: np.ndarray) -> np.ndarray:
        """Eq. (P2) of every finite point; NaN states elsewhere (a diverged rollout)."""
        flat = np.asarray(z, dtype=np.float64).reshape(-1, 6)
        ok = np.isfinite(flat).all(axis=1)
        out = np.full((len(flat), 7), np.nan)
        if ok.any():
            x, q = self._chart(field).from_chart(flat[ok])
            out[ok] = np.concatenate([x, q], axis=1)
        return out.reshape(np.shape(z)[:-1] + (7,))

    def state_velocity(self, field: VelocityField) -> Callable[[np.ndarray], np.ndarray]:
        """The twist (v, omega), shape (6,), at a pose (``VelocityField.pose_velocity``, Eq. (P3))."""
        return lambda s: field.pose_velocity(s[:3], s[3:])

    def fit_dmp(self, demos: DemoSet, options: dict[str, Any]) -> Model:
        return dmp.fit_cartesian_dmp(demos, **options)

    def dmp_config(self, options: dict[str, Any]) -> dict[str, Any]:
        return dataclasses.asdict(dmp.make_cartesian_config(**options))


POSITIONS = Positions()
POSES = Poses()


def fit(learner: str, demos: DemoSet, seed: int, options: dict[str, Any], space: Space = POSITIONS) -> Model:
    """Train ``learner`` (``dmp`` or a registered field learner) on ``demos`` with ``seed`` and
    ``options`` (``lfd.train``'s keyword options), as a model on ``space``'s states."""
    if learner == DMP:
        return space.fit_dmp(demos, options)
    field = train(learner, demos, seed=seed, progress=False, **options)
    return field_model(field, space)


def resolve_config(learner: str, options: dict[str, Any], space: Space = POSITIONS) -> dict[str, Any]:
    """The learner's full config for ``options`` (defaults filled in); ConfigError if invalid."""
    if learner == DMP:
        return space.dmp_config(options)
    return dataclasses.asdict(get_learner(learner).make_config(**options))
