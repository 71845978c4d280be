"""The compiled single-point evaluation of a contraction field, Eq. (C3), for control loops.

``ContractionField.point_fn`` is called once per control step (500 Hz and more); the numpy version
(``lfd.learners.flows.bounded_flow_numpy``) costs ~30 numpy calls per point. This module fuses
phi, J_phi (Eqs. (F1)-(F3)) and the d x d solve into one numba function (compiled once per
machine; ``cache=True`` keeps the machine code beside this file). numba is imported lazily:
``import lfd`` never pays for it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

_KERNEL: Any = None


def _compile() -> Any:
    import numba

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def kernel(x: np.ndarray, centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray,
               gen: np.ndarray, w1b: np.ndarray, w2: np.ndarray, inv_r2: float,
               a: np.ndarray, y_star: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
        d = x.shape[0]
        n_pairs, n_comp = theta.shape
        hidden = w1b.shape[1]
        y = x.copy()
        jac = np.eye(d)
        z = np.empty(d)
        kz = np.empty(d)
        rot = np.empty((d, d))
        step = np.empty((d, d))
        th = np.empty(hidden)
        h = np.empty(d)
        for k in range(n_pairs):
            # swirl, Eq. (F1)
            r2 = 0.0
            for i in range(d):
                z[i] = y[i] - centers[k, i]
                r2 += z[i] * z[i]
            ang = 0.0
            q = 0.0
            for j in range(n_comp):
                te = theta[k, j] * math.exp(-r2 * inv_2rho2[k, j])
                ang += te
                q -= 2.0 * te * inv_2rho2[k, j]
            cs, sn = math.cos(ang), math.sin(ang)
            if d == 2:
                rot[0, 0], rot[0, 1], rot[1, 0], rot[1, 1] = cs, -sn, sn, cs
                kz[0], kz[1] = -z[1], z[0]
            else:
                for i in range(d):
                    kz[i] = 0.0
                    for j in range(d):
                        kk2 = 0.0
                        for m in range(d):
                            kk2 += gen[k, i, m] * gen[k, m, j]
                        rot[i, j] = (1.0 if i == j else 0.0) + sn * gen[k, i, j] + (1.0 - cs) * kk2
                        kz[i] += gen[k, i, j] * z[j]
            # J_k = R (I + q Kz z'); y = c + R z
            for i in range(d):
                for j in range(d):
                    s = rot[i, j]
                    for m in range(d):
                        s += rot[i, m] * q * kz[m] * z[j]
                    step[i, j] = s
            jac = step @ jac
            for i in range(d):
                s = centers[k, i]
                for j in range(d):
                    s += rot[i, j] * z[j]
                y[i] = s
            # residual block, Eq. (F3)
            r2 = 0.0
            for i in range(d):
                r2 += y[i] * y[i]
            env = math.exp(-0.5 * r2 * inv_r2)
            for u in range(hidden):
                s = w1b[k, u, d]
                for i in range(d):
                    s += w1b[k, u, i] * y[i]
                th[u] = math.tanh(s)
            for i in range(d):
                s = 0.0
                for u in range(hidden):
                    s += w2[k, i, u] * th[u]
                h[i] = s
            for i in range(d):
                for j in range(d):
                    s = 0.0
                    for u in range(hidden):
                        s += w2[k, i, u] * (1.0 - th[u] * th[u]) * w1b[k, u, j]
                    step[i, j] = (1.0 if i == j else 0.0) + env * (s - h[i] * y[j] * inv_r2)
            jac = step @ jac
            for i in range(d):
                y[i] += env * h[i]
        # Eq. (C3): J^-1 A (y - y*)
        v = a @ (y - y_star)
        return np.linalg.solve(jac, v)

    return kernel


def kernel() -> Any:
    """The compiled kernel (compiled or loaded from numba's cache on first use)."""
    global _KERNEL
    if _KERNEL is None:
        _KERNEL = _compile()
    return _KERNEL


def contraction_point_fn(params: list[dict[str, Any]], a: np.ndarray, y_star: np.ndarray
                         ) -> Callable[[np.ndarray], np.ndarray]:
    """x_n (d,) -> f_n(x_n) (d,) of Eq. (C3) through the compiled kernel.

    params : ``BoundedFlow.numpy_params()``; a : A of Eq. (C2), (d, d); y_star : phi(0), (d,).
    """
    d = len(y_star)
    centers = np.ascontiguousarray(np.stack([p["c"] for p in params]))
    theta = np.ascontiguousarray(np.stack([p["theta"] for p in params]))
    inv_2rho2 = np.ascontiguousarray(np.stack([p["inv_2rho2"] for p in params]))
    gen = np.ascontiguousarray(np.stack([p.get("K", np.zeros((d, d))) for p in params]))
    w1b = np.ascontiguousarray(np.stack([p["w1b"] for p in params]))
    w2 = np.ascontiguousarray(np.stack([p["w2"] for p in params]))
    inv_r2 = float(params[0]["inv_r2"])
    a = np.ascontiguousarray(a, dtype=np.float64)
    y_star = np.ascontiguousarray(y_star, dtype=np.float64)
    k = kernel()

    def f(xn: np.ndarray) -> np.ndarray:
        return k(np.ascontiguousarray(xn, dtype=np.float64), centers, theta, inv_2rho2, gen, w1b, w2,
                 inv_r2, a, y_star)

    return f
