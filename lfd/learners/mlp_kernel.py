"""The compiled single-point evaluation of an MLP velocity field (NODE), for control loops.

``NodeField.single_point_evaluator`` is called once per control step (500 Hz and more), where a
numpy forward pass (two numpy calls per layer and an activation call) would cost more in call
overhead than in arithmetic at these sizes. ``mlp_point_fn`` runs the whole forward pass in one
numba function (compiled once per machine; ``cache=True`` keeps the machine code beside this file):
the products with the weights are BLAS's, the activations libm's. This module is imported lazily,
so ``import lfd`` never pays for numba.

Written once: ``mlp`` is the only single-point MLP outside tests (g(0) of ``lfd.learners.node.
numpy_layers`` included); the tests compare it with a numpy reference (tests/reference_kernels.py).
``NodeMLP`` and ``lfd.learners.node_kernel`` are not twins: they are the batched torch paths that
training (with autograd) and batched evaluation need.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

# activation codes of the kernel; each as the torch activation of ``lfd.learners.node.ACTIVATIONS``
ACTIVATIONS: dict[str, int] = {"tanh": 0, "relu": 1, "softplus": 2, "elu": 3, "silu": 4}


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def activate(z: float, act: int) -> float:  # pragma: no cover - compiled
    """The activation ``act`` (``ACTIVATIONS``) of z (softplus: beta 1, threshold 20, as torch)."""
    if act == 0:
        return math.tanh(z)
    if act == 1:
        return z if z > 0.0 else 0.0
    if act == 2:
        return z if z > 20.0 else math.log1p(math.exp(z))
    if act == 3:
        return z if z > 0.0 else math.expm1(z)
    return z * (1.0 / (1.0 + math.exp(-z)))


@numba.njit(cache=True, fastmath=False, nogil=True)
def mlp(x: np.ndarray, prm: np.ndarray, widths: np.ndarray, act: int,
        out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out (widths[-1],) <- W_L z_{L-1} + b_L with z_i = sigma(W_i z_{i-1} + b_i), z_0 = x.

    x : (widths[0],); prm : W_1 (row-major), b_1, ..., W_L, b_L, flattened; widths : (L + 1,)
    layer widths, input first; act : the hidden layers' activation (``ACTIVATIONS``).
    """
    n_layers = widths.shape[0] - 1
    if x.shape[0] != widths[0] or out.shape[0] != widths[n_layers]:
        raise ValueError("the point's dimension does not match the field's")
    z = np.empty(widths[0])   # a contiguous copy of x (which may be a strided view)
    for i in range(widths[0]):
        z[i] = x[i]
    o = 0
    for layer in range(n_layers):
        n_in, n_out = widths[layer], widths[layer + 1]
        b = o + n_out * n_in
        last = layer == n_layers - 1
        y = np.dot(prm[o:b].reshape((n_out, n_in)), z)   # BLAS, as numpy's ndarray.dot
        for r in range(n_out):
            acc = y[r] + prm[b + r]
            y[r] = acc if last else activate(acc, act)
        if last:
            out[:] = y
        o = b + n_out
        z = y


def point_call(kernel: Any, d_in: int, d_out: int, *params: Any) -> Callable[[np.ndarray], np.ndarray]:
    """x (d_in,) -> ``kernel(x, *params, out)`` with a fresh out (d_out,): a compiled kernel as a
    point function (x made float64 if it is not), the kernel compiled or loaded now, not in the
    first control step."""
    f64, empty = np.dtype(np.float64), np.empty

    def f(x: np.ndarray) -> np.ndarray:
        if type(x) is not np.ndarray or x.dtype is not f64:
            x = np.asarray(x, dtype=np.float64)
        out = empty(d_out)
        kernel(x, *params, out)
        return out

    f(np.zeros(d_in))
    return f


def pack_layers(layers: list[tuple[np.ndarray, np.ndarray]], activation: str
                ) -> tuple[np.ndarray, np.ndarray, int]:
    """The arguments ``mlp`` takes for ``layers`` (W_i (out, in), b_i (out,), input first): every
    weight and bias in one float64 array, the widths (input first, int64) and the activation's code.
    Raises ValueError for an unknown activation."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation '{activation}'")
    prm = np.ascontiguousarray(np.concatenate([np.concatenate([np.asarray(w, dtype=np.float64).ravel(),
                                                               np.asarray(b, dtype=np.float64).ravel()])
                                               for w, b in layers]))
    widths = np.array([layers[0][0].shape[1]] + [w.shape[0] for w, _ in layers], dtype=np.int64)
    return prm, widths, ACTIVATIONS[activation]


def mlp_point_fn(layers: list[tuple[np.ndarray, np.ndarray]], activation: str
                 ) -> Callable[[np.ndarray], np.ndarray]:
    """x (d,) -> W_L z_{L-1} + b_L (d,) with z_i = sigma(W_i z_{i-1} + b_i), z_0 = x, compiled.

    Parameters
    ----------
    layers : list of (W_i (out, in), b_i (out,))
        The layers, input first (float64).
    activation : str
        The hidden layers' activation, a key of ``ACTIVATIONS``.

    Returns
    -------
    callable
        x, array of shape (d,) -> array of shape (d_out,), a fresh array; reentrant (no shared
        buffers).
    """
    prm, widths, act = pack_layers(layers, activation)
    return point_call(mlp, int(widths[0]), int(widths[-1]), prm, widths, act)
