"""Modulation units: one obstacle, or overlapping static obstacles merged into one.

Obstacles that overlap are merged (connected components of the overlap graph): their union is
star-shaped about a common interior point, the reference point of [2]_, and its Gamma is the
smooth minimum

.. math::

    \\Gamma = \\Big(\\sum_k \\Gamma_k^{-p}\\Big)^{-1/p} \\le \\min_k \\Gamma_k

(p = ``MERGE_POWER``), whose surface encloses the union and rounds its concave creases. Each unit
gives Gamma, the normal and the reference direction, batched and for one point as plain floats.

References
----------
.. [2] L. Huber, A. Billard and J.-J. Slotine, "Avoidance of convex and concave obstacles with
   convergence ensured through contraction", IEEE Robotics and Automation Letters 4(2),
   1462-1469, 2019.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lfd.errors import ConfigError
from lfd.obstacles._point_kernel import EPS, pad3
from lfd.obstacles.shapes import Obstacle

__all__ = ["MERGE_POWER", "Unit", "group"]

#: exponent p of the smooth minimum that merges overlapping obstacles
MERGE_POWER = 8.0


class Unit:
    """One modulation unit: a single obstacle, or overlapping static obstacles merged by the smooth
    minimum of their Gammas around a common reference point."""

    def __init__(self, members: list[Obstacle], reference: np.ndarray) -> None:
        self.members = members
        self.reference = reference
        self.obstacle = members[0]
        self.moving = members[0].moving

    def describe(self) -> str:
        if len(self.members) == 1:
            return self.obstacle.describe()
        return "group of overlapping obstacles (" + "; ".join(o.describe() for o in self.members) + ")"

    def geometry(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gamma (B,), normal (B, d) and reference direction (B, d) of x : (B, d) at time t."""
        off = self.obstacle.offset(t) if self.moving else 0.0
        y = x - off
        if len(self.members) == 1:
            o = self.obstacle
            sdf, n = o.sdf(y)
            g = 1.0 + sdf / o.size
        else:
            p = MERGE_POWER
            gs, grads = [], []
            for o in self.members:
                sdf, n_k = o.sdf(y)
                gs.append(np.maximum(1.0 + sdf / o.size, EPS))
                grads.append(n_k / o.size)
            G = np.stack(gs)                                          # (K, B)
            g = np.sum(G ** -p, axis=0) ** (-1.0 / p)                 # (B,)
            wk = (g / G) ** (p + 1.0)                                 # (K, B)
            grad = np.einsum("kb,kbd->bd", wk, np.stack(grads))
            n = grad / np.maximum(np.linalg.norm(grad, axis=1), EPS)[:, None]
        q = y - self.reference
        r = q / np.maximum(np.linalg.norm(q, axis=1), EPS)[:, None]
        return g, n, r

    def point_geometry(self) -> Callable[[float, float, float, float],
                                         tuple[float, float, float, float, float, float, float]]:
        """The same for one point as plain floats, padded to 3-D:
        (x0, x1, x2, t) -> (Gamma, n0, n1, n2, r0, r1, r2)."""
        f0, f1, f2 = pad3(self.reference)
        o = self.obstacle
        sqrt = math.sqrt
        if len(self.members) == 1:
            sdf, inv = o.point_sdf3(), 1.0 / o.size
        else:
            sdfs = [(m.point_sdf3(), 1.0 / m.size) for m in self.members]
            p = MERGE_POWER

            def sdf(y0: float, y1: float, y2: float) -> tuple[float, float, float, float]:
                acc, parts = 0.0, []
                for sdf_k, inv_k in sdfs:
                    s, a0, a1, a2 = sdf_k(y0, y1, y2)
                    g_k = max(1.0 + s * inv_k, EPS)
                    acc += g_k ** -p
                    parts.append((g_k, a0, a1, a2, inv_k))
                g = acc ** (-1.0 / p)
                m0 = m1 = m2 = 0.0
                for g_k, a0, a1, a2, inv_k in parts:
                    w = (g / g_k) ** (p + 1.0) * inv_k
                    m0, m1, m2 = m0 + w * a0, m1 + w * a1, m2 + w * a2
                mn = sqrt(m0 * m0 + m1 * m1 + m2 * m2) or 1.0
                return g - 1.0, m0 / mn, m1 / mn, m2 / mn   # "sdf" in Gamma units: inv = 1
            inv = 1.0
        if not self.moving:
            def geom(x0: float, x1: float, x2: float, t: float
                     ) -> tuple[float, float, float, float, float, float, float]:
                s, n0, n1, n2 = sdf(x0, x1, x2)
                q0, q1, q2 = x0 - f0, x1 - f1, x2 - f2
                qn = sqrt(q0 * q0 + q1 * q1 + q2 * q2) or 1.0
                return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn
            return geom
        if o.velocity is not None:
            v0, v1, v2 = pad3(o.velocity)

            def offset(t: float) -> tuple[float, float, float]:
                return v0 * t, v1 * t, v2 * t
        else:
            def offset(t: float) -> tuple[float, float, float]:
                return pad3(o.offset(t))

        def geom_moving(x0: float, x1: float, x2: float, t: float
                        ) -> tuple[float, float, float, float, float, float, float]:
            d0, d1, d2 = offset(t)
            x0, x1, x2 = x0 - d0, x1 - d1, x2 - d2
            s, n0, n1, n2 = sdf(x0, x1, x2)
            q0, q1, q2 = x0 - f0, x1 - f1, x2 - f2
            qn = sqrt(q0 * q0 + q1 * q1 + q2 * q2) or 1.0
            return 1.0 + s * inv, n0, n1, n2, q0 / qn, q1 / qn, q2 / qn
        return geom_moving


def group(obstacles: list[Obstacle]) -> list[Unit]:
    """Merge overlapping obstacles (connected components of the overlap graph) into units with a
    common reference point: the point that minimises max_k Gamma_k (the deepest common point).

    Parameters
    ----------
    obstacles : list of Obstacle
        The obstacles, of one dimension.

    Returns
    -------
    list of Unit
        One unit per connected component: a lone obstacle keeps its own reference point.

    Raises
    ------
    ConfigError
        Overlapping obstacles of which one moves, or a chain of overlaps without a common interior point.
    """
    n = len(obstacles)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    surface = [o.surface_points(128) for o in obstacles]
    for i in range(n):
        for j in range(i + 1, n):
            oi, oj = obstacles[i], obstacles[j]
            overlap = (np.min(oi.gamma(surface[j])) < 1.0 or np.min(oj.gamma(surface[i])) < 1.0
                       or oi.gamma(oj.reference) < 1.0 or oj.gamma(oi.reference) < 1.0)
            if overlap:
                if oi.moving or oj.moving:
                    raise ConfigError(f"obstacles {i} ({oi.describe()}) and {j} ({oj.describe()}) overlap: "
                                      "overlapping obstacles must be static")
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    units = []
    for idx in groups.values():
        members = [obstacles[i] for i in idx]
        if len(members) == 1:
            units.append(Unit(members, members[0].reference))
            continue
        from scipy.optimize import minimize

        def worst(p: np.ndarray) -> float:
            return max(float(o.gamma(p)) for o in members)  # noqa: B023 (only called in this iteration)

        start = np.mean([o.reference for o in members], axis=0)
        res = minimize(worst, start, method="Nelder-Mead",
                       options={"xatol": 1e-9 * max(o.size for o in members), "fatol": 1e-12, "maxiter": 4000})
        if worst(res.x) >= 1.0:
            raise ConfigError("obstacles " + ", ".join(str(i) for i in idx) + " overlap in a chain without a "
                              "common interior point: split them or make them overlap pairwise")
        units.append(Unit(members, np.asarray(res.x, dtype=np.float64)))
    return units
