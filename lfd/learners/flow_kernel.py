"""The compiled single-point evaluation of a contraction field, Eq. (C3), for control loops.

A contraction field's single-point evaluation is called once per control step (500 Hz and more). This
module fuses phi, J_phi (Eqs. (F1)-(F3)) and the d x d solve into one numba function (compiled once per
machine; ``cache=True`` keeps the machine code beside this file), made of small ``njit`` helpers
(one swirl, one residual block) that numba inlines into it (``inline="always"``); ``flow_point`` is
phi and J_phi alone (phi(0), y* of Eq. (C2), comes from it). This module is imported lazily (by
``ContractionField``'s single-point evaluation), so ``import lfd`` never pays for numba.

Written once: these kernels are the only single-point phi, J_phi and Eq. (C3) outside tests; the
tests compare them with a numpy reference (tests/reference_kernels.py). The torch ``BoundedFlow``
(``lfd.learners.flows``) is not a twin: it is the batched, differentiable path that training and
batched evaluation need.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _rotation(gen: np.ndarray, k: int, ang: float, z: np.ndarray, rot: np.ndarray,
              kz: np.ndarray) -> None:  # pragma: no cover - compiled
    """rot (d, d) <- R = exp(ang K_k) (Rodrigues: I + sin(ang) K + (1 - cos(ang)) K^2) and kz (d,) <- K_k z,
    for the generator K_k = gen[k] (d, d) (d = 2: the rotation by ang) and z (d,)."""
    d = z.shape[0]
    cs, sn = math.cos(ang), math.sin(ang)
    if d == 2:
        rot[0, 0], rot[0, 1], rot[1, 0], rot[1, 1] = cs, -sn, sn, cs
        kz[0], kz[1] = -z[1], z[0]
        return
    for i in range(d):
        kz[i] = 0.0
        for j in range(d):
            kk2 = 0.0
            for m in range(d):
                kk2 += gen[k, i, m] * gen[k, m, j]
            rot[i, j] = (1.0 if i == j else 0.0) + sn * gen[k, i, j] + (1.0 - cs) * kk2
            kz[i] += gen[k, i, j] * z[j]


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def swirl(y: np.ndarray, k: int, centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray,
          gen: np.ndarray, z: np.ndarray, kz: np.ndarray, rot: np.ndarray,
          step: np.ndarray) -> None:  # pragma: no cover - compiled
    """Swirl k, Eq. (F1), in place: y (d,) <- c_k + R z with z = y - c_k, step (d, d) <- its Jacobian
    J_k = R (I + q Kz z^T). z, kz (d,) and rot (d, d) are scratch."""
    d = y.shape[0]
    r2 = 0.0
    for i in range(d):
        z[i] = y[i] - centers[k, i]
        r2 += z[i] * z[i]
    ang = 0.0
    q = 0.0
    for j in range(theta.shape[1]):
        te = theta[k, j] * math.exp(-r2 * inv_2rho2[k, j])
        ang += te
        q -= 2.0 * te * inv_2rho2[k, j]
    _rotation(gen, k, ang, z, rot, kz)
    for i in range(d):
        for j in range(d):
            s = rot[i, j]
            for m in range(d):
                s += rot[i, m] * q * kz[m] * z[j]
            step[i, j] = s
    for i in range(d):
        s = centers[k, i]
        for j in range(d):
            s += rot[i, j] * z[j]
        y[i] = s


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def residual_block(y: np.ndarray, k: int, w1b: np.ndarray, w2: np.ndarray, inv_r2: float, th: np.ndarray,
                   h: np.ndarray, step: np.ndarray) -> None:  # pragma: no cover - compiled
    """Residual block k, Eq. (F3), in place: y (d,) <- y + e(y) h(y), step (d, d) <- its Jacobian.
    th (hidden,) and h (d,) are scratch."""
    d = y.shape[0]
    r2 = 0.0
    for i in range(d):
        r2 += y[i] * y[i]
    env = math.exp(-0.5 * r2 * inv_r2)
    for u in range(th.shape[0]):
        s = w1b[k, u, d]
        for i in range(d):
            s += w1b[k, u, i] * y[i]
        th[u] = math.tanh(s)
    for i in range(d):
        s = 0.0
        for u in range(th.shape[0]):
            s += w2[k, i, u] * th[u]
        h[i] = s
    for i in range(d):
        for j in range(d):
            s = 0.0
            for u in range(th.shape[0]):
                s += w2[k, i, u] * (1.0 - th[u] * th[u]) * w1b[k, u, j]
            step[i, j] = (1.0 if i == j else 0.0) + env * (s - h[i] * y[j] * inv_r2)
    for i in range(d):
        y[i] += env * h[i]


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def left_multiply(step: np.ndarray, jac: np.ndarray, tmp: np.ndarray) -> None:  # pragma: no cover - compiled
    """jac (d, d) <- step @ jac in place; tmp (d, d) is scratch (no allocation)."""
    d = jac.shape[0]
    for i in range(d):
        for j in range(d):
            s = 0.0
            for m in range(d):
                s += step[i, m] * jac[m, j]
            tmp[i, j] = s
    for i in range(d):
        for j in range(d):
            jac[i, j] = tmp[i, j]


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def flow_layers(y: np.ndarray, jac: np.ndarray, centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray,
                gen: np.ndarray, w1b: np.ndarray, w2: np.ndarray, inv_r2: float, z: np.ndarray, kz: np.ndarray,
                h: np.ndarray, th: np.ndarray, rot: np.ndarray, step: np.ndarray,
                tmp: np.ndarray) -> None:  # pragma: no cover - compiled
    """phi of Eqs. (F1)-(F3) in place: y (d,) <- phi(y) and jac (d, d) <- J_phi(y) jac, through every
    (swirl, residual block) pair (the flow's arrays as ``pack_flow`` packs them). z, kz, h (d,),
    th (hidden,), rot, step and tmp (d, d) are scratch."""
    for k in range(theta.shape[0]):
        swirl(y, k, centers, theta, inv_2rho2, gen, z, kz, rot, step)
        left_multiply(step, jac, tmp)
        residual_block(y, k, w1b, w2, inv_r2, th, h, step)
        left_multiply(step, jac, tmp)


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _solve_small(jac: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out (d,) <- jac^-1 b: for d = 2 or 3 by Cramer's rule (J_phi is well conditioned by
    construction: its singular values lie in [s_lo, s_hi], Eq. (F4)), above by LAPACK's LU solve."""
    if jac.shape[0] > 3:
        out[:] = np.linalg.solve(jac, b)
        return
    if jac.shape[0] == 2:
        det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
        out[0] = (b[0] * jac[1, 1] - jac[0, 1] * b[1]) / det
        out[1] = (jac[0, 0] * b[1] - b[0] * jac[1, 0]) / det
        return
    c00 = jac[1, 1] * jac[2, 2] - jac[1, 2] * jac[2, 1]
    c01 = jac[1, 2] * jac[2, 0] - jac[1, 0] * jac[2, 2]
    c02 = jac[1, 0] * jac[2, 1] - jac[1, 1] * jac[2, 0]
    det = jac[0, 0] * c00 + jac[0, 1] * c01 + jac[0, 2] * c02
    c10 = jac[0, 2] * jac[2, 1] - jac[0, 1] * jac[2, 2]
    c11 = jac[0, 0] * jac[2, 2] - jac[0, 2] * jac[2, 0]
    c12 = jac[0, 1] * jac[2, 0] - jac[0, 0] * jac[2, 1]
    c20 = jac[0, 1] * jac[1, 2] - jac[0, 2] * jac[1, 1]
    c21 = jac[0, 2] * jac[1, 0] - jac[0, 0] * jac[1, 2]
    c22 = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
    out[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _ridge_input(rw: np.ndarray, rb: np.ndarray, y: np.ndarray, k: int) -> float:  # pragma: no cover - compiled
    """(W y + c)_k of Eq. (N1) for ridge unit k: rw (H, d), rb (H,), y (d,)."""
    z = rb[k]
    for j in range(y.shape[0]):
        z += rw[k, j] * y[j]
    return z


@numba.njit(cache=True, fastmath=False, nogil=True)
def _kernel(x: np.ndarray, centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray,
            gen: np.ndarray, w1b: np.ndarray, w2: np.ndarray, inv_r2: float,
            a: np.ndarray, y_star: np.ndarray, rw: np.ndarray, rb: np.ndarray, rd: np.ndarray, rt: np.ndarray,
            goal: np.ndarray, scale: float, vec: np.ndarray,
            mat: np.ndarray, th: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out (d,) <- scale f_n((x - goal) / scale) of Eq. (C3) at x (d,): y = phi(x_n) and J_phi through
    the swirl and residual blocks (n_pairs of each; arrays as ``contraction_point_fn`` packs them),
    then J_phi^-1 h(y), back in user units (goal = 0 and scale = 1: normalised units), with the latent
    field h(y) = A (y - y*) - W' (d * (tanh(W y + c) - t*)) of Eq. (N1) (rw = W (H, d), rb = c (H,),
    rd = d (H,), rt = t* = tanh(W y* + c) (H,); H = 0 gives the linear field of Eq. (C2)).

    vec (5, d), mat (4, d, d) and th (hidden,) are scratch, allocated once per evaluator; the caller
    allocates out (a numpy array returned from compiled code costs more to hand back)."""
    d = x.shape[0]
    if d != out.shape[0]:
        raise ValueError("the point's dimension does not match the field's")
    y, z, kz, h, b = vec[0], vec[1], vec[2], vec[3], vec[4]
    jac, rot, step, tmp = mat[0], mat[1], mat[2], mat[3]
    for i in range(d):
        y[i] = (x[i] - goal[i]) / scale
        for j in range(d):
            jac[i, j] = 1.0 if i == j else 0.0
    flow_layers(y, jac, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, z, kz, h, th, rot, step, tmp)
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += a[i, j] * (y[j] - y_star[j])
        b[i] = s
    for k in range(rw.shape[0]):
        g = rd[k] * (math.tanh(_ridge_input(rw, rb, y, k)) - rt[k])
        for i in range(d):
            b[i] -= g * rw[k, i]
    _solve_small(jac, b, out)
    for i in range(d):
        out[i] *= scale


@numba.njit(cache=True, fastmath=False, nogil=True)
def _flow_kernel(x: np.ndarray, centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray, gen: np.ndarray,
                 w1b: np.ndarray, w2: np.ndarray, inv_r2: float, vec: np.ndarray, mat: np.ndarray, th: np.ndarray,
                 y: np.ndarray, jac: np.ndarray) -> None:  # pragma: no cover - compiled
    """y (d,) <- phi(x) and jac (d, d) <- J_phi(x) at x (d,), normalised units (the flow's arrays as
    ``pack_flow`` packs them). vec (3, d), mat (3, d, d) and th (hidden,) are scratch."""
    d = x.shape[0]
    if d != y.shape[0] or d != centers.shape[1]:
        raise ValueError("the point's dimension does not match the flow's")
    for i in range(d):
        y[i] = x[i]
        for j in range(d):
            jac[i, j] = 1.0 if i == j else 0.0
    flow_layers(y, jac, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, vec[0], vec[1], vec[2], th,
                mat[0], mat[1], mat[2])


@numba.njit(cache=True, fastmath=False, nogil=True)
def _ridge_at(rw: np.ndarray, rb: np.ndarray, y: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """tanh(W y + c) (H,), by the kernel's own ``_ridge_input``, so that h(y*) = 0 to the last bit."""
    out = np.empty(rw.shape[0])
    for k in range(rw.shape[0]):
        out[k] = math.tanh(_ridge_input(rw, rb, y, k))
    return out


def pack_flow(params: list[dict[str, Any]], d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                              np.ndarray, np.ndarray, float]:
    """The flow's arguments of the compiled kernels, each layer's stacked (first axis: the (swirl,
    block) pair): centres, theta, 1 / (2 rho^2), the generators K (zeros in 2-D), W1 with its bias, W2,
    and 1 / R^2. params : ``BoundedFlow.numpy_params()``; d : the dimension."""
    def stacked(key: str) -> np.ndarray:
        return np.ascontiguousarray(np.stack([p.get(key, np.zeros((d, d))) if key == "K" else p[key] for p in params]))

    return (stacked("c"), stacked("theta"), stacked("inv_2rho2"), stacked("K"), stacked("w1b"), stacked("w2"),
            float(params[0]["inv_r2"]))


def flow_point(params: list[dict[str, Any]], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi(x) and J_phi(x) of Eqs. (F1)-(F3) for one point, compiled.

    Parameters
    ----------
    params : list of dict
        ``BoundedFlow.numpy_params()``.
    x : array, shape (d,)
        The point, normalised units.

    Returns
    -------
    y : array, shape (d,)
        phi(x).
    jac : array, shape (d, d)
        J_phi(x).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    d = x.shape[0]
    centers, theta, inv_2rho2, gen, w1b, w2, inv_r2 = pack_flow(params, d)
    y, jac = np.empty(d), np.empty((d, d))
    _flow_kernel(x, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, np.empty((3, d)), np.empty((3, d, d)),
                 np.empty(w1b.shape[1]), y, jac)
    return y, jac


def contraction_point_fn(params: list[dict[str, Any]], a: np.ndarray, goal: np.ndarray | None = None,
                         scale: float = 1.0, ridge: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                         ) -> Callable[[np.ndarray], np.ndarray]:
    """x (d,) -> scale f_n((x - goal) / scale) (d,) of Eq. (C3) through the compiled kernel: the field
    in user units given the normalisation (goal, scale), in normalised units by default.

    params : ``BoundedFlow.numpy_params()``; a : A of Eq. (C2), (d, d); goal : (d,) (default 0);
    scale : > 0; ridge : (W (H, d), c (H,), d (H,)) of the contracting NODE's latent field, Eq. (N1)
    (default: none, Eq. (C2)). y* = phi(0) comes from ``flow_point``, the same operations as the kernel's phi, so
    the goal is an equilibrium to the last bit. The kernel is compiled or loaded here, not in the
    first control step. The evaluator owns scratch memory: one evaluator is for one thread.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    d = a.shape[0]
    centers, theta, inv_2rho2, gen, w1b, w2, inv_r2 = pack_flow(params, d)
    y_star = flow_point(params, np.zeros(d))[0]
    if ridge is None:
        rw, rb, rd = np.zeros((0, d)), np.zeros(0), np.zeros(0)
    else:
        rw, rb, rd = (np.ascontiguousarray(r, dtype=np.float64) for r in ridge)
    rt = _ridge_at(rw, rb, y_star)
    goal_ = np.zeros(d) if goal is None else np.ascontiguousarray(goal, dtype=np.float64).copy()
    scale_ = float(scale)
    vec, mat, th = np.empty((5, d)), np.empty((4, d, d)), np.empty(w1b.shape[1])   # the kernel's scratch
    k, f64, empty = _kernel, np.dtype(np.float64), np.empty

    def f(xn: np.ndarray) -> np.ndarray:
        if type(xn) is not np.ndarray or xn.dtype is not f64 or not xn.flags.c_contiguous:
            xn = np.ascontiguousarray(xn, dtype=np.float64)
        out = empty(d)
        k(xn, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, a, y_star, rw, rb, rd, rt, goal_, scale_, vec, mat,
          th, out)
        return out

    f(np.zeros(d))
    return f
