"""The roots of f(x) = 0 in a box: seeds, damped Newton from each, central-difference Jacobians, and
merging the roots found more than once (docs/equations.md, Eqs. (E1)-(E2))."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

PointsFn = Callable[[np.ndarray], np.ndarray]

#: seeds per axis of the full grid, by dimension; above 3 dimensions a Sobol sequence of ``SOBOL_SEEDS``
GRID_PER_AXIS = {1: 101, 2: 16, 3: 7}
SOBOL_SEEDS = 512
JACOBIAN_STEP = 5e-6       # central differences: h_k = JACOBIAN_STEP (hi_k - lo_k), Eq. (E2)
NEWTON_ITERATIONS = 60
BACKTRACK = 8              # step fractions 1, 1/2, ..., 2^-(BACKTRACK - 1) tried at once
MAX_STEP = 0.5             # a Newton step moves at most half the box's size on each axis
ARMIJO = 1e-4
RADIUS_PERCENTILE = 95    # of the spectral radii of J at the seeds (a jump of f across a cell makes a few huge)
REGULARISATION = 1e-12     # Levenberg-Marquardt mu = REGULARISATION max eig(J'J): Newton where J is regular


def seeds(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, str]:
    """The starts of the search in the box [lo, hi], each shape (d,): a full grid of
    ``GRID_PER_AXIS[d]`` points per axis (corners included) up to d = 3, else ``SOBOL_SEEDS`` points of
    a scrambled Sobol sequence (seed 0: a full grid is out of reach in 6 dimensions).

    Returns (points (P, d), "grid" or "sobol").
    """
    d = lo.shape[0]
    if d in GRID_PER_AXIS:
        axes = [np.linspace(a, b, GRID_PER_AXIS[d]) for a, b in zip(lo, hi)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d), "grid"
    from scipy.stats import qmc  # scipy's start-up only where a Sobol sequence is needed

    u = qmc.Sobol(d, scramble=True, seed=0).random(SOBOL_SEEDS)
    return lo + u * (hi - lo), "sobol"


def evaluate(f: PointsFn, x: np.ndarray) -> np.ndarray:
    """f at the points x, shape (P, d) -> (P, d); rows that are not finite come back as NaN."""
    if len(x) == 0:
        return np.empty_like(x)
    with np.errstate(all="ignore"):
        out = np.asarray(f(x), dtype=np.float64).reshape(x.shape)
    return np.where(np.isfinite(out).all(1, keepdims=True), out, np.nan)


def jacobians(f: PointsFn, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """J_f at the points x, shape (P, d) -> (P, d, d), by central differences with steps h (d,), Eq. (E2):
    J[:, :, k] = (f(x + h_k e_k) - f(x - h_k e_k)) / (2 h_k), all 2 d P points in one call of f."""
    p, d = x.shape
    shifts = np.diag(h)                                            # (d, d): row k is h_k e_k
    pts = np.concatenate([x[:, None, :] + shifts[None], x[:, None, :] - shifts[None]], axis=1)  # (P, 2d, d)
    v = evaluate(f, pts.reshape(-1, d)).reshape(p, 2 * d, d)
    return np.swapaxes((v[:, :d] - v[:, d:]) / (2.0 * h[:, None]), 1, 2)


def newton(f: PointsFn, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, ftol: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Damped Newton on f(x) = 0 from every start at once, Eq. (E1).

    Each step solves (J'J + mu I) dx = -J' f (Newton where J is regular), caps dx at ``MAX_STEP`` of the
    box on each axis, and takes the largest fraction 2^-k of it that decreases |f| by the Armijo
    factor (else the one that decreases it most); a start stops when |f| <= ftol, when no fraction
    decreases |f|, or when it leaves the box grown by its size on every side.

    Parameters
    ----------
    f : callable
        The field on points, (P, d) -> (P, d), user units.
    x0 : array, shape (P, d)
        The starts.
    lo, hi : arrays, shape (d,)
        The box.
    ftol : float
        |f| at a root, user units/s.

    Returns
    -------
    (x (P, d), |f(x)| (P,), converged (P,) bool, the ``RADIUS_PERCENTILE`` percentile of the
        spectral radii of J at the starts, 1/s)
    """
    width = hi - lo
    h = JACOBIAN_STEP * width
    x = np.array(x0, dtype=np.float64)
    fx = evaluate(f, x)
    r = np.linalg.norm(fx, axis=1)
    done = ~np.isfinite(r) | (r <= ftol)
    radius = 0.0
    alphas = 2.0 ** -np.arange(BACKTRACK)
    for it in range(NEWTON_ITERATIONS):
        idx = np.flatnonzero(~done)
        if len(idx) == 0:
            break
        xa, fa, ra = x[idx], fx[idx], r[idx]
        jac = jacobians(f, xa, h)
        if it == 0:
            with np.errstate(all="ignore"):
                eig = np.abs(np.linalg.eigvals(np.nan_to_num(jac)))
            eig = eig[np.isfinite(eig)]
            radius = float(np.percentile(eig, RADIUS_PERCENTILE)) if len(eig) else 0.0
        step = _lm_step(np.nan_to_num(jac), fa)
        step /= np.maximum(1.0, np.abs(step / width).max(1) / MAX_STEP)[:, None]
        cand = xa[None] + alphas[:, None, None] * step[None]                    # (BACKTRACK, n, d)
        fc = evaluate(f, cand.reshape(-1, x.shape[1])).reshape(cand.shape)
        rc = np.linalg.norm(fc, axis=2)
        rc[~np.isfinite(rc)] = np.inf
        armijo = rc <= (1.0 - ARMIJO * alphas[:, None]) * ra[None]
        pick = np.where(armijo.any(0), armijo.argmax(0), rc.argmin(0))
        cols = np.arange(len(idx))
        rn = rc[pick, cols]
        better = rn < ra
        moved = idx[better]
        x[moved], fx[moved], r[moved] = cand[pick, cols][better], fc[pick, cols][better], rn[better]
        far = ((x[idx] < lo - width) | (x[idx] > hi + width)).any(1)
        done[idx[~better | far | (r[idx] <= ftol)]] = True
    return x, r, r <= ftol, radius


def _lm_step(jac: np.ndarray, fx: np.ndarray) -> np.ndarray:
    """dx = -(J'J + mu I)^-1 J' f for each point: jac (n, d, d), fx (n, d) -> (n, d)."""
    jt = np.swapaxes(jac, 1, 2)
    jtj = jt @ jac
    d = jac.shape[1]
    mu = REGULARISATION * np.maximum(np.trace(jtj, axis1=1, axis2=2), 1e-300)
    a = jtj + mu[:, None, None] * np.eye(d)
    return -np.linalg.solve(a, (jt @ fx[..., None]))[..., 0]


def merge(points: np.ndarray, radius: float) -> np.ndarray:
    """The distinct points of ``points`` (P, d): each kept one is the first of those within ``radius``
    of it. Returns shape (K, d)."""
    kept: list[np.ndarray] = []
    for p in points:
        if all(float(np.linalg.norm(p - q)) > radius for q in kept):
            kept.append(p)
    return np.array(kept).reshape(-1, points.shape[1])


def eigenvalues(f: PointsFn, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The eigenvalues of J_f at the points x (K, d), by ``jacobians``; shape (K, d) complex, sorted by real part."""
    if len(x) == 0:
        return np.empty((0, x.shape[1]), dtype=complex)
    jac = jacobians(f, x, JACOBIAN_STEP * (hi - lo))
    out = np.full(x.shape, math.nan, dtype=complex)
    ok = np.isfinite(jac).all((1, 2))
    if ok.any():
        ev = np.linalg.eigvals(jac[ok])
        order = np.lexsort((ev.imag, ev.real), axis=1)
        out[ok] = np.take_along_axis(ev, order, axis=1)
    return out
