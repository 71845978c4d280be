"""The numpy references of the compiled single-point kernels, for the tests that compare against them.

Each fast path of lfd is written once, as a numba kernel (``lfd.learners.mlp_kernel``,
``flow_kernel``, ``tracking_kernel``); the plain numpy versions here exist only so that the tests can
check those kernels (and the torch paths) against an independent implementation, operation by
operation. Nothing in lfd imports this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.special import expit

from lfd.learners.node import NodeMLP

# ---------------------------------------------------------------- the NODE's MLP (lfd.learners.mlp_kernel)

def activation_reference(name: str) -> Callable[[np.ndarray], np.ndarray]:
    """The numpy version of the torch activation ``name`` (softplus: beta 1, threshold 20, as torch)."""
    if name == "tanh":
        return np.tanh
    if name == "relu":
        return lambda z: np.maximum(z, 0.0)
    if name == "softplus":
        return lambda z: np.where(z > 20.0, z, np.log1p(np.exp(np.minimum(z, 20.0))))
    if name == "elu":
        return lambda z: np.where(z > 0.0, z, np.expm1(np.minimum(z, 0.0)))
    if name == "silu":
        return lambda z: z * expit(z)
    raise ValueError(f"unknown activation '{name}'")


def mlp_reference(layers: list[tuple[np.ndarray, np.ndarray]],
                  activation: str) -> Callable[[np.ndarray], np.ndarray]:
    """x (d,) -> W_L z_{L-1} + b_L with z_i = sigma(W_i z_{i-1} + b_i), z_0 = x, in numpy; layers :
    (W_i (out, in), b_i (out,)), input first."""
    act = activation_reference(activation)
    hidden, (w_out, b_out) = tuple(layers[:-1]), layers[-1]

    def f(x: np.ndarray) -> np.ndarray:
        z = x
        for w, b in hidden:
            z = act(w.dot(z) + b)
        return w_out.dot(z) + b_out

    return f


def node_reference(module: NodeMLP) -> Callable[[np.ndarray], np.ndarray]:
    """x_n (d,) -> f_n(x_n) (d,) of a NodeMLP in numpy, normalised units: g(x_n) - g(0) with
    ``goal_equilibrium``, else g(x_n)."""
    layers = [(m.weight.detach().double().numpy().copy(), m.bias.detach().double().numpy().copy())
              for m in module.linears()]
    g = mlp_reference(layers, module.activation)
    g0 = g(np.zeros(layers[0][0].shape[1])) if module.goal_equilibrium else 0.0

    def f(xn: np.ndarray) -> np.ndarray:
        return g(xn) - g0

    return f


# ---------------------------------------------------------------- the flow phi (lfd.learners.flow_kernel)

def bounded_flow_reference(params: list[dict[str, Any]], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi(x) and J_phi(x) for ONE point, as ``BoundedFlow.forward_with_jacobian`` in float64.

    params : ``BoundedFlow.numpy_params()``; x : array, shape (d,). Returns y (d,) and J (d, d).
    """
    d = x.shape[0]
    y = np.array(x, dtype=np.float64)
    jac = np.eye(d)
    arg = np.ones(d + 1)
    eye = np.eye(d)
    for p in params:
        w1, w2 = p["w1b"][:, :d], p["w2"]
        m = (w2[:, None, :] * w1.T[None, :, :]).reshape(d * d, -1)      # W2 diag(.) W1, flattened
        z = y - p["c"]
        r2 = float(z @ z)
        e = np.exp(-r2 * p["inv_2rho2"])
        te = p["theta"] * e
        ang = float(te.sum())
        q = -2.0 * float((te * p["inv_2rho2"]).sum())
        cs, sn = math.cos(ang), math.sin(ang)
        if d == 2:
            rot = np.array([[cs, -sn], [sn, cs]])
            kz = np.array([-z[1], z[0]])
        else:
            kk = p["K"]
            rot = eye + sn * kk + (1 - cs) * (kk @ kk)
            kz = kk @ z
        jac = (rot @ (eye + q * np.outer(kz, z))) @ jac
        y = p["c"] + rot @ z
        arg[:d] = y
        th = np.tanh(p["w1b"] @ arg)
        env = math.exp(-0.5 * p["inv_r2"] * float(y @ y))
        h = w2 @ th
        jg = (m @ (1.0 - th * th)).reshape(d, d) - np.outer(h, y * p["inv_r2"])
        jac = (eye + env * jg) @ jac
        y = y + env * h
    return y, jac


# ---------------------------------------------------------------- the tracking field (lfd.learners.tracking_kernel)

def _hermite(w: float) -> tuple[float, ...]:
    """The cubic Hermite basis on [0, 1] at w, then its derivatives in w."""
    w2, w3 = w * w, w * w * w
    return (2 * w3 - 3 * w2 + 1, w3 - 2 * w2 + w, -2 * w3 + 3 * w2, w3 - w2,
            6 * w2 - 6 * w, 3 * w2 - 4 * w + 1, -6 * w2 + 6 * w, 3 * w2 - 2 * w)


def phase_point_reference(ref: np.ndarray, dref: np.ndarray, goal: np.ndarray, sc: float, k: float, eps2: float,
                          inv_t: float, stop: bool, phase_end: float,
                          clock_weight: Callable[[np.ndarray], float] | None = None
                          ) -> Callable[[np.ndarray, float], tuple[np.ndarray, float]]:
    """Eqs. (T3)-(T4) (with ``clock_weight``, Eq. (T4b)) for one point in numpy: (x (d,), s) ->
    (dx/dt (d,), ds/dt), user units; the arguments of ``lfd.learners.tracking_kernel.phase_point_fn``."""
    m = ref.shape[0]
    hs = 1.0 / (m - 1)

    def f(x: np.ndarray, s: float) -> tuple[np.ndarray, float]:
        u = min(max(s, 0.0), 1.0) * (m - 1)
        i0 = min(int(u), m - 2)
        a0, b0, a1, b1, da0, db0, da1, db1 = _hermite(u - i0)
        p0, p1, m0, m1 = ref[i0], ref[i0 + 1], dref[i0] * hs, dref[i0 + 1] * hs
        r = a0 * p0 + b0 * m0 + a1 * p1 + b1 * m1
        dr = (da0 * p0 + db0 * m0 + da1 * p1 + db1 * m1) / hs
        xn = (np.asarray(x, dtype=np.float64) - goal) / sc
        e = xn - r
        end = min(max((1.0 - s) / phase_end, 0.0), 1.0)
        if not stop:
            sdot = inv_t * end
        elif clock_weight is None:
            sdot = inv_t / (1.0 + float(e.dot(e)) / eps2) * end
        else:   # Eq. (T4b)
            h = 1.0 / (1.0 + float(e.dot(e)) / eps2)
            sdot = inv_t * (h + clock_weight(x) * (1.0 - h)) * end
        return (sdot * dr - k * e) * sc, sdot

    return f


def nearest_point_reference(ref: np.ndarray, dref: np.ndarray, k: float, eps2: float, inv_t: float, stop: bool,
                            phase_end: float) -> Callable[[np.ndarray], np.ndarray]:
    """The tracking field's autonomous view (``TrackingModule.forward``) for one point in numpy,
    normalised units: x_n (d,) -> Eq. (T3) at the phase of the nearest tabulated reference point."""
    m = ref.shape[0]

    def f(xn: np.ndarray) -> np.ndarray:
        j = int(np.argmin(((ref - xn) ** 2).sum(1)))
        e = xn - ref[j]
        end = min(max((m - 1 - j) / ((m - 1) * phase_end), 0.0), 1.0)
        sdot = (inv_t / (1.0 + float(e.dot(e)) / eps2) if stop else inv_t) * end
        return sdot * dref[j] - k * e

    return f
