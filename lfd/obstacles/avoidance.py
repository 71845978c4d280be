"""Obstacle avoidance for any velocity field by dynamical-system modulation [1]_.

A field f (a ``VelocityField`` or a time-varying field such as ``lfd.goal.MovingGoalField``) is
wrapped so that trajectories go around obstacles, never entering one:

.. math::

    \\dot x = M(x)\\,\\big(f(x) - \\dot x_o\\big) + \\dot x_o, \\qquad
    M(x) = E(x)\\,D(x)\\,E(x)^{-1}

with the obstacle velocity :math:`\\dot x_o` (0 for static ones), E's first column the reference
direction r = (x - x_ref) / |x - x_ref| ([2]_), its others tangents orthogonal to the normal n, and
D = diag(1 - 1/Gamma, 1 + 1/Gamma, ...). With f = a r + t (t orthogonal to n) this is
M f = lambda_r a r + lambda_t t: O(d), no matrix inverse. Several obstacles combine by the weighted
product of [1]_ (``_kzb_weights``); overlapping ones are merged first (``lfd.obstacles.groups``).
Preserved (checked in ``tests/test_obstacles.py``): impenetrability, the goal as an equilibrium,
and no tail effect (lambda_r = 1 where f points away). Convergence to the goal is proven for a
linear f only; a field that winds around its goal can gain a limit cycle (docs/equations.md).

References
----------
.. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
   avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
.. [2] L. Huber, A. Billard and J.-J. Slotine, "Avoidance of convex and concave obstacles with
   convergence ensured through contraction", IEEE Robotics and Automation Letters 4(2),
   1462-1469, 2019.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lfd.errors import ConfigError
from lfd.field import FieldWrapper, cached_single_point_evaluator, is_time_varying
from lfd.integrate import rk4_step
from lfd.obstacles.groups import _group
from lfd.obstacles.parse import parse_obstacle
from lfd.obstacles.shapes import _EPS, Obstacle, _pad3

__all__ = ["AvoidingField", "avoid", "MIN_GOAL_GAMMA", "REACTIVITY"]

#: default rho of the eigenvalues 1 -+ 1/Gamma^(1/rho) (see ``AvoidingField``)
REACTIVITY = 0.5
#: the goal must have Gamma >= this (1% of the obstacle's size outside its surface)
MIN_GOAL_GAMMA = 1.01


def _mover_velocity(movers: Sequence[tuple[int, Obstacle]], w: Sequence[float], t: float
                    ) -> tuple[float, float, float]:
    """The weighted velocity sum_k w_k u_k(t) of the moving obstacles, (k, obstacle) pairs, as
    three floats (z = 0 in 2-D): the single-point path's frame velocity."""
    u0 = u1 = u2 = 0.0
    for k, o in movers:
        o0, o1, o2 = _pad3(o.offset_velocity(t))
        u0, u1, u2 = u0 + w[k] * o0, u1 + w[k] * o1, u2 + w[k] * o2
    return u0, u1, u2


def _kzb_weights(gammas: Sequence[float]) -> list[float]:
    """w_k = prod_{i != k} (Gamma_i - 1) / ((Gamma_k - 1) + (Gamma_i - 1)), the weights of [1]_
    (Gamma_i - 1 clipped at 0; a point on or inside an obstacle gives it the full weight)."""
    e = [g - 1.0 if g > 1.0 else 0.0 for g in gammas]
    if len(e) == 2:
        s = e[0] + e[1]
        return [e[1] / s, e[0] / s] if s > 0.0 else [0.5, 0.5]
    if len(e) == 3 and e[0] > 0.0 and e[1] > 0.0 and e[2] > 0.0:
        a, b, c = e
        ab, ac, bc = a + b, a + c, b + c
        return [b * c / (ab * ac), a * c / (ab * bc), a * b / (ac * bc)]
    w = []
    for k, ek in enumerate(e):
        prod = 1.0
        for i, ei in enumerate(e):
            if i != k:
                den = ek + ei
                prod *= ei / den if den > 0.0 else 0.5
        w.append(prod)
    return w


class AvoidingField(FieldWrapper):
    """A velocity field modulated to avoid obstacles [1]_ (see the module docstring for the math).

    Parameters
    ----------
    field : VelocityField or a time-varying field (``lfd.goal.MovingGoalField``)
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

    Calls: ``field(x, t=0)`` with x of shape (d,) or (..., d); ``single_point_evaluator()`` for
    control loops; ``rollout(x0, t)``; ``gamma(x, t)`` the smallest Gamma over obstacles.

    References
    ----------
    .. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
       avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
    """

    time_varying = True

    def __init__(self, field: Any, obstacles: Sequence[Obstacle], reactivity: float = REACTIVITY,
                 min_goal_gamma: float = MIN_GOAL_GAMMA) -> None:
        obs: list[Obstacle] = list(obstacles)
        if isinstance(field, AvoidingField):  # avoid(avoid(f, A), B) == avoid(f, A + B)
            obs = field.obstacles + obs
            field = field.field
        for i, o in enumerate(obs):
            if not isinstance(o, Obstacle):
                raise ConfigError(f"obstacle {i} is a {type(o).__name__}, not an lfd Obstacle")
            if o.dim != field.dim:
                raise ConfigError(f"obstacle {i} ({o.describe()}) is {o.dim}-D but the field is {field.dim}-D")
        if not (math.isfinite(reactivity) and reactivity > 0):
            raise ConfigError(f"reactivity must be > 0, got {reactivity}")
        self.field = field
        self.obstacles: list[Obstacle] = obs
        self.reactivity = float(reactivity)
        self._time_varying = is_time_varying(field)
        self.units = _group(obs)
        goals = np.atleast_2d(field.goal_samples())
        for u in self.units:
            g = np.min(u.geometry(goals, 0.0)[0]) if not u.moving else float("inf")
            if g < min_goal_gamma:
                raise ConfigError(f"goal lies inside obstacle {u.describe()}" if g < 1.0 else
                                  f"goal lies inside obstacle {u.describe()}'s clearance: Gamma(goal) = "
                                  f"{g:.4f} < {min_goal_gamma} (move the goal or shrink the obstacle)")
            if u.moving:
                gm = float(u.obstacle.gamma(goals[0], 0.0))
                if gm < min_goal_gamma:
                    raise ConfigError(f"goal lies inside obstacle {u.describe()} at t = 0")

    @property
    def goal(self) -> np.ndarray:
        """The attractor, shape (d,), at t = 0."""
        return self.field.goal

    def avoiding(self, obstacles: Sequence[Obstacle], **kw: Any) -> AvoidingField:
        """This field with more obstacles."""
        return AvoidingField(self, obstacles, **kw)

    def gamma(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """min_k Gamma_k(x, t) over obstacles (merged groups count as one), shape (...) of x (..., d);
        < 1 means inside an obstacle."""
        x = np.asarray(x, dtype=np.float64)
        flat = x.reshape(-1, self.dim)
        if not self.units:
            return np.full(x.shape[:-1], np.inf)
        g = np.min([u.geometry(flat, t)[0] for u in self.units], axis=0)
        return g.reshape(x.shape[:-1])

    # ---- batched numpy path
    def modulate(self, x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
        """M(x) (v - xdot_o) + xdot_o for points x and nominal velocities v, shape (B, d) each."""
        if not self.units:
            return v
        geo = [u.geometry(x, t) for u in self.units]
        G = np.stack([g for g, _, _ in geo])                             # (K, B)
        E = np.maximum(G - 1.0, 0.0)
        K = len(self.units)
        if K == 1:
            W = np.ones_like(G)
        else:
            W = np.ones_like(G)
            for k in range(K):
                for i in range(K):
                    if i != k:
                        den = E[k] + E[i]
                        W[k] *= np.where(den > 0, E[i] / np.where(den > 0, den, 1.0), 0.5)
        vo = np.zeros_like(v)
        for k, u in enumerate(self.units):
            if u.moving:
                vo = vo + W[k][:, None] * u.obstacle.offset_velocity(t)
        f = v - vo
        for k, (g, n, r) in enumerate(geo):
            inv = W[k] / (np.maximum(g, _EPS) ** (1.0 / self.reactivity))      # (B,)
            nr = np.maximum(np.sum(n * r, axis=1), 1e-6)
            a = np.sum(n * f, axis=1) / nr                                     # (B,)
            tan = f - a[:, None] * r
            lam_r = np.where(a < 0.0, 1.0 - inv, 1.0)
            f = (lam_r * a)[:, None] * r + (1.0 + inv)[:, None] * tan
        return f + vo

    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """dx/dt, same shape as x : array, shape (d,) or (..., d) [units/s], at time t [s]."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"field expects points of dimension {self.dim}, got shape {x.shape}")
        if x.ndim == 1:
            return cached_single_point_evaluator(self)(x, t)
        flat = x.reshape(-1, self.dim)
        v = self.field(flat, t) if self._time_varying else self.field(flat)
        return self.modulate(flat, np.asarray(v, dtype=np.float64), t).reshape(x.shape)

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                max_refine: int = 6) -> np.ndarray:
        """Fixed-step RK4 from x0, shape (B, d) or (d,), over times t, shape (T,), with ``substeps``
        steps per interval. Returns shape (B, T, d) (or (T, d)).

        A step that would carry a start from outside into an obstacle (possible only through the
        integration error of a large step, near a sharp corner) is redone for those starts with
        2, 4, ... 2^max_refine sub-steps. ``method`` must be ``rk4`` (the only solver here)."""
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
            x = new
            out[:, j + 1] = x
        return out[0] if np.ndim(x0) == 1 else out

    def _rk4(self, x: np.ndarray, t0: float, t1: float, n: int) -> np.ndarray:
        """n classic RK4 steps (``lfd.integrate.rk4_step``) of the batch x, shape (B, d), from t0 to t1."""
        h = (t1 - t0) / n
        for s in range(n):
            x = rk4_step(self, x, t0 + s * h, h)
        return x

    # ---- single-point path
    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast path for one point, for control loops: ``field(x, t)`` on x of shape (d,) calls it.

        Plain floats inside (written out for 3-D; a 2-D point is padded with z = 0).
        ``scripts/speed_obstacles.py`` measures its extra cost over the nominal field's
        ``single_point_evaluator``.

        Returns
        -------
        callable
            (x, array of shape (d,), user units; t, float, s, default 0.0) -> dx/dt, array of
            shape (d,), user units.
        """
        base = self.field.single_point_evaluator()
        tv = self._time_varying
        geoms = [u.point_geometry() for u in self.units]
        movers = [(k, u.obstacle) for k, u in enumerate(self.units) if u.moving]
        inv_rho = 1.0 / self.reactivity
        square = inv_rho == 2.0
        two = self.dim == 2
        K = len(geoms)
        array = np.array

        def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
            v = base(x, t) if tv else base(x)
            if two:
                x0, x1 = x.tolist()
                v0, v1 = v.tolist()
                x2 = v2 = 0.0
            else:
                x0, x1, x2 = x.tolist()
                v0, v1, v2 = v.tolist()
            if K == 0:
                return array((v0, v1)) if two else array((v0, v1, v2))
            geo = [gm(x0, x1, x2, t) for gm in geoms]
            w: Sequence[float] = (1.0,) if K == 1 else _kzb_weights([gg[0] for gg in geo])
            if movers:
                u0, u1, u2 = _mover_velocity(movers, w, t)
                v0, v1, v2 = v0 - u0, v1 - u1, v2 - u2
            for k in range(K):
                g, n0, n1, n2, r0, r1, r2 = geo[k]
                wk = w[k]
                if wk == 0.0:
                    continue
                if g < _EPS:
                    g = _EPS
                inv = wk / (g * g) if square else (wk / g if inv_rho == 1.0 else wk / g ** inv_rho)
                nr = n0 * r0 + n1 * r1 + n2 * r2
                a = (n0 * v0 + n1 * v1 + n2 * v2) / (nr if nr > 1e-6 else 1e-6)
                lt = 1.0 + inv
                la = (1.0 - inv) * a if a < 0.0 else a
                v0 = la * r0 + lt * (v0 - a * r0)
                v1 = la * r1 + lt * (v1 - a * r1)
                v2 = la * r2 + lt * (v2 - a * r2)
            if movers:
                v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
            return array((v0, v1)) if two else array((v0, v1, v2))

        return f

    def __repr__(self) -> str:
        return f"AvoidingField({self.field!r}, {len(self.obstacles)} obstacles)"


def avoid(field: Any, obstacles: Sequence[Obstacle | str] | Obstacle | str, **kw: Any) -> AvoidingField:
    """``field`` modulated to avoid ``obstacles`` (Obstacle objects or ``parse_obstacle`` texts);
    see ``AvoidingField``. Raises ``ConfigError`` when the goal lies inside or too close to one."""
    if isinstance(obstacles, (Obstacle, str)):
        obstacles = [obstacles]
    obs = [parse_obstacle(o, field.dim) if isinstance(o, str) else o for o in obstacles]
    return AvoidingField(field, obs, **kw)
