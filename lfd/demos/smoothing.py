"""Savitzky-Golay smoothing in numpy, and the demos' velocities by smoothed differences.

``savgol`` gives the values of ``scipy.signal.savgol_filter(x, window, order, axis=0)`` (its default
mode "interp") without importing ``scipy.signal``, which takes seconds: in the interior the
precomputed convolution of the least-squares polynomial of degree ``order`` over ``window`` samples,
and within half a window of each end that polynomial fitted to the first (last) ``window`` samples.
Its sums run in SciPy's order, so that the demos' velocities are SciPy's to the last bit.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

VELOCITY_WINDOW = 9   # samples of the cubic Savitzky-Golay fit behind the demos' velocities
VELOCITY_ORDER = 3


@lru_cache(maxsize=64)
def savgol_coefficients(window: int, order: int) -> np.ndarray:
    """The smoothing weights c_j, shape (window,), of the least-squares polynomial of degree ``order``
    over ``window`` (odd) samples evaluated at the middle one: y_k = sum_j c_j x_(k + j - window // 2).
    Read-only (cached)."""
    half = window // 2
    u = np.arange(-half, window - half, dtype=np.float64)
    a = u ** np.arange(order + 1, dtype=np.float64).reshape(-1, 1)           # (order + 1, window)
    e0 = np.zeros(order + 1)
    e0[0] = 1.0
    c = np.linalg.lstsq(a, e0, rcond=None)[0]
    c.setflags(write=False)
    return c


def savgol(x: np.ndarray, window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing along axis 0.

    Parameters
    ----------
    x : array, shape (T, ...)
        Samples, uniformly spaced (the filter assumes so).
    window : int
        Odd number of samples of each fit, order < window <= T.
    order : int
        Degree of the fitted polynomial.

    Returns
    -------
    array, shape (T, ...)
        The smoothed samples.
    """
    x = np.asarray(x, dtype=np.float64)
    T = x.shape[0]
    if window % 2 != 1 or not order < window <= T:
        raise ValueError(f"savgol needs an odd window with order < window <= T, got window={window}, "
                         f"order={order}, T={T}")
    w = savgol_coefficients(window, order)[::-1]                         # as a convolution takes them
    half = window // 2
    flat = x.reshape(T, -1)
    y = np.empty_like(flat)
    inner = T - 2 * half
    # the symmetric weights summed pairwise from the outside in, the order of SciPy's convolve1d
    acc = flat[half:half + inner] * w[half]
    for j in range(half, 0, -1):
        acc += (flat[half - j:half - j + inner] + flat[half + j:half + j + inner]) * w[half - j]
    y[half:T - half] = acc
    u = np.arange(window, dtype=np.float64)
    for first, at in ((0, u[:half]), (T - window, u[window - half:])):
        poly = np.polyfit(u, flat[first:first + window], order)            # (order + 1, columns)
        value = np.zeros((len(at), flat.shape[1]))
        for coefficient in poly:                                           # Horner, highest power first
            value = value * at[:, None] + coefficient
        y[first + at.astype(int)] = value
    return y.reshape(x.shape)


def smoothed_velocity(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Velocity by smoothed differences (demos are noisy samples of the paper's Eq. (1)).

    A Savitzky-Golay filter (window 9, cubic) smooths each coordinate, then second-order
    central differences dx/dt ~ (x[k+1] - x[k-1]) / (t[k+1] - t[k-1]) give the velocity.
    t : array, shape (T,); x : array, shape (T, d); returns shape (T, d).
    """
    window = min(VELOCITY_WINDOW, len(t) - (1 - len(t) % 2))
    xs = savgol(x, window, VELOCITY_ORDER) if window > VELOCITY_ORDER else x
    return np.gradient(xs, t, axis=0)
