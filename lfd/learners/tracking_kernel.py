"""The tracking field for one point, compiled: Eqs. (T3)-(T4b) and the autonomous view in numba.

``TrackingField.phase_point_fn`` and ``TrackingField.single_point_evaluator`` run once per control
step, where a dozen numpy calls per point (and for the autonomous view a search over every tabulated
reference point) would cost more in call overhead than in arithmetic. ``phase_point_fn`` and
``nearest_point_fn`` build one-call versions on a snapshot of the tables: the cubic Hermite
reference (Eqs. (T1)-(T2)) and the phase law (Eq. (T4), or Eq. (T4b) with a clock weight computed
in Python per call); the nearest reference point is found by a compiled scan that drops a candidate
as soon as its partial squared distance reaches the best so far (the same point as numpy's
``argmin``, the first of equals). Compiled once per machine (``cache=True``); this module is
imported on first use, so ``import lfd`` never pays for numba.

Written once: these kernels are the only single-point Eqs. (T3)-(T4b) outside tests; the tests
compare them with a numpy reference (tests/reference_kernels.py). ``TrackingModule``
(``lfd.learners.tracking``) is not a twin: it is the batched torch path of rollouts of many starts.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np

from lfd.learners.mlp_kernel import point_call

__all__ = ["nearest_point_fn", "phase_point_fn"]

# prm: goal (d), then these scalars
_SCALE, _RATE, _EPS2, _INV_T, _STOP, _PHASE_END = range(6)
#: the clock weight omega that ``phase_velocity`` reads as "no weight": Eq. (T4) as is
NO_CLOCK = -1.0


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def phase_velocity(x: np.ndarray, s: float, ref: np.ndarray, dref: np.ndarray, prm: np.ndarray, omega: float,
                   out: np.ndarray) -> float:  # pragma: no cover - compiled
    """Eqs. (T3)-(T4) at x (d,), user units, and the phase s: out (d,) <- dx/dt, user units;
    returns ds/dt.

    ref, dref : (M, d) r(s_j) and r'(s_j) at s_j = j / (M - 1), normalised units (cubic Hermite
    between them); prm : goal (d), then the scale s, K, eps^2, 1 / T, phase stopping (1 or 0) and
    the phase end c of Eq. (T4); omega : the clock weight in [0, 1] of Eq. (T4b), h + omega (1 - h)
    in place of the phase stopping h, or ``NO_CLOCK`` for Eq. (T4) as is.
    """
    m, d = ref.shape
    if x.shape[0] != d or out.shape[0] != d:
        raise ValueError("the point's dimension does not match the field's")
    sc, k, o = prm[d + _SCALE], prm[d + _RATE], d
    hs = 1.0 / (m - 1)
    u = min(max(s, 0.0), 1.0) * (m - 1)
    i0 = min(int(u), m - 2)
    w = u - i0
    w2, w3 = w * w, w * w * w
    a0, b0, a1, b1 = 2 * w3 - 3 * w2 + 1, w3 - 2 * w2 + w, -2 * w3 + 3 * w2, w3 - w2
    ee = 0.0
    for j in range(d):
        r = a0 * ref[i0, j] + b0 * (dref[i0, j] * hs) + a1 * ref[i0 + 1, j] + b1 * (dref[i0 + 1, j] * hs)
        e = (x[j] - prm[j]) / sc - r
        out[j] = e
        ee += e * e
    end = min(max((1.0 - s) / prm[o + _PHASE_END], 0.0), 1.0)
    if prm[o + _STOP] == 0.0:
        sdot = prm[o + _INV_T] * end
    elif omega < 0.0:
        sdot = prm[o + _INV_T] / (1.0 + ee / prm[o + _EPS2]) * end
    else:   # Eq. (T4b)
        h = 1.0 / (1.0 + ee / prm[o + _EPS2])
        sdot = prm[o + _INV_T] * (h + omega * (1.0 - h)) * end
    da0, db0, da1, db1 = 6 * w2 - 6 * w, 3 * w2 - 4 * w + 1, -6 * w2 + 6 * w, 3 * w2 - 2 * w
    for j in range(d):
        dr = (da0 * ref[i0, j] + db0 * (dref[i0, j] * hs) + da1 * ref[i0 + 1, j]
              + db1 * (dref[i0 + 1, j] * hs)) / hs
        out[j] = (sdot * dr - k * out[j]) * sc
    return sdot


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def nearest_velocity(x: np.ndarray, ref: np.ndarray, dref: np.ndarray, prm: np.ndarray,
                     out: np.ndarray) -> None:  # pragma: no cover - compiled
    """The autonomous view at x (d,), user units (``TrackingModule.forward``): Eq. (T3) at the
    tabulated reference point r(s_j) nearest to x, s_j its phase. out (d,) <- dx/dt, user units.

    ref, dref, prm : as ``phase_velocity``'s.
    """
    m, d = ref.shape
    if x.shape[0] != d or out.shape[0] != d:
        raise ValueError("the point's dimension does not match the field's")
    sc, o = prm[d + _SCALE], d
    xn = np.empty(d)
    for j in range(d):
        xn[j] = (x[j] - prm[j]) / sc
    best, jb = np.inf, 0
    for i in range(m):
        acc = 0.0
        for j in range(d):
            t = ref[i, j] - xn[j]
            acc += t * t
            if acc >= best:   # this point cannot be strictly nearer: the first of equals stays
                break
        if acc < best:
            best, jb = acc, i
    ee = 0.0
    for j in range(d):
        e = xn[j] - ref[jb, j]
        out[j] = e
        ee += e * e
    end = min(max((m - 1 - jb) / ((m - 1) * prm[o + _PHASE_END]), 0.0), 1.0)
    if prm[o + _STOP] == 0.0:
        sdot = prm[o + _INV_T] * end
    else:
        sdot = prm[o + _INV_T] / (1.0 + ee / prm[o + _EPS2]) * end
    for j in range(d):
        out[j] = (sdot * dref[jb, j] - prm[o + _RATE] * out[j]) * sc


def _params(goal: np.ndarray, scale: float, rate: float, eps2: float, inv_t: float, stop: bool,
            phase_end: float) -> np.ndarray:
    """The kernels' prm: goal (d), then s, K, eps^2, 1 / T, phase stopping and c."""
    return np.concatenate([np.asarray(goal, dtype=np.float64),
                           [scale, rate, eps2, inv_t, 1.0 if stop else 0.0, phase_end]]).astype(np.float64)


def _tables(ref: np.ndarray, dref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(ref, dtype=np.float64).copy(), np.ascontiguousarray(dref, dtype=np.float64).copy()


def phase_point_fn(ref: np.ndarray, dref: np.ndarray, goal: np.ndarray, scale: float, rate: float, eps2: float,
                   inv_t: float, stop: bool, phase_end: float,
                   clock_weight: Callable[[np.ndarray], float] | None = None
                   ) -> Callable[[np.ndarray, float], tuple[np.ndarray, float]]:
    """(x (d,), s) -> (dx/dt (d,), ds/dt), user units, Eqs. (T3)-(T4), compiled.

    Parameters
    ----------
    ref, dref : array, shape (M, d)
        r(s_j) and r'(s_j) at s_j = j / (M - 1), normalised units (conditioned on the run's start).
    goal : array, shape (d,)
        The normalisation's goal, user units; ``scale``: its scale s.
    rate, eps2, inv_t : float
        K [1/s], eps^2 and 1 / T [1/s] of Eqs. (T3)-(T4).
    stop : bool
        Phase stopping h of Eq. (T4) (else h = 1).
    phase_end : float
        c of Eq. (T4): the phase slows linearly over its last ``phase_end``.
    clock_weight : callable, optional
        x (d,), user units -> omega in [0, 1]: Eq. (T4b), called once per call in Python (not at
        all without phase stopping, where it changes nothing). None: Eq. (T4) as is.

    Returns
    -------
    callable
        A fresh array and a float per call; reentrant. The kernel is compiled or loaded here, not in
        the first control step.
    """
    ref, dref = _tables(ref, dref)
    prm = _params(goal, scale, rate, eps2, inv_t, stop, phase_end)
    kernel, f64, empty, d = phase_velocity, np.dtype(np.float64), np.empty, ref.shape[1]
    kernel(np.zeros(d), 0.0, ref, dref, prm, NO_CLOCK, empty(d))

    if clock_weight is None or not stop:
        def f(x: np.ndarray, s: float) -> tuple[np.ndarray, float]:
            if type(x) is not np.ndarray or x.dtype is not f64:
                x = np.asarray(x, dtype=np.float64)
            out = empty(d)
            return out, kernel(x, float(s), ref, dref, prm, NO_CLOCK, out)

        return f
    weight = clock_weight

    def f_clock(x: np.ndarray, s: float) -> tuple[np.ndarray, float]:
        if type(x) is not np.ndarray or x.dtype is not f64:
            x = np.asarray(x, dtype=np.float64)
        out = empty(d)
        return out, kernel(x, float(s), ref, dref, prm, float(weight(x)), out)

    return f_clock


def nearest_point_fn(ref: np.ndarray, dref: np.ndarray, goal: np.ndarray, scale: float, rate: float, eps2: float,
                     inv_t: float, stop: bool, phase_end: float) -> Callable[[np.ndarray], np.ndarray]:
    """x (d,) -> dx/dt (d,), user units: the autonomous view (``nearest_velocity``), compiled; the
    parameters as ``phase_point_fn``'s (ref, dref: the mean reference)."""
    ref, dref = _tables(ref, dref)
    prm = _params(goal, scale, rate, eps2, inv_t, stop, phase_end)
    return point_call(nearest_velocity, ref.shape[1], ref.shape[1], ref, dref, prm)
