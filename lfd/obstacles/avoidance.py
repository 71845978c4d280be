"""Obstacle avoidance for any velocity field by dynamical-system modulation [1]_ that keeps the
field converging (docs/equations.md, Eqs. (O1)-(O3)).

A field f (a ``VelocityField``, a time-varying field such as ``lfd.goal.MovingGoalField``, or a
field with a phase, ``lfd.learners.tracking``) is wrapped so that trajectories go around
obstacles, never entering one, and are turned toward the goal beside them (what is proved and
what is measured about reaching it: docs/equations.md):

.. math::

    \\dot x = M(x)\\,\\big(b(x) - \\dot x_o\\big) + \\dot x_o, \\qquad
    M(x) = E(x)\\,D(x)\\,E(x)^{-1}                                          \\quad (O1)

    b = (1 - \\omega) f + \\omega \\lVert f \\rVert \\hat c, \\quad
    \\hat c = (g - x) / \\lVert g - x \\rVert                                   \\quad (O2)

with the obstacle velocity :math:`\\dot x_o` (0 for static ones), E's first column the reference
direction r = (x - x_ref) / |x - x_ref| ([2]_), its others tangents orthogonal to the normal n, and
D = diag(1 - eta w / Gamma^(1/rho), 1 + eta w / Gamma^(1/rho), ...) (w the weights of several
obstacles; Eq. (O3): eta fades the modulation out near the goal).
omega rises from 0 half an obstacle's size away to 1 on its surface, so near an obstacle the field
is turned toward the goal (the convergence dynamics of [3]_) before it is modulated; |b| <= |f|. With
b = a r + t (t orthogonal to n) M b = lambda_r a r + lambda_t t: O(d), no matrix inverse. Several
obstacles combine by the weighted product of [1]_ (``_kzb_weights``); overlapping ones are merged
first (``lfd.obstacles.groups``). Preserved (checked in ``tests/test_obstacles.py``):
impenetrability, the goal as an equilibrium, no tail effect (lambda_r = 1 where b points away),
and no stall on a surface except the saddle behind each obstacle; ``convergence=False`` gives the
plain modulation of f.

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

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lfd.errors import ConfigError
from lfd.field import FieldWrapper, PhasedRuns, cached_single_point_evaluator, is_phased, is_time_varying
from lfd.integrate import rk4_phase, rk4_step
from lfd.obstacles.groups import MERGE_POWER, _group
from lfd.obstacles.parse import parse_obstacle
from lfd.obstacles.shapes import _EPS, Box, Capsule, Obstacle, Sphere, _pad3

__all__ = ["AvoidingField", "PhasedAvoidingField", "avoid", "CONVERGENCE_BAND", "GOAL_FADE", "MIN_GOAL_GAMMA",
           "REACTIVITY"]

#: default rho of the eigenvalues 1 -+ 1/Gamma^(1/rho) (see ``AvoidingField``)
REACTIVITY = 0.5
#: the goal must have Gamma >= this (1% of the obstacle's size outside its surface)
MIN_GOAL_GAMMA = 1.01
#: Gamma is floored at this in the eigenvalues: a step's stage that lands deep inside an obstacle
#: gets a bounded velocity (with ``INSIDE_NR_FLOOR``, a bounded multiple of the nominal speed)
GAMMA_FLOOR = 0.5
#: inside an obstacle n . r is floored at this (a merged group need not be star-shaped there)
INSIDE_NR_FLOOR = 0.1
#: beta of Eq. (O2): within Gamma < 1 + beta of an obstacle the nominal field turns toward the goal
CONVERGENCE_BAND = 0.5
#: the modulation fades out within this fraction of the goal's clearance from an obstacle, Eq. (O3)
GOAL_FADE = 0.5
#: Eq. (T4b): the phase keeps the clock's pace up to Gamma = 1 + this, the whole band of Eq. (O2),
#: and its weight falls to 0 over a further ``CONVERGENCE_BAND``
DETOUR_HOLD = CONVERGENCE_BAND


def settings(phased: bool) -> dict[str, float]:
    """The modulation's constants, and with ``phased`` those of Eq. (T4b): what a cached result
    of an avoiding field depends on beyond its inputs (benchmarks put them into their cache keys)."""
    out = {"reactivity": REACTIVITY, "min_goal_gamma": MIN_GOAL_GAMMA, "gamma_floor": GAMMA_FLOOR,
           "inside_nr_floor": INSIDE_NR_FLOOR, "band": CONVERGENCE_BAND, "goal_fade": GOAL_FADE,
           "merge_power": MERGE_POWER}
    if phased:
        out["detour_hold"] = DETOUR_HOLD
    return out


def _smoothstep(u: float) -> float:
    """3 u^2 - 2 u^3 on u clipped to [0, 1]: 0 -> 0, 1 -> 1, C1."""
    u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
    return u * u * (3.0 - 2.0 * u)


def _smoothstep_array(u: np.ndarray) -> np.ndarray:
    """``_smoothstep`` elementwise."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


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
    """A velocity field modulated to avoid obstacles and turned toward its goal beside them (module
    docstring; Eqs. (O1)-(O3) of docs/equations.md).

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
    convergence : bool
        Turn f toward the goal near obstacles (Eq. (O2)) and fade the modulation near the goal
        (Eq. (O3)), default True; False gives the plain modulation of [1]_, which can stall a
        winding field against an obstacle.

    Calls: ``field(x, t=0)`` with x of shape (d,) or (..., d); ``single_point_evaluator()`` for
    control loops; ``rollout(x0, t)``; ``gamma(x, t)`` the smallest Gamma over obstacles.

    References
    ----------
    .. [1] S. M. Khansari-Zadeh and A. Billard, "A dynamical system approach to realtime obstacle
       avoidance", Autonomous Robots 32(4), 433-454, 2012. doi:10.1007/s10514-012-9287-y
    """

    def __init__(self, field: Any, obstacles: Sequence[Obstacle], reactivity: float = REACTIVITY,
                 min_goal_gamma: float = MIN_GOAL_GAMMA, convergence: bool = True) -> None:
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
        if not (isinstance(min_goal_gamma, (int, float)) and math.isfinite(min_goal_gamma) and min_goal_gamma >= 1.0):
            raise ConfigError(f"min_goal_gamma must be a number >= 1, got {min_goal_gamma!r}")
        if not isinstance(convergence, bool):
            raise ConfigError(f"convergence must be True or False, got {convergence!r}")
        if is_phased(field) and not isinstance(self, PhasedAvoidingField):
            raise ConfigError("a field with a phase avoids obstacles through lfd.avoid (a PhasedAvoidingField)")
        if field.dim > 3:
            raise ConfigError(f"obstacles live in 2-D or 3-D task space; this field is {field.dim}-D")
        self.field = field
        self.obstacles: list[Obstacle] = obs
        self.reactivity = float(reactivity)
        self.convergence = bool(convergence)
        self._time_varying = is_time_varying(field)
        self.units = _group(obs)
        goals = np.atleast_2d(field.goal_samples())
        fade: list[float] = []
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
            # Eq. (O3): Gamma is (1 / l_min)-Lipschitz, so within this radius of the goal Gamma > 1
            length = min(m.size for m in u.members)
            fade.append(0.0 if u.moving or not self.convergence else GOAL_FADE * length * (float(g) - 1.0))
        self._fade = fade

    @property
    def goal(self) -> np.ndarray:
        """The attractor, shape (d,), at t = 0."""
        return self.field.goal

    def goal_at(self, t: float) -> np.ndarray:
        """The attractor at time t, shape (d,)."""
        return self.field.goal_at(t) if self._time_varying else self.field.goal

    def avoiding(self, obstacles: Sequence[Obstacle], **kw: Any) -> AvoidingField:
        """This field with more obstacles."""
        return avoid(self, obstacles, **kw)

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
        """Eqs. (O1)-(O3): the avoiding velocity for points x and nominal velocities v, shape (B, d) each."""
        if not self.units:
            return v
        geo = [u.geometry(x, t) for u in self.units]
        G = np.stack([g for g, _, _ in geo])                             # (K, B)
        if self.convergence:   # Eq. (O2): b = (1 - omega) f + omega |f| c_hat
            omega = _smoothstep_array((1.0 + CONVERGENCE_BAND - G.min(axis=0)) / CONVERGENCE_BAND)
            to_goal = self.goal_at(t) - x
            dist = np.linalg.norm(to_goal, axis=1)
            c_hat = to_goal / np.maximum(dist, _EPS)[:, None]
            v = (1.0 - omega)[:, None] * v + (omega * np.linalg.norm(v, axis=1))[:, None] * c_hat
        E = np.maximum(G - 1.0, 0.0)
        K = len(self.units)
        W = np.ones_like(G)
        if K > 1:
            for k in range(K):
                for i in range(K):
                    if i != k:
                        den = E[k] + E[i]
                        W[k] *= np.where(den > 0, E[i] / np.where(den > 0, den, 1.0), 0.5)
        if self.convergence:   # Eq. (O3): eta_k fades the modulation out at the goal
            for k, rho in enumerate(self._fade):
                if rho > 0.0:
                    W[k] = W[k] * _smoothstep_array(dist / rho)
        vo = np.zeros_like(v)
        for k, u in enumerate(self.units):
            if u.moving:
                vo = vo + W[k][:, None] * u.obstacle.offset_velocity(t)
        f = v - vo
        for k, (g, n, r) in enumerate(geo):
            inv = W[k] / (np.maximum(g, GAMMA_FLOOR) ** (1.0 / self.reactivity))      # (B,)
            nr = np.maximum(np.sum(n * r, axis=1), np.where(g < 1.0, INSIDE_NR_FLOOR, 1e-6))
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
        """Points x, shape (B, d), moved along each obstacle's normal toward Gamma >= 1: up to 8
        rounds of a Newton step on sdf = (Gamma - 1) l per obstacle (exact for one convex
        obstacle: 1e-9 units outside its surface)."""
        x = np.array(x, dtype=np.float64)
        for _ in range(8):
            moved = False
            for u in self.units:
                g, n, _ = u.geometry(x, t)
                inside = g < 1.0
                if inside.any():
                    length = min(m.size for m in u.members)
                    x[inside] += ((1.0 - g[inside]) * length + 1e-9)[:, None] * n[inside]
                    moved = True
            if not moved:
                break
        return x

    def _rk4(self, x: np.ndarray, t0: float, t1: float, n: int) -> np.ndarray:
        """n classic RK4 steps (``lfd.integrate.rk4_step``) of the batch x, shape (B, d), from t0 to t1."""
        h = (t1 - t0) / n
        for s in range(n):
            x = rk4_step(self, x, t0 + s * h, h)
        return x

    # ---- single-point path
    def _compilable(self) -> bool:
        """Whether ``lfd.obstacles._point_kernel`` takes these obstacles: static ones of the
        built-in shapes, and a fixed goal."""
        return (bool(self.units) and not any(u.moving for u in self.units) and not self._time_varying
                and all(type(o) in (Sphere, Box, Capsule) for u in self.units for o in u.members))

    def _fades_for(self, goal: np.ndarray) -> list[float]:
        """r_k of Eq. (O3) for a fixed goal, shape (d,) (``_fade`` for the field's own goal);
        ``ConfigError`` if that goal lies inside an obstacle."""
        fades = []
        for u in self.units:
            g = float(u.geometry(np.asarray(goal, dtype=np.float64)[None], 0.0)[0][0])
            if g < 1.0:
                raise ConfigError(f"the run's goal {np.round(goal, 6).tolist()} lies inside obstacle {u.describe()}")
            length = min(m.size for m in u.members)
            fades.append(0.0 if u.moving or not self.convergence else GOAL_FADE * length * (g - 1.0))
        return fades

    def point_band(self, compiled: bool = True, hold: float = 0.0) -> Callable[[np.ndarray], float]:
        """A band weight for one point: x (d,) -> a float in [0, 1], 1 up to Gamma = 1 + ``hold``
        from the nearest obstacle and 0 from Gamma = 1 + ``hold`` + ``CONVERGENCE_BAND`` on, the
        smoothstep between (static obstacles; compiled like ``point_modulator``). ``hold`` = 0 is
        omega of Eq. (O2); ``DETOUR_HOLD`` is the detour weight of Eq. (T4b)."""
        if compiled and self._compilable():
            from lfd.obstacles._point_kernel import band_weight, pack

            prm = pack(self.units, [0.0] * len(self.units), self.reactivity, self.convergence, CONVERGENCE_BAND,
                       _pad3(self.field.goal), (GAMMA_FLOOR, INSIDE_NR_FLOOR), self.dim == 2, MERGE_POWER, _EPS)

            def wc(x: np.ndarray) -> float:
                return float(band_weight(x, prm, hold))
            return wc
        geoms = [u.point_geometry() for u in self.units]
        two, inv_band = self.dim == 2, 1.0 / CONVERGENCE_BAND

        def w(x: np.ndarray) -> float:
            x0, x1, x2 = (*x.tolist(), 0.0) if two else x.tolist()
            if not geoms:
                return 0.0
            gmin = min(gm(x0, x1, x2, 0.0)[0] for gm in geoms)
            return _smoothstep((1.0 + hold + CONVERGENCE_BAND - gmin) * inv_band)
        return w

    def point_modulator(self, compiled: bool = True, goal: np.ndarray | None = None
                        ) -> Callable[[np.ndarray, np.ndarray, float], np.ndarray]:
        """``modulate`` for one point, as plain floats (written out for 3-D; a 2-D point is padded
        with z = 0): (x (d,), v (d,), t) -> the avoiding velocity (d,), user units.

        With ``compiled`` (the default), static obstacles of the built-in shapes and a fixed goal
        take the same arithmetic compiled with numba (``lfd.obstacles._point_kernel``; equal to
        the Python closure to round-off); moving obstacles, a moving goal or other shapes take
        the Python closure. ``goal``, shape (d,): the fixed point g of Eqs. (O2)-(O3) (default
        the field's goal; a start-conditioned phase field's run ends at r(1 | x0) instead)."""
        movers = [(k, u.obstacle) for k, u in enumerate(self.units) if u.moving]
        own_goal = goal is None
        goal_g = np.asarray(self.field.goal if goal is None else goal, dtype=np.float64)
        fade_g = self._fade if own_goal else self._fades_for(goal_g)
        if compiled and self._compilable():
            from lfd.obstacles._point_kernel import modulate, pack

            prm = pack(self.units, fade_g if self.convergence else [0.0] * len(self.units), self.reactivity,
                       self.convergence, CONVERGENCE_BAND, _pad3(goal_g), (GAMMA_FLOOR, INSIDE_NR_FLOOR),
                       self.dim == 2, MERGE_POWER, _EPS)

            def mc(x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
                return modulate(x, v, prm)
            return mc
        geoms = [u.point_geometry() for u in self.units]
        inv_rho = 1.0 / self.reactivity
        square = inv_rho == 2.0
        two = self.dim == 2
        K = len(geoms)
        array = np.array
        steer = self.convergence
        band, inv_band = CONVERGENCE_BAND, 1.0 / CONVERGENCE_BAND
        fades = [(k, 1.0 / rho) for k, rho in enumerate(fade_g) if rho > 0.0]
        goal_at, tv = self.goal_at, self._time_varying and own_goal
        g0, g1, g2 = _pad3(goal_g)
        sqrt = math.sqrt

        def m(x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
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
            dist = 0.0
            if steer:   # Eq. (O2)
                a0, a1, a2 = (_pad3(goal_at(t)) if tv else (g0, g1, g2))
                c0, c1, c2 = a0 - x0, a1 - x1, a2 - x2
                dist = sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                gmin = min(gg[0] for gg in geo)
                om = _smoothstep((1.0 + band - gmin) * inv_band)
                if om > 0.0:
                    sp = om * sqrt(v0 * v0 + v1 * v1 + v2 * v2) / (dist if dist > _EPS else _EPS)
                    keep = 1.0 - om
                    v0, v1, v2 = keep * v0 + sp * c0, keep * v1 + sp * c1, keep * v2 + sp * c2
                if fades:   # Eq. (O3)
                    w = list(w)
                    for k, inv_r in fades:
                        w[k] *= _smoothstep(dist * inv_r)
            if movers:
                u0, u1, u2 = _mover_velocity(movers, w, t)
                v0, v1, v2 = v0 - u0, v1 - u1, v2 - u2
            for k in range(K):
                g, n0, n1, n2, r0, r1, r2 = geo[k]
                wk = w[k]
                if wk == 0.0:
                    continue
                if g < GAMMA_FLOOR:
                    g = GAMMA_FLOOR
                inv = wk / (g * g) if square else (wk / g if inv_rho == 1.0 else wk / g ** inv_rho)
                nr = n0 * r0 + n1 * r1 + n2 * r2
                floor = 1e-6 if g >= 1.0 else INSIDE_NR_FLOOR
                a = (n0 * v0 + n1 * v1 + n2 * v2) / (nr if nr > floor else floor)
                lt = 1.0 + inv
                la = (1.0 - inv) * a if a < 0.0 else a
                v0 = la * r0 + lt * (v0 - a * r0)
                v1 = la * r1 + lt * (v1 - a * r1)
                v2 = la * r2 + lt * (v2 - a * r2)
            if movers:
                v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
            return array((v0, v1)) if two else array((v0, v1, v2))

        return m

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast path for one point, for control loops: ``field(x, t)`` on x of shape (d,) calls it.

        The nominal field's own single-point evaluator, then ``point_modulator``.
        ``scripts/speed_obstacles.py`` measures its extra cost over the nominal field's.

        Returns
        -------
        callable
            (x, array of shape (d,), user units; t, float, s, default 0.0) -> dx/dt, array of
            shape (d,), user units.
        """
        base = self.field.single_point_evaluator()
        mod = self.point_modulator()
        if self._time_varying:
            def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
                return mod(x, base(x, t), t)
        else:
            def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
                return mod(x, base(x), t)
        return f

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
        ``point_modulator``: (x (d,), t = 0) -> dx/dt (d,)."""
        base = self.field.single_point_evaluator()
        mod = self.point_modulator()

        def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
            return mod(x, base(x), 0.0)

        return f

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


def avoid(field: Any, obstacles: Sequence[Obstacle | str] | Obstacle | str, **kw: Any) -> AvoidingField:
    """``field`` modulated to avoid ``obstacles`` (Obstacle objects or ``parse_obstacle`` texts);
    see ``AvoidingField``. Raises ``ConfigError`` when the goal lies inside or too close to one."""
    if isinstance(obstacles, (Obstacle, str)):
        obstacles = [obstacles]
    obs = [parse_obstacle(o, field.dim) if isinstance(o, str) else o for o in obstacles]
    if is_phased(field):
        return PhasedAvoidingField(field, obs, **kw)
    return AvoidingField(field, obs, **kw)
