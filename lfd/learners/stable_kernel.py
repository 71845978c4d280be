"""The compiled single-point evaluation of a stable NODE field, Eq. (L2), for control loops.

One numba function evaluates the nominal MLP fhat (as ``lfd.learners.mlp_kernel.mlp``, by loops
into scratch memory rather than BLAS calls: no allocation per call), phi and J_phi
through the flow's swirls and residual blocks (``lfd.learners.flow_kernel``'s helpers, Eqs.
(F1)-(F3)), V and grad V of Eq. (L1), and the projection of Eq. (L2), with the normalisation folded
in. Compiled once per machine (``cache=True`` keeps the machine code beside this file); imported
lazily, so ``import lfd`` never pays for numba.

Written once: this kernel is the only single-point Eq. (L2) outside tests (the tests compare it with
the torch module). ``StableNodeModule`` (``lfd.learners.stable_node``) is not a twin: it is the
batched, differentiable path that training and batched evaluation need.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from lfd.learners.flow_kernel import flow_layers, flow_point, pack_flow
from lfd.learners.mlp_kernel import activate, pack_layers


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _mlp(x: np.ndarray, prm: np.ndarray, widths: np.ndarray, act: int, buf: np.ndarray,
         out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out <- W_L z_{L-1} + b_L with z_i = sigma(W_i z_{i-1} + b_i), z_0 = x, by loops into the
    scratch rows buf (2, max width) (``lfd.learners.mlp_kernel.mlp``'s layout and activations)."""
    n_layers = widths.shape[0] - 1
    for i in range(widths[0]):
        buf[0, i] = x[i]
    o = 0
    src = 0
    for layer in range(n_layers):
        n_in, n_out = widths[layer], widths[layer + 1]
        b = o + n_out * n_in
        last = layer == n_layers - 1
        for r in range(n_out):
            acc = prm[b + r]
            row = o + r * n_in
            for c in range(n_in):
                acc += prm[row + c] * buf[src, c]
            if last:
                out[r] = acc
            else:
                buf[1 - src, r] = activate(acc, act)
        src = 1 - src
        o = b + n_out


@numba.njit(cache=True, fastmath=False, nogil=True)
def _kernel(x: np.ndarray, goal: np.ndarray, scale: float, prm: np.ndarray, widths: np.ndarray, act: int,
            centers: np.ndarray, theta: np.ndarray, inv_2rho2: np.ndarray, gen: np.ndarray, w1b: np.ndarray,
            w2: np.ndarray, inv_r2: float, y_zero: np.ndarray, alpha: float, alpha_goal: float, v_goal: float,
            gain: float, vec: np.ndarray, mat: np.ndarray,
            th: np.ndarray, buf: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out (d,) <- scale f_n((x - goal) / scale) of Eq. (L2) at x (d,).

    prm, widths, act : fhat as ``mlp`` takes it (fhat(0) folded into the output bias); the flow's
    arrays as ``stable_point_fn`` packs them; y_zero : phi(0) (d,); alpha : 1/s. vec (7, d), mat
    (4, d, d), th (flow hidden,) and buf (2, widest layer) are scratch.
    """
    d = x.shape[0]
    if d != out.shape[0] or d != y_zero.shape[0]:
        raise ValueError("the point's dimension does not match the field's")
    xn, y, z, kz, h, fh, g = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6]
    jac, rot, step, tmp = mat[0], mat[1], mat[2], mat[3]
    for i in range(d):
        xn[i] = (x[i] - goal[i]) / scale
        y[i] = xn[i]
        for j in range(d):
            jac[i, j] = 1.0 if i == j else 0.0
    _mlp(xn, prm, widths, act, buf, fh)
    flow_layers(y, jac, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, z, kz, h, th, rot, step, tmp)
    v = 0.0
    for i in range(d):
        z[i] = y[i] - y_zero[i]
        v += z[i] * z[i]
    g2 = 0.0
    gf = 0.0
    for j in range(d):
        s = 0.0
        for i in range(d):
            s += jac[i, j] * z[i]
        g[j] = 2.0 * s
        g2 += g[j] * g[j]
        gf += g[j] * fh[j]
    excess = gf + (alpha + alpha_goal * (v_goal / (v_goal + v))) * v
    coef = gain * excess / g2 if excess > 0.0 and g2 > 0.0 else 0.0
    for i in range(d):
        out[i] = scale * (fh[i] - coef * g[i])


def stable_point_fn(layers: list[tuple[np.ndarray, np.ndarray]], activation: str, flow: list[dict[str, Any]],
                    alpha: float, alpha_goal: float, v_goal: float, gain: float, goal: np.ndarray, scale: float
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """x (d,) -> f(x) (d,) of Eq. (L2) in user units, through the compiled kernel.

    layers : fhat's (W_i (out, in), b_i (out,)), input first, with fhat(0) folded into the last
    bias; activation : a key of ``lfd.learners.mlp_kernel.ACTIVATIONS``; flow :
    ``BoundedFlow.numpy_params()``; alpha : 2 rate, 1/s; goal (d,), scale : the normalisation.
    phi(0) comes from ``lfd.learners.flow_kernel.flow_point``, the kernel's own phi. The evaluator
    owns scratch memory: one evaluator is for one thread.
    """
    goal_ = np.ascontiguousarray(goal, dtype=np.float64).copy()
    d = goal_.shape[0]
    prm, widths, act = pack_layers(layers, activation)
    centers, theta, inv_2rho2, gen, w1b, w2, inv_r2 = pack_flow(flow, d)
    y0 = flow_point(flow, np.zeros(d))[0]
    scale_, alpha_, alpha_goal_, v_goal_, gain_ = (float(v) for v in (scale, alpha, alpha_goal, v_goal, gain))
    vec, mat, th = np.empty((7, d)), np.empty((4, d, d)), np.empty(w1b.shape[1])
    buf = np.empty((2, int(widths.max())))
    k, f64, empty = _kernel, np.dtype(np.float64), np.empty

    def f(x: np.ndarray) -> np.ndarray:
        if type(x) is not np.ndarray or x.dtype is not f64:
            x = np.asarray(x, dtype=np.float64)
        out = empty(d)
        k(x, goal_, scale_, prm, widths, act, centers, theta, inv_2rho2, gen, w1b, w2, inv_r2, y0, alpha_,
          alpha_goal_, v_goal_, gain_, vec, mat, th, buf, out)
        return out

    f(np.zeros(d))   # compile or load the kernel now, not in the first control step
    return f
