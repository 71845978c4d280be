"""The velocity-field interface shared by every learner, and the declaration of a field's kind.

A learned field is dx/dt = f(x): the paper's system without noise, Eq. (2), autonomous as its
Eqs. (10) and (15). Internally a torch module computes the normalised field f_n(x_n) (see
``lfd.normalization``); in user units f(x) = s f_n((x - goal) / s). Rollouts solve the paper's
Eq. (5) through ``lfd.integrate``.

Every field declares what it is, and code asks the declaration (``Field.kind``, ``Field.space``),
never the field's attributes:

- ``FieldKind.AUTONOMOUS``: f(x), the learners' fields (``VelocityField``);
- ``FieldKind.TIME_VARYING``: f(x, t), called with the time [s] as its second argument (a moving
  goal, ``lfd.goal``; an obstacle-avoiding field, ``lfd.obstacles``);
- ``FieldKind.PHASED``: (dx/dt, ds/dt) = f(x, s) with a phase s in [0, 1] carried beside x (the
  tracking learner, ``lfd.learners.tracking``, and obstacles around it,
  ``lfd.obstacles.PhasedAvoidingField``; ``PhasedField``).

``StateSpace.POSITION`` is R^d, positions only. ``StateSpace.POSE`` is position and orientation,
R^3 x SO(3), learned in the log chart at the goal orientation (``lfd.pose``, Eqs. (P1)-(P4) of
docs/equations.md): such a field is the same learner's field on the chart's R^6, and carries its
``PoseChart`` (``Field.chart``). Its x are chart points z = (p, l log(R_g^T R)) and its output
z_dot; ``pose_velocity`` turns a pose into the linear and angular velocity, Eq. (P3).
"""

from __future__ import annotations

import enum
import os
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar, Protocol, TypeGuard

import numpy as np
import torch
from torch import Tensor

from lfd import integrate
from lfd.errors import ConfigError
from lfd.guarantees import Guarantees
from lfd.normalization import Normalization
from lfd.pose import PoseChart
from lfd.runner import (
    PhaseRunner,
    PointRunner,
    Runner,
    TimedRunner,
    phase_trajectory,
    point_trajectory,
    timed_trajectory,
)
from lfd.threads import torch_threads

#: batches of up to this many points are evaluated point by point (``VelocityField.__call__``)
SMALL_BATCH = 8


class FieldKind(enum.Enum):
    """What a field's evaluator takes besides the state x (module docstring)."""

    AUTONOMOUS = "autonomous"
    TIME_VARYING = "time_varying"
    PHASED = "phased"


class StateSpace(enum.Enum):
    """The space a field's state x lives in."""

    POSITION = "position"   #: R^d, task units
    POSE = "pose"           #: R^3 x SO(3), as chart points of R^6 (``lfd.pose``)


class Field(Protocol):
    """What every field offers, whatever its kind: sim, the benchmark and the scripts use only this.

    ``single_point_evaluator()`` returns the per-point function the control loop calls:
    ``fn(x)`` for ``FieldKind.AUTONOMOUS``, ``fn(x, t)`` for ``FieldKind.TIME_VARYING``; a
    ``FieldKind.PHASED`` field's loop goes through ``PhasedField.phase_point_fn`` instead, and its
    ``single_point_evaluator`` is its autonomous view (the phase of the nearest reference point).
    """

    @property
    def kind(self) -> FieldKind:
        """What the evaluator takes besides x."""
        ...

    @property
    def space(self) -> StateSpace:
        """The space x lives in."""
        ...

    @property
    def dim(self) -> int:
        """The task dimension d."""
        ...

    @property
    def goal(self) -> np.ndarray:
        """The attractor at t = 0, shape (d,), task units."""
        ...

    @property
    def learner(self) -> str:
        """The learner's registry name (``node``, ``contraction``, ``tracking``, ...)."""
        ...

    @property
    def history(self) -> dict[str, Any]:
        """The training record (``loss``, ``train_time_s``, ...); empty for a hand-built field."""
        ...

    @property
    def config(self) -> Any:
        """The learner's options (a JSON-able dict), or None."""
        ...

    @property
    def demo_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lo, hi), each shape (d,): the training demos' bounding box, or None."""
        ...

    @property
    def chart(self) -> PoseChart | None:
        """The orientation chart of a ``StateSpace.POSE`` field (None on positions)."""
        ...

    def goal_at(self, t: float) -> np.ndarray:
        """The goal at time t [s], shape (d,)."""
        ...

    def goal_samples(self) -> np.ndarray:
        """Every place the goal visits, shape (G, d) (one row for a fixed goal)."""
        ...

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast per-point function (see the class docstring)."""
        ...

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        """The run from ``start``, shape (d,), stepped every ``dt`` s (``lfd.runner``)."""
        ...

    def toward(self, goal: np.ndarray) -> Any:
        """The same learned motion toward another goal (``VelocityField.toward``)."""
        ...

    def stability_constants(self) -> dict[str, Any] | None:
        """The constants of a Lyapunov function the field states (``lfd.guarantees.Guarantees``), or None."""

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        """Single-start RK4 (Eq. (8)) from x0, shape (d,), over t, shape (T,): x (T, d) and the
        phase (T,) of a field that has one, else None."""
        ...

    def __call__(self, x: np.ndarray, *args: Any) -> np.ndarray:
        """dx/dt at x, shape (..., d) (and the time t [s] for ``FieldKind.TIME_VARYING``)."""
        ...


class PhasedField(Field, Protocol):
    """A ``FieldKind.PHASED`` field: x and its phase s in [0, 1] evolve together (Eq. (T3) of
    docs/equations.md), s advancing at the demos' pace and waiting when x is held back."""

    @property
    def duration(self) -> float:
        """The demos' duration T, s: ds/dt = 1 / T on the reference."""
        ...

    def phase_point_fn(self, x0: np.ndarray | None = None, clock_weight: Callable[[np.ndarray], float] | None = None
                       ) -> Callable[[np.ndarray, float], tuple[np.ndarray, float]]:
        """(x, s) -> (dx/dt, ds/dt) for one point, conditioned on the start x0, shape (d,);
        ``clock_weight`` (x (d,) -> omega in [0, 1]) blends the phase's waiting toward the clock,
        Eq. (T4b) of docs/equations.md (None: Eq. (T4) as is)."""
        ...

    def reference(self, s: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """The reference r(s), shape s.shape + (d,), conditioned on the start x0."""
        ...

    def rollout_with_phase(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                           s0: np.ndarray | float = 0.0, start: np.ndarray | None = None,
                           step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Integrate (x, s) from x0, shape (B, d), and phase s0 over t, shape (T,): x of shape
        (B, T, d) and s of shape (B, T)."""
        ...


def is_phased(field: Field) -> TypeGuard[PhasedField]:
    """Whether ``field`` declares ``FieldKind.PHASED`` (narrows it to ``PhasedField``)."""
    return field.kind is FieldKind.PHASED


class PhasedRuns:
    """The runs of a ``FieldKind.PHASED`` field (mixed into ``lfd.learners.tracking.TrackingField``
    and ``lfd.obstacles.PhasedAvoidingField``): (x, s) of Eqs. (T3)-(T4), from its
    ``phase_point_fn``, ``initial_phase``, ``reference`` and ``duration``."""

    kind: ClassVar[FieldKind] = FieldKind.PHASED

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        """A ``lfd.runner.PhaseRunner`` conditioned on ``start``, shape (d,)."""
        me: Any = self
        start_c = None if start is None else np.asarray(start, dtype=np.float64).copy()
        return PhaseRunner(me.phase_point_fn(start_c), dt, float(me.initial_phase()),
                           lambda s: me.reference(s, start_c), float(me.duration))

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        """RK4 of (x, s) from x0, shape (d,), and the initial phase over t, shape (T,)."""
        me: Any = self
        x0 = np.asarray(x0, dtype=np.float64)
        return phase_trajectory(me.phase_point_fn(x0), x0, t, substeps, float(me.initial_phase()))


def cached_single_point_evaluator(field: Any) -> Callable[..., np.ndarray]:
    """``field.single_point_evaluator()``, built on first use and kept on the field.

    ``field(x)`` on one point, x of shape (d,), dispatches to it.
    """
    fn = field.__dict__.get("_point")
    if fn is None:
        fn = field.__dict__["_point"] = field.single_point_evaluator()
    return fn


class VelocityField(Guarantees):
    """A learned autonomous velocity field x -> dx/dt (``FieldKind.AUTONOMOUS`` on positions).

    Parameters
    ----------
    module : torch.nn.Module
        Maps normalised x_n, shape (B, d), to dx_n/dt, shape (B, d).
    norm : Normalization
        Between user units and the unit box.
    learner : str
        Registry name of the learner that made it (``node``, ``contraction``, ``tracking``).
    config : dict
        The learner's options (plain JSON-able dict).
    history : dict, optional
        Training record (``loss`` list, ``train_time_s``, ...).
    demo_box : pair of arrays, each shape (d,), optional
        (lo, hi), the bounding box of the training demos, user units; None when unknown (a field
        built by hand). ``lfd certify`` and ``lfd export --format npz-grid`` default to it, grown.
    chart : PoseChart, optional
        The orientation chart of a pose field (then d = 6: x are chart points, module docstring).
    """

    kind: ClassVar[FieldKind] = FieldKind.AUTONOMOUS

    def __init__(self, module: torch.nn.Module, norm: Normalization, learner: str,
                 config: dict[str, Any], history: dict[str, Any] | None = None,
                 demo_box: tuple[np.ndarray, np.ndarray] | None = None, chart: PoseChart | None = None) -> None:
        self.chart = chart
        self.module = module.double().eval()
        self.norm = norm
        self.learner = learner
        self.config = dict(config)
        self.history = dict(history or {})
        self.demo_box: tuple[np.ndarray, np.ndarray] | None = None
        if demo_box is not None:
            lo, hi = (np.asarray(c, dtype=np.float64).copy() for c in demo_box)
            if lo.shape != (self.dim,) or hi.shape != (self.dim,):
                raise ValueError(f"demo_box must be two corners of shape ({self.dim},), "
                                 f"got {lo.shape} and {hi.shape}")
            self.demo_box = (lo, hi)
        for p in self.module.parameters():
            p.requires_grad_(False)
        if chart is not None and self.dim != 6:
            raise ValueError(f"a pose field has 6 chart coordinates, got d={self.dim}")

    @property
    def space(self) -> StateSpace:
        """``StateSpace.POSE`` with a chart, else ``StateSpace.POSITION``."""
        return StateSpace.POSITION if self.chart is None else StateSpace.POSE

    def toward(self, goal: np.ndarray) -> VelocityField:
        """The same learned motion, run toward ``goal`` instead of the demos' mean end.

        The field is learned relative to its goal (f(x) = s f_n((x - g) / s), ``lfd.normalization``),
        so moving the goal moves the whole motion with it: positions by translation, and a pose
        field's orientations by its chart moved to the new goal orientation (Eq. (P1) at R_g').
        Every constant of the field (a rate, metric bounds, a Lipschitz bound, a Lyapunov function's
        constants) is the same for any goal.

        Parameters
        ----------
        goal : array, shape (d,)
            The new goal, task units; a pose field takes the position (3,) or the pose (7,),
            x, y, z, qw, qx, qy, qz (the orientation unchanged when only the position is given).

        Returns
        -------
        VelocityField
            A field of the same class and learner, sharing this one's weights.
        """
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        chart = self.chart
        new_goal = self.norm.goal.copy()
        if chart is None:
            if g.shape != (self.dim,):
                raise ConfigError(f"the goal must have {self.dim} coordinates, got {g.shape[0]}")
            new_goal = g
        else:
            if g.shape not in ((3,), (7,)):
                raise ConfigError(f"a pose goal is x,y,z or x,y,z,qw,qx,qy,qz, got {g.shape[0]} values")
            new_goal[:3] = g[:3]
            if g.shape == (7,):
                q = g[3:]
                norm = float(np.linalg.norm(q))
                if not (np.isfinite(q).all() and abs(norm - 1.0) <= 0.01):
                    raise ConfigError(f"the goal's quaternion must be a unit quaternion (w, x, y, z), got {q.tolist()}")
                chart = PoseChart.at(q / norm, chart.length)
        if not np.isfinite(new_goal).all():
            raise ConfigError(f"the goal must be finite, got {g.tolist()}")
        box = None
        if self.demo_box is not None:
            shift = new_goal - self.norm.goal
            if chart is not None:   # the chart's rotation coordinates stay those of the new chart
                shift[3:] = 0.0
            box = (self.demo_box[0] + shift, self.demo_box[1] + shift)
        return type(self)(self.module, Normalization(goal=new_goal, scale=self.norm.scale), self.learner,
                          self.config, self.history, demo_box=box, chart=chart)

    def pose_velocity(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The twist (v [m/s], omega [rad/s], world axes), shape (6,), of a pose field at the pose
        x (3,), q (4,) (w, x, y, z): Eq. (P1), the field, then Eq. (P3)."""
        if self.chart is None:
            raise ValueError("pose_velocity needs a pose field (a field trained on poses)")
        z = self.chart.point_of(x, q)
        return self.chart.twist(z, cached_single_point_evaluator(self)(z))

    @property
    def dim(self) -> int:
        return self.norm.dim

    @property
    def goal(self) -> np.ndarray:
        """The attractor, shape (d,), in user units."""
        return self.norm.goal

    def goal_at(self, t: float) -> np.ndarray:
        """The goal at time t [s], shape (d,): fixed, ``goal``."""
        return self.goal

    def goal_samples(self) -> np.ndarray:
        """The one place the goal is, shape (1, d)."""
        return self.goal[None, :]

    # ---- torch path (differentiable, batched, no numpy round trip)
    def torch(self, x: torch.Tensor) -> torch.Tensor:
        """f(x) in user units; x : tensor, shape (..., d), float64."""
        shape = x.shape
        xn = self.norm.to_norm_torch(x.reshape(-1, self.dim))
        return (self.module(xn) * self.norm.scale).reshape(shape)

    # annotations below say Tensor: inside the class body, ``torch`` is the method above
    def rollout_torch(self, x0: Tensor, t: Tensor, method: str = "rk4",
                      options: dict[str, Any] | None = None) -> Tensor:
        """Integrate from x0, shape (B, d), over t, shape (T,): returns (B, T, d) in user units.

        ``method`` and ``options`` as torchdiffeq's (built by ``lfd.integrate.odeint_kwargs``);
        the solve is ``lfd.integrate.solve`` in normalised units.
        """
        xn0 = self.norm.to_norm_torch(x0)
        yn = integrate.solve(lambda _t, y: self.module(y), xn0, t, method, options)
        return self.norm.from_norm_torch(yn).permute(1, 0, 2)

    # ---- numpy path
    def __call__(self, x: np.ndarray) -> np.ndarray:
        """dx/dt, same shape as x : array, shape (..., d), user units.

        One point, shape (d,), or up to ``SMALL_BATCH`` points take the single-point path
        (``single_point_evaluator``, built once per field); a larger batch takes the torch path.
        Both agree to 1e-12 relative.
        """
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"field expects points of dimension {self.dim}, got shape {x.shape}")
        if x.ndim == 1:
            return cached_single_point_evaluator(self)(x)
        if 0 < x.size <= SMALL_BATCH * self.dim:    # a few points: the single-point path is faster
            fn = cached_single_point_evaluator(self)
            return np.stack([fn(p) for p in x.reshape(-1, self.dim)]).reshape(x.shape)
        with torch.no_grad(), torch_threads(1):   # small batches: one thread is fastest (lfd.threads)
            return self.torch(torch.tensor(x)).numpy()

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4",
                substeps: int = 1) -> np.ndarray:
        """Integrate B starts at once (``lfd.integrate.rollout``): x0 (B, d) or (d,), user units, over
        t (T,), s, with ``method`` of ``lfd.integrate.SOLVERS``; fixed-step solvers take ``substeps``
        steps per interval of t (an adaptive solver refuses substeps > 1: ValueError). Returns x
        (B, T, d), or (T, d) for one start. ``rk4`` with one substep on at most
        ``lfd.integrate.POINTWISE_MAX`` starts runs each through the compiled single-point path."""
        xb = np.asarray(x0, dtype=np.float64)
        if method == "rk4" and substeps == 1 and 0 < len(np.atleast_2d(xb)) <= integrate.POINTWISE_MAX \
                and xb.shape[-1] == self.dim and np.ndim(t) == 1 and len(t) >= 1:
            fn = cached_single_point_evaluator(self)
            runs = np.stack([integrate.rk38_grid(fn, x, t) for x in np.atleast_2d(xb)])
            return runs[0] if xb.ndim == 1 else runs
        return integrate.rollout(self, x0, t, method, substeps)

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        """A ``lfd.runner.PointRunner`` of the single-point evaluator (``start`` is not needed)."""
        return PointRunner(cached_single_point_evaluator(self), dt)

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        """Single-start numpy RK4 (Eq. (8)) from x0, shape (d,), over t, shape (T,): (x (T, d), None)."""
        return point_trajectory(cached_single_point_evaluator(self), x0, t, substeps)

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """The fast path for one point, for control loops: ``field(x)`` on x of shape (d,) calls it.

        The default runs the torch module on the one point (a hand-built field); every learner's
        field overrides it with its compiled kernel (``lfd.learners.mlp_kernel``, ``flow_kernel``,
        ``stable_kernel``, ``tracking_kernel``), which must agree with the torch path to 1e-12.

        Returns
        -------
        callable
            x, array of shape (d,), user units -> dx/dt, array of shape (d,), user units; built
            on a snapshot of the weights.
        """
        module = self.module
        goal, s = self.norm.goal.copy(), float(self.norm.scale)

        def f(x: np.ndarray) -> np.ndarray:
            xn = (np.asarray(x, dtype=np.float64) - goal) / s
            with torch.no_grad():
                return module(torch.from_numpy(xn).reshape(1, -1))[0].numpy() * s

        return f

    def save(self, path: str | os.PathLike) -> None:
        """Write the model file atomically (see ``lfd.modelfile``)."""
        from lfd.modelfile import save_payload

        payload: dict[str, Any] = {
            "learner": self.learner,
            "dim": self.dim,
            "config": self.config,
            "normalization": self.norm.to_dict(),
            "state_dict": {k: v.detach().clone() for k, v in self.module.state_dict().items()},
            "history": self.history,
        }
        if self.demo_box is not None:
            payload["demo_box"] = [c.tolist() for c in self.demo_box]
        if self.chart is not None:
            payload["pose_chart"] = self.chart.to_dict()
        save_payload(payload, path)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(learner={self.learner!r}, dim={self.dim})"


class ContractingField(VelocityField, ABC):
    """A field that contracts by construction, with the analytic constants ``lfd.certify`` reports
    (``lfd.learners.contraction.ContractionField``, ``lfd.learners.tracking.TrackingField``).

    ``rate`` is the learner's ``rate`` option; a subclass gives ``metric_bounds`` (a, b) of its
    metric M and ``lipschitz_bound``; ``condition_bound`` b / a follows.
    """

    @property
    def rate(self) -> float:
        """The guaranteed contraction rate, 1/s (the same in user and normalised time)."""
        return float(self.config["rate"])

    @property
    @abstractmethod
    def metric_bounds(self) -> tuple[float, float]:
        """(a, b) with a I <= M(x) <= b I for every x in R^d, user units."""

    @property
    def condition_bound(self) -> float:
        """b / a of ``metric_bounds``, analytic: sqrt(b / a) is the overshoot constant of Eq. (18)
        (Eq. (C1) for the contraction learner, where b / a <= ``max_condition``)."""
        a, b = self.metric_bounds
        return b / a

    @property
    @abstractmethod
    def lipschitz_bound(self) -> float:
        """An upper bound of the field's Lipschitz constant in x, 1/s."""


def is_time_varying(field: Field) -> bool:
    """Whether ``field`` declares ``FieldKind.TIME_VARYING``: f(x, t), called with the time [s]."""
    return field.kind is FieldKind.TIME_VARYING


def goal_at(field: Field, t: float) -> np.ndarray:
    """The goal of ``field`` at time t [s], shape (d,) (``Field.goal_at``)."""
    return np.asarray(field.goal_at(t), dtype=np.float64)


class FieldWrapper:
    """Base of the fields that wrap another one (``lfd.goal.MovingGoalField``,
    ``lfd.obstacles.AvoidingField``): ``FieldKind.TIME_VARYING`` (a subclass may declare another
    kind: ``lfd.obstacles.PhasedAvoidingField``) on the wrapped ``field``'s space, with its
    dimension, learner name and training record."""

    kind: ClassVar[FieldKind] = FieldKind.TIME_VARYING
    field: Field

    @property
    def space(self) -> StateSpace:
        """The wrapped field's state space."""
        return self.field.space

    @property
    def dim(self) -> int:
        """The task dimension d."""
        return int(self.field.dim)

    @property
    def chart(self) -> PoseChart | None:
        """The wrapped field's orientation chart."""
        return self.field.chart

    @property
    def learner(self) -> str:
        """The nominal field's learner name (for plots and reports)."""
        return str(self.field.learner)

    def stability_constants(self) -> dict[str, Any] | None:
        """None: a wrapper changes the field, so the nominal field's Lyapunov function is not its own."""
        return None

    @property
    def history(self) -> dict[str, Any]:
        """The nominal field's training record."""
        return dict(self.field.history)

    @property
    def config(self) -> Any:
        """The nominal field's training options (None for a field without them)."""
        return self.field.config

    @property
    def demo_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The nominal field's training-demo box (lo, hi), each shape (d,), or None."""
        return self.field.demo_box

    def goal_at(self, t: float) -> np.ndarray:
        """The goal at time t [s], shape (d,): the wrapped field's (``goal_at``)."""
        return goal_at(self.field, t)

    def goal_samples(self) -> np.ndarray:
        """Every place the goal visits, shape (G, d): the wrapped field's."""
        return self.field.goal_samples()

    def toward(self, goal: np.ndarray) -> Any:
        """A wrapped field takes its goal from the field it wraps: ``ConfigError`` (call ``toward``
        on that field, then wrap it)."""
        raise ConfigError("toward(goal) applies to a learned field, before it is wrapped (obstacles, a "
                          "moving goal)")

    def runner(self, start: np.ndarray | None, dt: float) -> Runner:
        """A ``lfd.runner.TimedRunner`` of the single-point evaluator, (x, t) -> dx/dt."""
        return TimedRunner(cached_single_point_evaluator(self), dt)

    def trajectory(self, x0: np.ndarray, t: np.ndarray, substeps: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
        """Single-start numpy RK4 (Eq. (8)) of f(x, t) from x0, shape (d,), over t, shape (T,)."""
        return timed_trajectory(cached_single_point_evaluator(self), x0, t, substeps)


def require_kind(field: Field, kinds: tuple[FieldKind, ...], what: str) -> None:
    """``ConfigError`` saying that ``what`` does not apply to ``field`` unless its kind is one of ``kinds``."""
    if field.kind not in kinds:
        raise ConfigError(f"{what} does not apply to the {field.learner} learner's field "
                          f"({field.kind.value}; it takes {', '.join(k.value for k in kinds)} fields)")


def by_kind(field: Field, table: dict[FieldKind, Any]) -> Any:
    """The entry of ``table`` for the field's kind (``ConfigError`` naming the kinds it has)."""
    if field.kind not in table:
        require_kind(field, tuple(table), "this")
    return table[field.kind]


def space_mismatch(field: Field, chart: PoseChart | None) -> str | None:
    """Why ``field`` cannot run on a task whose orientation chart is ``chart`` (None: a position
    task), or None when it can: a pose field on positions, a position field on poses, or a pose
    field learned at another goal orientation."""
    own = field.chart
    if (own is None) != (chart is None):
        return (f"a {'pose' if own is not None else 'position'} field cannot run on "
                f"{'poses' if chart is not None else 'positions'}")
    if own is not None and chart is not None and not np.allclose(own.goal_rotation, chart.goal_rotation, atol=1e-9):
        return "the pose field's goal orientation is not this task's"
    return None
