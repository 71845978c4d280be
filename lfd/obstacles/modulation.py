"""The modulation of Eqs. (O1)-(O3) (docs/equations.md) around a set of obstacles, for any nominal
velocity: its constants, and ``Modulation``, batched (numpy) and for one point (plain floats, compiled
with numba for static obstacles of the built-in shapes, ``lfd.obstacles._point_kernel``).

It knows the obstacles, not the field: the goal g of Eqs. (O2)-(O3) and the nominal velocity f are
handed in by the avoiding fields of ``lfd.obstacles.avoidance``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from lfd.errors import ConfigError
from lfd.obstacles._point_kernel import (
    EPS,
    kzb_weights,
    modulate_unit,
    pack,
    pad3,
    smoothstep,
    steer,
)
from lfd.obstacles._point_kernel import compiled as kernels
from lfd.obstacles.groups import MERGE_POWER, group
from lfd.obstacles.shapes import Box, Capsule, Obstacle, Sphere

__all__ = ["Modulation", "settings", "CONVERGENCE_BAND", "DETOUR_HOLD", "GOAL_FADE", "MIN_GOAL_GAMMA", "REACTIVITY"]

#: default rho of the eigenvalues 1 -+ 1/Gamma^(1/rho) (see ``lfd.obstacles.AvoidingField``)
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

PointModulator = Callable[[np.ndarray, np.ndarray, float], np.ndarray]


def settings(phased: bool) -> dict[str, float]:
    """The modulation's constants, and with ``phased`` those of Eq. (T4b): what a cached result
    of an avoiding field depends on beyond its inputs (benchmarks put them into their cache keys)."""
    out = {"reactivity": REACTIVITY, "min_goal_gamma": MIN_GOAL_GAMMA, "gamma_floor": GAMMA_FLOOR,
           "inside_nr_floor": INSIDE_NR_FLOOR, "band": CONVERGENCE_BAND, "goal_fade": GOAL_FADE,
           "merge_power": MERGE_POWER}
    if phased:
        out["detour_hold"] = DETOUR_HOLD
    return out


def _smoothstep_array(u: np.ndarray) -> np.ndarray:
    """``smoothstep`` elementwise."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _mover_velocity(movers: Sequence[tuple[int, Obstacle]], w: Sequence[float], t: float) -> tuple[float, float, float]:
    """The weighted velocity sum_k w_k u_k(t) of the moving obstacles, (k, obstacle) pairs, as
    three floats (z = 0 in 2-D): the single-point path's frame velocity."""
    u0 = u1 = u2 = 0.0
    for k, o in movers:
        o0, o1, o2 = pad3(o.offset_velocity(t))
        u0, u1, u2 = u0 + w[k] * o0, u1 + w[k] * o1, u2 + w[k] * o2
    return u0, u1, u2


class Modulation:
    """Eqs. (O1)-(O3) around ``obstacles`` in d = 2 or 3 dimensions; overlapping ones are merged into
    units first (``lfd.obstacles.groups``):

    .. math::

        \\dot x = M(x)\\,\\big(b(x) - \\dot x_o\\big) + \\dot x_o, \\qquad
        M(x) = E(x)\\,D(x)\\,E(x)^{-1}                                          \\quad (O1)

        b = (1 - \\omega) f + \\omega \\lVert f \\rVert \\hat c, \\quad
        \\hat c = (g - x) / \\lVert g - x \\rVert                                   \\quad (O2)

    with the obstacles' weighted velocity :math:`\\dot x_o`, E's first column the reference direction
    r, its others tangents orthogonal to the normal n, and D = diag(1 - eta w / Gamma^(1/rho),
    1 + eta w / Gamma^(1/rho), ...) (w the weights of several units; eta fades them out at the
    goal, Eq. (O3)). With b = a r + t, t orthogonal to n, M b = lambda_r a r + lambda_t t: O(d),
    no matrix inverse (docs/equations.md has the conditions of what holds).

    Parameters
    ----------
    obstacles : sequence of Obstacle
        In task units, of dimension ``dim``.
    dim : int
        d.
    reactivity : float
        rho of the eigenvalues 1 -+ w / Gamma^(1/rho).
    convergence : bool
        Steer toward the goal near obstacles (Eq. (O2)) and fade out at the goal (Eq. (O3)).
    """

    def __init__(self, obstacles: Sequence[Obstacle], dim: int, reactivity: float, convergence: bool) -> None:
        self.units = group(list(obstacles))
        self.dim = int(dim)
        self.reactivity = float(reactivity)
        self.convergence = bool(convergence)

    @property
    def compilable(self) -> bool:
        """Whether ``lfd.obstacles._point_kernel`` takes these obstacles: static ones of the built-in shapes."""
        return (bool(self.units) and not any(u.moving for u in self.units)
                and all(type(o) in (Sphere, Box, Capsule) for u in self.units for o in u.members))

    def gamma(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """min_k Gamma_k(x, t) over the units, shape (...) of x (..., d); < 1 means inside an obstacle."""
        x = np.asarray(x, dtype=np.float64)
        if not self.units:
            return np.full(x.shape[:-1], np.inf)
        flat = x.reshape(-1, self.dim)
        return np.min([u.geometry(flat, t)[0] for u in self.units], axis=0).reshape(x.shape[:-1])

    def goal_fades(self, goals: np.ndarray, min_goal_gamma: float) -> list[float]:
        """r_k of Eq. (O3) for the field's own goal (0 for a moving obstacle or without convergence),
        after checking that every goal it visits, shape (G, d), has Gamma >= ``min_goal_gamma`` for
        every unit (a moving one: the first goal at t = 0); ``ConfigError`` otherwise."""
        fade: list[float] = []
        for u in self.units:
            g = np.min(u.geometry(goals, 0.0)[0]) if not u.moving else float("inf")
            if g < min_goal_gamma:
                raise ConfigError(f"goal lies inside obstacle {u.describe()}" if g < 1.0 else
                                  f"goal lies inside obstacle {u.describe()}'s clearance: Gamma(goal) = "
                                  f"{g:.4f} < {min_goal_gamma} (move the goal or shrink the obstacle)")
            if u.moving and float(u.obstacle.gamma(goals[0], 0.0)) < min_goal_gamma:
                raise ConfigError(f"goal lies inside obstacle {u.describe()} at t = 0")
            # Eq. (O3): Gamma is (1 / l_min)-Lipschitz, so within this radius of the goal Gamma > 1
            length = min(m.size for m in u.members)
            fade.append(0.0 if u.moving or not self.convergence else GOAL_FADE * length * (float(g) - 1.0))
        return fade

    def fades_for(self, goal: np.ndarray) -> list[float]:
        """r_k of Eq. (O3) for a run's fixed goal, shape (d,); ``ConfigError`` if it lies inside an obstacle."""
        fades = []
        for u in self.units:
            g = float(u.geometry(np.asarray(goal, dtype=np.float64)[None], 0.0)[0][0])
            if g < 1.0:
                raise ConfigError(f"the run's goal {np.round(goal, 6).tolist()} lies inside obstacle {u.describe()}")
            length = min(m.size for m in u.members)
            fades.append(0.0 if u.moving or not self.convergence else GOAL_FADE * length * (g - 1.0))
        return fades

    # ---- batched numpy path
    def __call__(self, x: np.ndarray, v: np.ndarray, t: float, goal: np.ndarray, fades: Sequence[float]) -> np.ndarray:
        """Eqs. (O1)-(O3): the avoiding velocity for points x and nominal velocities v, shape (B, d)
        each, at time t [s], toward ``goal``, shape (d,), with the r_k of Eq. (O3) ``fades``."""
        if not self.units:
            return v
        geo = [u.geometry(x, t) for u in self.units]
        G = np.stack([g for g, _, _ in geo])                             # (K, B)
        if self.convergence:   # Eq. (O2): b = (1 - omega) f + omega |f| c_hat
            omega = _smoothstep_array((1.0 + CONVERGENCE_BAND - G.min(axis=0)) / CONVERGENCE_BAND)
            to_goal = goal - x
            dist = np.linalg.norm(to_goal, axis=1)
            c_hat = to_goal / np.maximum(dist, EPS)[:, None]
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
            for k, rho in enumerate(fades):
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

    def push_out(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Points x, shape (B, d), moved along each obstacle's normal toward Gamma >= 1: up to 8
        rounds of a Newton step on sdf = (Gamma - 1) l per unit (exact for one convex obstacle:
        1e-9 units outside its surface)."""
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

    # ---- single-point path
    def _packed(self, fades: Sequence[float], goal: np.ndarray) -> np.ndarray:
        """The parameters of the compiled kernel (``lfd.obstacles._point_kernel.pack``)."""
        return pack(self.units, fades, self.reactivity, self.convergence, CONVERGENCE_BAND, pad3(goal),
                    (GAMMA_FLOOR, INSIDE_NR_FLOOR), self.dim == 2, MERGE_POWER)

    def band(self, hold: float = 0.0, compiled: bool = True) -> Callable[[np.ndarray], float]:
        """A band weight for one point: x (d,) -> a float in [0, 1], 1 up to Gamma = 1 + ``hold``
        from the nearest obstacle and 0 from Gamma = 1 + ``hold`` + ``CONVERGENCE_BAND`` on, the
        smoothstep between (compiled like ``point`` where ``compilable``). ``hold`` = 0 is omega
        of Eq. (O2); ``DETOUR_HOLD`` is the detour weight of Eq. (T4b)."""
        if compiled and self.compilable:
            band_weight = kernels()[1]
            prm = self._packed([0.0] * len(self.units), np.zeros(self.dim))

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
            return smoothstep((1.0 + hold + CONVERGENCE_BAND - gmin) * inv_band)
        return w

    def point(self, goal: np.ndarray, fades: Sequence[float], goal_at: Callable[[float], np.ndarray] | None = None,
              compiled: bool = True) -> PointModulator:
        """``__call__`` for one point, as plain floats (padded to 3-D: a 2-D point has z = 0):
        (x (d,), v (d,), t) -> the avoiding velocity (d,), user units.

        ``goal``, shape (d,), is g of Eqs. (O2)-(O3) with the r_k ``fades``; ``goal_at`` (t -> g(t))
        replaces it for a moving goal. With ``compiled`` (the default), static obstacles of the
        built-in shapes and a fixed goal take the compiled kernel (``lfd.obstacles._point_kernel``);
        moving obstacles, a moving goal or other shapes take the Python closure. Both run the same
        helpers (equal to round-off)."""
        if compiled and goal_at is None and self.compilable:
            modulate = kernels()[0]
            prm = self._packed(fades if self.convergence else [0.0] * len(self.units), goal)

            def mc(x: np.ndarray, v: np.ndarray, t: float = 0.0) -> np.ndarray:
                return modulate(x, v, prm)
            return mc
        movers = [(k, u.obstacle) for k, u in enumerate(self.units) if u.moving]
        geoms = [u.point_geometry() for u in self.units]
        inv_rho = 1.0 / self.reactivity
        square, two, K, steering = inv_rho == 2.0, self.dim == 2, len(geoms), self.convergence
        array, sqrt = np.array, math.sqrt
        inv_band = 1.0 / CONVERGENCE_BAND
        fade_k = [(k, 1.0 / rho) for k, rho in enumerate(fades) if rho > 0.0]
        g0, g1, g2 = pad3(goal)

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
            w = [1.0] * K
            if K > 1:
                kzb_weights([gg[0] for gg in geo], w, K)
            if steering:   # Eq. (O2), then the fade of Eq. (O3)
                a0, a1, a2 = (g0, g1, g2) if goal_at is None else pad3(goal_at(t))
                c0, c1, c2 = a0 - x0, a1 - x1, a2 - x2
                dist = sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                om = smoothstep((1.0 + CONVERGENCE_BAND - min(gg[0] for gg in geo)) * inv_band)
                v0, v1, v2 = steer(om, dist, c0, c1, c2, v0, v1, v2)
                for k, inv_r in fade_k:
                    w[k] *= smoothstep(dist * inv_r)
            if movers:
                u0, u1, u2 = _mover_velocity(movers, w, t)
                v0, v1, v2 = v0 - u0, v1 - u1, v2 - u2
            for k in range(K):   # Eq. (O1)
                g, n0, n1, n2, r0, r1, r2 = geo[k]
                v0, v1, v2 = modulate_unit(w[k], g, n0, n1, n2, r0, r1, r2, v0, v1, v2, inv_rho, square,
                                           GAMMA_FLOOR, INSIDE_NR_FLOOR)
            if movers:
                v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
            return array((v0, v1)) if two else array((v0, v1, v2))

        return m
