"""Obstacle avoidance for any velocity field, by a modulation that keeps it converging.

``avoid`` wraps a field (a ``VelocityField``, a time-varying field such as ``lfd.goal.MovingGoalField``,
or a field with a phase, ``lfd.learners.tracking``) so that its trajectories go around obstacles,
never entering one, and are turned toward the goal beside them: the modulation of [1]_ about the
reference point of [2]_, steered by the convergence dynamics of [3]_ (``lfd.obstacles.modulation``;
Eqs. (O1)-(O3) of docs/equations.md, with what is proved and what is measured about reaching the goal).

References
----------
.. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
   avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
.. [2] L. Huber, A. Billard and J.-J. Slotine, "Avoidance of convex and concave obstacles with
   convergence ensured through contraction", IEEE Robotics and Automation Letters 4(2),
   1462-1469, 2019.
.. [3] L. Huber, J.-J. Slotine and A. Billard, "Avoidance of concave obstacles through rotation of
   nonlinear dynamics", IEEE Transactions on Robotics 40, 1983-2002, 2023.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np

from lfd.errors import ConfigError
from lfd.field import FieldKind, FieldWrapper, PhasedRuns, by_kind, cached_single_point_evaluator, require_kind
from lfd.integrate import rk4_phase, rk4_step
from lfd.obstacles.groups import Unit
from lfd.obstacles.modulation import (
    CONVERGENCE_BAND,
    DETOUR_HOLD,
    GOAL_FADE,
    MIN_GOAL_GAMMA,
    REACTIVITY,
    Modulation,
    PointModulator,
    settings,
)
from lfd.obstacles.parse import parse_obstacle
from lfd.obstacles.shapes import Obstacle

__all__ = ["AvoidingField", "PhasedAvoidingField", "avoid", "settings", "CONVERGENCE_BAND", "DETOUR_HOLD",
           "GOAL_FADE", "MIN_GOAL_GAMMA", "REACTIVITY"]

#: the nominal velocity at points x (B, d) and time t [s], by the wrapped field's kind (an autonomous
#: field, and the autonomous view of a phased one, take no time)
_NOMINAL: dict[FieldKind, Callable[[Any, np.ndarray, float], np.ndarray]] = {
    FieldKind.AUTONOMOUS: lambda f, x, t: f(x),
    FieldKind.TIME_VARYING: lambda f, x, t: f(x, t),
    FieldKind.PHASED: lambda f, x, t: f(x),
}


def _autonomous_point(nominal: Callable[[np.ndarray], np.ndarray], mod: PointModulator) -> Callable[..., np.ndarray]:
    """(x (d,), t) -> the avoiding dx/dt (d,) around an autonomous nominal x -> dx/dt."""
    def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
        return mod(x, nominal(x), t)
    return f


def _timed_point(nominal: Callable[[np.ndarray, float], np.ndarray], mod: PointModulator) -> Callable[..., np.ndarray]:
    """(x (d,), t) -> the avoiding dx/dt (d,) around a time-varying nominal (x, t) -> dx/dt."""
    def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
        return mod(x, nominal(x, t), t)
    return f


#: the single-point evaluator around the nominal field's own, by its kind
_POINT: dict[FieldKind, Callable[[Any, PointModulator], Callable[..., np.ndarray]]] = {
    FieldKind.AUTONOMOUS: _autonomous_point, FieldKind.TIME_VARYING: _timed_point}


class AvoidingField(FieldWrapper):
    """A velocity field modulated to avoid obstacles and turned toward its goal beside them (module
    docstring; Eqs. (O1)-(O3) of docs/equations.md).

    Parameters
    ----------
    field : an autonomous field (``VelocityField``) or a time-varying one (``lfd.goal.MovingGoalField``)
        The nominal field f(x) (or f(x, t)) [units/s].
    obstacles : sequence of Obstacle
        In the field's dimension and units.
    reactivity : float
        rho > 0, the reactivity of [1]_: eigenvalues 1 -+ w / Gamma^(1/rho); larger reacts earlier.
        The default 0.5 makes a sphere's eigenvalues 1 -+ (R / |x - c|)^2, the paper's sphere
        Gamma = (|x - c| / R)^2 with rho = 1; rho = 1 bends paths far from the obstacle more, and
        lengthens them more (see docs/equations.md).
    min_goal_gamma : float
        The goal must have Gamma >= this for every obstacle (default 1.01: 1% of the obstacle's
        size outside it), else ``ConfigError`` ("goal lies inside obstacle ...").
    convergence : bool
        Turn f toward the goal near obstacles (Eq. (O2)) and fade the modulation near the goal
        (Eq. (O3)), default True; False gives the plain modulation of [1]_, which can stall a
        winding field against an obstacle.

    Calls: ``field(x, t=0)`` with x of shape (d,) or (..., d); ``single_point_evaluator()`` for
    control loops; ``rollout(x0, t)``; ``gamma(x, t)`` the smallest Gamma over obstacles. A field
    with a phase takes ``PhasedAvoidingField``: ``avoid`` picks the class by the field's kind.

    References
    ----------
    .. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
       avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
    """

    #: the kinds of field this class wraps (``lfd.field.FieldKind``)
    wraps: ClassVar[tuple[FieldKind, ...]] = (FieldKind.AUTONOMOUS, FieldKind.TIME_VARYING)

    def __init__(self, field: Any, obstacles: Sequence[Obstacle], reactivity: float = REACTIVITY,
                 min_goal_gamma: float = MIN_GOAL_GAMMA, convergence: bool = True) -> None:
        obs: list[Obstacle] = list(obstacles)
        for i, o in enumerate(obs):
            if not isinstance(o, Obstacle):
                raise ConfigError(f"obstacle {i} is a {type(o).__name__}, not an lfd Obstacle")
            if o.dim != field.dim:
                raise ConfigError(f"obstacle {i} ({o.describe()}) is {o.dim}-D but the field is {field.dim}-D")
        if not (math.isfinite(reactivity) and reactivity > 0):
            raise ConfigError(f"reactivity must be > 0, got {reactivity}")
        if not (isinstance(min_goal_gamma, (int, float)) and math.isfinite(min_goal_gamma) and min_goal_gamma >= 1.0):
            raise ConfigError(f"min_goal_gamma must be a number >= 1, got {min_goal_gamma!r}")
        if not isinstance(convergence, bool):
            raise ConfigError(f"convergence must be True or False, got {convergence!r}")
        require_kind(field, self.wraps, f"{type(self).__name__} (build it with lfd.avoid)")
        if field.dim > 3:
            raise ConfigError(f"obstacles live in 2-D or 3-D task space; this field is {field.dim}-D")
        self.field = field
        self.obstacles: list[Obstacle] = obs
        self.reactivity = float(reactivity)
        self.convergence = bool(convergence)
        self.modulation = Modulation(obs, field.dim, reactivity, convergence)
        goals = np.atleast_2d(field.goal_samples())
        self._fixed_goal = len(goals) == 1     # a goal that visits one place does not move
        self._fade = self.modulation.goal_fades(goals, min_goal_gamma)

    @property
    def units(self) -> list[Unit]:
        """The modulation units (``lfd.obstacles.groups``): single obstacles and merged groups."""
        return self.modulation.units

    @property
    def goal(self) -> np.ndarray:
        """The attractor, shape (d,), at t = 0."""
        return self.field.goal

    def avoiding(self, obstacles: Sequence[Obstacle | str] | Obstacle | str, **kw: Any) -> AvoidingField:
        """The nominal field avoiding these obstacles and ``obstacles`` too, as one modulation (``avoid``
        of an avoiding field): overlapping obstacles merge, and Eq. (O1) weighs them all."""
        more = [obstacles] if isinstance(obstacles, (Obstacle, str)) else list(obstacles)
        return avoid(self.field, [*self.obstacles, *more], **kw)

    def gamma(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """min_k Gamma_k(x, t) over obstacles (merged groups count as one), shape (...) of x (..., d);
        < 1 means inside an obstacle."""
        return self.modulation.gamma(x, t)

    # ---- batched numpy path
    def modulate(self, x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Eqs. (O1)-(O3): the avoiding velocity for points x and nominal velocities v, shape (B, d) each."""
        return self.modulation(x, v, t, self.goal_at(t), self._fade)

    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """dx/dt, same shape as x : array, shape (d,) or (..., d) [units/s], at time t [s]."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"field expects points of dimension {self.dim}, got shape {x.shape}")
        if x.ndim == 1:
            return cached_single_point_evaluator(self)(x, t)
        flat = x.reshape(-1, self.dim)
        v = by_kind(self.field, _NOMINAL)(self.field, flat, t)
        return self.modulate(flat, np.asarray(v, dtype=np.float64), t).reshape(x.shape)

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                max_refine: int = 6) -> np.ndarray:
        """Fixed-step RK4 from x0, shape (B, d) or (d,), over times t, shape (T,), with ``substeps``
        steps per interval. Returns shape (B, T, d) (or (T, d)).

        A step that would carry a start from outside into an obstacle (possible only through the
        integration error of a large step, near a sharp corner) is redone for those starts with
        2, 4, ... 2^max_refine sub-steps; one still inside then is moved back onto the surface
        (``push_out``). ``method`` must be ``rk4`` (the only solver here)."""
        if method != "rk4":
            raise ConfigError(f"an obstacle-avoiding field integrates with rk4 only, not '{method}'")
        x = np.atleast_2d(np.asarray(x0, dtype=np.float64)).copy()
        t = np.asarray(t, dtype=np.float64)
        out = np.empty((x.shape[0], t.size, self.dim))
        out[:, 0] = x
        for j in range(t.size - 1):
            t0, t1 = float(t[j]), float(t[j + 1])
            new = self._rk4(x, t0, t1, substeps)
            outside = self.gamma(x, t0) >= 1.0
            bad = outside & (self.gamma(new, t1) < 1.0)
            level = 1
            while bad.any() and level <= max_refine:
                new[bad] = self._rk4(x[bad], t0, t1, substeps * 2 ** level)
                bad = outside & (self.gamma(new, t1) < 1.0)
                level += 1
            if bad.any():   # still inside: back onto the surface (the exact flow never enters)
                new[bad] = self.push_out(new[bad], t1)
            x = new
            out[:, j + 1] = x
        return out[0] if np.ndim(x0) == 1 else out

    def push_out(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Points x, shape (B, d), moved along each obstacle's normal toward Gamma >= 1
        (``Modulation.push_out``)."""
        return self.modulation.push_out(x, t)

    def _rk4(self, x: np.ndarray, t0: float, t1: float, n: int) -> np.ndarray:
        """n classic RK4 steps (``lfd.integrate.rk4_step``) of the batch x, shape (B, d), from t0 to t1."""
        h = (t1 - t0) / n
        for s in range(n):
            x = rk4_step(self, x, t0 + s * h, h)
        return x

    # ---- single-point path
    def point_band(self, compiled: bool = True, hold: float = 0.0) -> Callable[[np.ndarray], float]:
        """A band weight for one point, x (d,) -> [0, 1] (``Modulation.band``): ``hold`` = 0 is omega of
        Eq. (O2), ``DETOUR_HOLD`` the detour weight of Eq. (T4b)."""
        return self.modulation.band(hold, compiled)

    def point_modulator(self, compiled: bool = True, goal: np.ndarray | None = None) -> PointModulator:
        """``modulate`` for one point, as plain floats (``Modulation.point``): (x (d,), v (d,), t) ->
        the avoiding velocity (d,), user units.

        With ``compiled`` (the default), static obstacles of the built-in shapes and a fixed goal
        take the compiled kernel; moving obstacles, a moving goal or other shapes take the Python
        closure (the same arithmetic). ``goal``, shape (d,): the fixed point g of Eqs. (O2)-(O3)
        (default the field's goal; a start-conditioned phase field's run ends at r(1 | x0) instead)."""
        own = goal is None
        goal_g = np.asarray(self.field.goal if goal is None else goal, dtype=np.float64)
        fades = self._fade if own else self.modulation.fades_for(goal_g)
        moving = self.field.goal_at if own and not self._fixed_goal else None
        return self.modulation.point(goal_g, fades, moving, compiled)

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast path for one point, for control loops: ``field(x, t)`` on x of shape (d,) calls it.

        The nominal field's own single-point evaluator (given the time if it takes one), then
        ``point_modulator``.

        Returns
        -------
        callable
            (x, array of shape (d,), user units; t, float, s, default 0.0) -> dx/dt, array of
            shape (d,), user units.
        """
        return by_kind(self.field, _POINT)(self.field.single_point_evaluator(), self.point_modulator())

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.field!r}, {len(self.obstacles)} obstacles)"


class PhasedAvoidingField(PhasedRuns, AvoidingField):
    """``AvoidingField`` around a field with a phase (``lfd.learners.tracking``): Eqs. (O1)-(O3)
    act on its x-velocity of Eq. (T3), with the run's end r(1 | x0) as the goal g (``run_goal``);
    its phase law is Eq. (T4b) of docs/equations.md.

    Eq. (T4b) blends the phase stopping h of Eq. (T4) toward the clock by a detour weight, 1 across
    the band of Eq. (O2) and 0 from Gamma = 1 + 2 beta on, so the phase keeps the demos' pace while
    the tool goes around an obstacle (a detour is not a hold-up) and is Eq. (T4) further out; the
    reference r(s) is the learned one. As s
    goes to 1 the field becomes K (r(1 | x0) - x), the linear case of Eqs. (O1)-(O3).
    """

    field: Any   # a PhasedField (``lfd.field.PhasedField``)
    wraps: ClassVar[tuple[FieldKind, ...]] = (FieldKind.PHASED,)

    def __init__(self, field: Any, obstacles: Sequence[Obstacle], **kw: Any) -> None:
        super().__init__(field, obstacles, **kw)
        if any(u.moving for u in self.units):
            raise ConfigError("a field with a phase avoids static obstacles only")

    @property
    def duration(self) -> float:
        """T of the nominal field, s."""
        return float(self.field.duration)

    def initial_phase(self) -> float:
        """s(0) of the nominal field."""
        return float(self.field.initial_phase())

    def reference(self, s: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """The nominal field's reference r(s), shape s.shape + (d,)."""
        return self.field.reference(s, x0)

    def run_goal(self, x0: np.ndarray | None = None) -> np.ndarray:
        """Where the run started at x0 ends, r(1 | x0), shape (d,): the g of Eqs. (O2)-(O3) for that
        run (the field's goal when the reference is not start-conditioned, or ends there)."""
        end = np.asarray(self.field.reference(np.array([1.0]), x0), dtype=np.float64).reshape(-1, self.dim)[0]
        goal = np.asarray(self.field.goal, dtype=np.float64)
        return goal.copy() if float(np.linalg.norm(end - goal)) <= 1e-9 * max(1.0, float(np.linalg.norm(goal))) else end

    def phase_point_fn(self, x0: np.ndarray | None = None, clock_weight: Callable[[np.ndarray], float] | None = None
                       ) -> Callable[[np.ndarray, float], tuple[np.ndarray, float]]:
        """(x (d,), s) -> (the avoiding dx/dt (d,), ds/dt) for one point, for the run started at x0.

        Eqs. (O1)-(O3) steer toward the run's end r(1 | x0) (``run_goal``). With ``convergence``
        the phase law is Eq. (T4b): the phase stopping is blended toward the clock by the detour
        weight (``point_band`` with ``DETOUR_HOLD``: 1 across the band of Eq. (O2)), so the phase
        keeps the demos' pace while the tool goes around an obstacle; a ``clock_weight`` given by
        an outer wrapper is combined with it (the larger of the two)."""
        end = self.run_goal(x0)
        weight = clock_weight
        if self.convergence:
            band = self.point_band(hold=DETOUR_HOLD)
            weight = band if clock_weight is None else (lambda x: max(band(x), clock_weight(x)))
        base = self.field.phase_point_fn(x0, clock_weight=weight)
        mod = self.point_modulator(goal=None if np.array_equal(end, self.field.goal) else end)

        def f(x: np.ndarray, s: float) -> tuple[np.ndarray, float]:
            v, sdot = base(x, s)
            return mod(x, v, 0.0), sdot

        return f

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The autonomous view of the nominal field (its phase at the nearest reference point), then
        ``point_modulator``: (x (d,), t) -> dx/dt (d,) (static obstacles: t changes nothing)."""
        return _autonomous_point(self.field.single_point_evaluator(), self.point_modulator())

    def rollout_with_phase(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                           s0: np.ndarray | float = 0.0, start: np.ndarray | None = None,
                           step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Classic RK4 of (x, s) from x0, shape (B, d) or (d,), and phase s0 over t, shape (T,), with
        ``substeps`` steps per interval: x of shape (B, T, d) and s of shape (B, T) (or (T, d), (T,)).

        ``start``: the runs' starts for a start-conditioned reference (default x0). ``method`` must
        be ``rk4`` and ``step`` None."""
        if method != "rk4" or step is not None:
            raise ConfigError("an obstacle-avoiding field integrates with rk4 on the given times only")
        xb = np.atleast_2d(np.asarray(x0, dtype=np.float64)).copy()
        B = len(xb)
        st = np.broadcast_to(np.asarray(xb if start is None else start, dtype=np.float64), xb.shape)
        fns = [self.phase_point_fn(st[i]) for i in range(B)]
        sb = np.broadcast_to(np.asarray(s0, dtype=np.float64), (B,)).copy()
        t = np.asarray(t, dtype=np.float64)
        xs, ss = np.empty((B, t.size, self.dim)), np.empty((B, t.size))
        for i, fn in enumerate(fns):
            x, s = xb[i].copy(), float(sb[i])
            xs[i, 0], ss[i, 0] = x, s
            for j in range(t.size - 1):
                x1, s1 = _rk4_phase(fn, x, s, t[j + 1] - t[j], substeps)
                level = 1
                while float(self.gamma(x1)) < 1.0 <= float(self.gamma(x)) and level <= 6:   # as ``rollout``
                    x1, s1 = _rk4_phase(fn, x, s, t[j + 1] - t[j], substeps * 2 ** level)
                    level += 1
                if float(self.gamma(x1)) < 1.0 <= float(self.gamma(x)):
                    x1 = self.push_out(x1[None])[0]
                x, s = x1, s1
                xs[i, j + 1], ss[i, j + 1] = x, s
        return (xs[0], ss[0]) if np.ndim(x0) == 1 else (xs, ss)

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                max_refine: int = 6) -> np.ndarray:
        """x of ``rollout_with_phase`` from s = 0, shape (B, T, d) (or (T, d))."""
        return self.rollout_with_phase(x0, t, method, substeps)[0]


def _rk4_phase(fn: Callable[[np.ndarray, float], tuple[np.ndarray, float]], x: np.ndarray, s: float,
               dt: float, n: int) -> tuple[np.ndarray, float]:
    """n classic RK4 steps of (x (d,), s) over dt under fn (``lfd.integrate.rk4_phase``)."""
    xs, ss = rk4_phase(fn, x, np.array([0.0, dt]), substeps=n, s0=s)
    return xs[1], float(ss[1])


#: the avoiding field of each kind of nominal field
_AVOIDERS: dict[FieldKind, type[AvoidingField]] = {FieldKind.AUTONOMOUS: AvoidingField,
                                                   FieldKind.TIME_VARYING: AvoidingField,
                                                   FieldKind.PHASED: PhasedAvoidingField}


@functools.singledispatch
def avoid(field: Any, obstacles: Sequence[Obstacle | str] | Obstacle | str, **kw: Any) -> AvoidingField:
    """``field`` modulated to avoid ``obstacles`` (Obstacle objects or ``parse_obstacle`` texts);
    see ``AvoidingField`` (``PhasedAvoidingField`` for a field with a phase). An avoiding field
    given more obstacles avoids them all in one modulation (``AvoidingField.avoiding``). Raises
    ``ConfigError`` when the goal lies inside or too close to one."""
    if isinstance(obstacles, (Obstacle, str)):
        obstacles = [obstacles]
    obs = [parse_obstacle(o, field.dim) if isinstance(o, str) else o for o in obstacles]
    return by_kind(field, _AVOIDERS)(field, obs, **kw)


@avoid.register(AvoidingField)
def _avoid_more(field: AvoidingField, obstacles: Sequence[Obstacle | str] | Obstacle | str,
                **kw: Any) -> AvoidingField:
    """avoid(avoid(f, A), B) == avoid(f, A + B) (``AvoidingField.avoiding``)."""
    return field.avoiding(obstacles, **kw)
