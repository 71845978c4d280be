"""Metrics that compare a reproduced trajectory with a demonstration, and a field with demo velocities.

Every curve is an array of shape (T, d); a pair of curves may differ in length where the
metric allows it. Every metric is pure numpy/scipy and returns Python floats; rolling a field
out and scoring it (``reproduce``, ``evaluate``, ``converged_fraction``) is ``lfd.evaluation``.

Names and what they measure:

- ``rmse``: time-aligned error, sensitive to timing.
- ``dtw``: dynamic time warping distance (a SUM of point distances along the best monotone
  alignment), insensitive to timing, sensitive to direction.
- ``chamfer_dtwd``: closest-point (Chamfer) distance, the quantity some papers call "DTWD";
  it ignores order entirely, so it is NOT dynamic time warping.
- ``dtw_per_sample``: ``dtw`` over all samples divided by the demo's sample count (CONDOR, PUMA).
- ``chamfer_dtwd_std``: ``chamfer_dtwd`` on data divided by its standard deviation (ELCD, NCDS).
- ``frechet``: discrete Frechet distance (the "dog leash" length), a max, not a sum.
- ``swept_area``: swept error area between two planar curves (LASA literature), each crossed
  quadrilateral counted as the sum of its two lobes (never under-counts).
- ``grid_starts`` / ``spurious_attractor_fraction``: the 35 x 35 grid of starts of CONDOR/PUMA.
- ``velocity_rmse`` / ``cosine_error``: field values against demo velocities.
- ``final_goal_distance`` / ``convergence_rate``: reaching the goal.
- ``PER_DEMO_METRICS``: the names ``lfd.evaluation.evaluate`` scores per demo.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

__all__ = [
    "PER_DEMO_METRICS", "chamfer_dtwd", "chamfer_dtwd_std", "convergence_rate", "cosine_error", "dtw",
    "dtw_per_sample", "dtw_step_for", "final_goal_distance", "frechet", "grid_starts", "resample", "rmse",
    "spurious_attractor_fraction", "swept_area", "velocity_rmse",
]


def _curve(a: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] < 1:
        raise ValueError(f"{name} must have shape (T, d) with T >= 1, got {a.shape}")
    return a


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = _curve(a, "a"), _curve(b, "b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"curves differ in dimension: {a.shape} vs {b.shape}")
    return a, b


def resample(x: np.ndarray, n: int) -> np.ndarray:
    """Resample a curve to ``n`` samples, linearly in sample index (not in arc length or time).

    Sample k of the result is x interpolated at fractional index k (T - 1) / (n - 1).
    x : array, shape (T, d); returns shape (n, d).
    """
    x = _curve(x, "x")
    if x.shape[0] == n:
        return x
    if x.shape[0] == 1:
        return np.repeat(x, n, axis=0)
    s = np.linspace(0.0, x.shape[0] - 1.0, n)
    k = np.arange(x.shape[0])
    return np.stack([np.interp(s, k, x[:, j]) for j in range(x.shape[1])], axis=1)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Time-aligned root-mean-square error: sqrt( (1/T) sum_k |a_k - b_k|^2 ).

    a : array, shape (T, d); b : array, shape (T', d). If T' != T, b is first resampled to T
    samples linearly in sample index (see ``resample``), i.e. both curves are assumed to span
    the same time interval.
    """
    a, b = _pair(a, b)
    b = resample(b, a.shape[0])
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _antidiagonal_dp(c: np.ndarray, combine: str) -> float:
    """The value D[n, m] of the classic warping recursion over a cost matrix c, shape (n, m):

    D[i, j] = c[i, j] (+ or max) min(D[i-1, j-1], D[i-1, j], D[i, j-1]),  D[0, 0] = c[0, 0],
    with ``combine`` "sum" (DTW) or "max" (discrete Frechet).

    Cells on one anti-diagonal i + j = s depend only on the two previous anti-diagonals, so each
    diagonal is one vector operation. On the padded (n+1, m+1) table stored flat with row length
    m + 1, cell (i, s - i) sits at flat index i m + s: an anti-diagonal is a strided slice.
    """
    n, m = c.shape
    w = m + 1
    D = np.full((n + 1) * w, np.inf)
    C = np.zeros((n + 1) * w)
    C.reshape(n + 1, w)[1:, 1:] = c
    D[0] = 0.0 if combine == "sum" else -np.inf  # padded origin: D[1, 1] = c[0, 0]
    op = np.add if combine == "sum" else np.maximum
    for s in range(2, n + m + 1):
        i0, i1 = max(1, s - m), min(n, s - 1)
        cur = slice(i0 * m + s, i1 * m + s + 1, m)
        diag = slice(cur.start - w - 1, cur.stop - w - 1, m)
        up = slice(cur.start - w, cur.stop - w, m)
        left = slice(cur.start - 1, cur.stop - 1, m)
        best = np.minimum(np.minimum(D[diag], D[up]), D[left])
        D[cur] = op(C[cur], best)
    return float(D[n * w + m])


MAX_DP_CELLS = 50_000_000   # a warping table beyond this (3 float64 arrays: 1.2 GB) is refused
MAX_DTW_CELLS = 4_000_000   # ``evaluate`` subsamples its DTW and Frechet curves to stay below this


def _check_table(n: int, m: int) -> None:
    """ValueError before allocating an n x m distance or warping table beyond MAX_DP_CELLS."""
    if n * m > MAX_DP_CELLS:
        raise ValueError(f"a {n} x {m} warping table is too large (limit {MAX_DP_CELLS} cells); "
                         "subsample the curves (dtw's step)")


def dtw_step_for(n: int, m: int, step: int = 1) -> int:
    """The smallest stride k >= step with ceil(n / k) ceil(m / k) <= MAX_DTW_CELLS: the DTW step
    ``evaluate`` uses for curves of n and m samples (subsampled DTW where the full matrix is too big)."""
    k = max(int(step), 1)
    while -(-n // k) * -(-m // k) > MAX_DTW_CELLS:
        k += 1
    return k


def dtw(a: np.ndarray, b: np.ndarray, step: int = 1) -> float:
    """Dynamic time warping distance: the minimum, over monotone warping paths, of the SUM of
    Euclidean point distances.

    DTW(a, b) = min_P sum_{(i, j) in P} |a_i - b_j|, where P runs from (0, 0) to (n-1, m-1) by
    steps (1, 0), (0, 1) or (1, 1). Computed by the classic O(n m) recursion
    D[i, j] = |a_i - b_j| + min(D[i-1, j-1], D[i-1, j], D[i, j-1]), vectorised by anti-diagonals.
    ``step`` > 1 first keeps every step-th sample, a[::step] and b[::step] (the LASA protocol
    uses step = 4). a : array, shape (n, d); b : array, shape (m, d). Not normalised by length:
    two curves a constant distance c apart with n = m samples, aligned, give n c.
    """
    if step < 1:
        raise ValueError(f"step must be >= 1, got {step}")
    a, b = _pair(a, b)
    a, b = a[::step], b[::step]
    _check_table(len(a), len(b))
    return _antidiagonal_dp(cdist(a, b), "sum")


def dtw_path(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The optimal warping path of ``dtw(a, b)`` (step 1): pairs (i, j) from (0, 0) to
    (n - 1, m - 1) by steps (1, 0), (0, 1), (1, 1), minimising sum |a_i - b_j|.

    Each row of the accumulated cost D[i, j] = c_ij + min(D[i-1, j-1], D[i-1, j], D[i, j-1]) is one
    prefix-minimum: with S_j = sum_{l <= j} c_il and e_j = c_ij + min(D[i-1, j-1], D[i-1, j]),
    D[i, j] = S_j + min_{k <= j} (e_k - S_k). The path is traced back from (n - 1, m - 1), the
    diagonal step preferred on ties.

    Parameters
    ----------
    a : array, shape (n, d)
    b : array, shape (m, d)

    Returns
    -------
    array of int, shape (L, 2)
        The aligned index pairs in order, n, m <= L <= n + m - 1.
    """
    c = cdist(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    n, m = c.shape
    acc = np.empty((n, m))
    prev = np.full(m, np.inf)
    for i in range(n):
        s = np.cumsum(c[i])
        above = np.minimum(prev, np.concatenate([[np.inf if i else 0.0], prev[:-1]]))
        acc[i] = s + np.minimum.accumulate(c[i] + above - s)
        prev = acc[i]
    i, j = n - 1, m - 1
    path = [(i, j)]
    while i or j:
        steps = [(i - 1, j - 1), (i - 1, j), (i, j - 1)]
        i, j = min((p for p in steps if p[0] >= 0 and p[1] >= 0), key=lambda p: acc[p])
        path.append((i, j))
    return np.array(path[::-1], dtype=int)


def frechet(a: np.ndarray, b: np.ndarray) -> float:
    """Discrete Frechet distance (Eiter & Mannila 1994): the shortest leash over monotone couplings.

    F(a, b) = min_P max_{(i, j) in P} |a_i - b_j|, by the recursion
    ca[i, j] = max(|a_i - b_j|, min(ca[i-1, j-1], ca[i-1, j], ca[i, j-1])).
    a : array, shape (n, d); b : array, shape (m, d).
    """
    a, b = _pair(a, b)
    _check_table(len(a), len(b))
    return _antidiagonal_dp(cdist(a, b), "max")


def chamfer_dtwd(a: np.ndarray, b: np.ndarray) -> float:
    """Closest-point (Chamfer) distance, the "DTWD" of some LfD papers. Not dynamic time warping.

    chamfer(a, b) = (1/n) sum_i min_j |a_i - b_j| + (1/m) sum_j min_i |a_i - b_j|,
    the mean distance from each point of a to the curve b plus the same from b to a. It ignores
    the order of samples, so a curve and its reversal score 0. a : (n, d); b : (m, d).
    """
    a, b = _pair(a, b)
    return float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


def dtw_per_sample(a: np.ndarray, b: np.ndarray) -> float:
    """DTW divided by the number of samples, the "DTW" of CONDOR and PUMA:

    .. math::

        \\mathrm{DTW}_{ps}(a, b) = \\mathrm{DTW}(a, b) / m

    with DTW the summed distance of ``dtw`` over ALL samples (no stride) and m the number of
    samples of b, the demonstration (CONDOR divides ``similaritymeasures.dtw(y, x)[0]`` by the
    demo's length). a : array, shape (n, d); b : array, shape (m, d). Units: those of the curves.
    """
    a, b = _pair(a, b)
    return dtw(a, b) / b.shape[0]


def chamfer_dtwd_std(a: np.ndarray, b: np.ndarray, std: np.ndarray | None = None) -> float:
    """Closest-point (Chamfer) distance on standard-deviation-normalised data, the "DTWD" of
    ELCD and NCDS:

    .. math::

        \\mathrm{chamfer}_\\sigma(a, b) = \\mathrm{chamfer}(a \\oslash \\sigma, b \\oslash \\sigma)

    with ``chamfer_dtwd`` (mean closest-point distance from a to b plus from b to a) and every
    point divided element-wise by sigma, shape (d,), the per-coordinate standard deviation of
    the data set (the benchmark passes the std over all demo samples of the shape; default: the
    std of b's samples). Dimensionless. a : (n, d); b : (m, d).
    """
    a, b = _pair(a, b)
    sigma = b.std(axis=0) if std is None else np.asarray(std, dtype=np.float64)
    if sigma.shape != (a.shape[1],) or not np.all(sigma > 0):
        raise ValueError(f"std must have shape ({a.shape[1]},) and be positive, got {sigma}")
    return chamfer_dtwd(a / sigma, b / sigma)


def swept_area(a: np.ndarray, b: np.ndarray) -> float:
    """Swept error area between two planar curves, every region between them counted positive
    (the LASA literature: Khansari-Zadeh & Billard 2011, doi:10.1109/TRO.2011.2159412).

    E = sum_{k=0}^{T-2} A(a_k, a_{k+1}, b_{k+1}, b_k), A the area of that quadrilateral: the shoelace
    formula for a simple one; a crossed ("bow-tie") one is split into its two lobes (triangles) at the
    crossing of the curve segments a_k a_{k+1} and b_k b_{k+1} (the curves swap sides) or of the rungs
    a_{k+1} b_{k+1} and b_k a_k (they run in opposite directions), and their absolute areas added.
    The sum of lobes never under-counts; the plain shoelace value of a bow-tie is the DIFFERENCE of
    its lobes, and ``similaritymeasures.area_between_two_curves`` also counts the triangles between
    them (tests/test_lasa_metrics.py).

    Parameters
    ----------
    a : array, shape (T, 2)
        First curve (e.g. the reproduction).
    b : array, shape (T', 2)
        Second curve; resampled to T samples in sample index if T' != T (see ``resample``).

    Returns
    -------
    float
        E, in the curves' units squared.
    """
    a, b = _pair(a, b)
    if a.shape[1] != 2:
        raise ValueError(f"swept area needs 2-D curves, got dimension {a.shape[1]}")
    b = resample(b, a.shape[0])
    return float(np.sum(_quad_areas(a[:-1], a[1:], b[1:], b[:-1])))


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """z of u x v for arrays of 2-D vectors, shape (..., 2) -> (...)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _tri(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Unsigned triangle areas, each argument of shape (K, 2) -> (K,)."""
    return 0.5 * np.abs(_cross(q - p, r - p))


def _crossing(p: np.ndarray, p2: np.ndarray, q: np.ndarray, q2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where segments p p2 and q q2, shape (K, 2) each, cross in their interiors: a mask, shape
    (K,), and the crossing points, shape (K, 2) (meaningless where the mask is False)."""
    r, s, w = p2 - p, q2 - q, q - p
    den = _cross(r, s)
    ok = den != 0
    safe = np.where(ok, den, 1.0)
    t, u = _cross(w, s) / safe, _cross(w, r) / safe
    hit = ok & (t > 0) & (t < 1) & (u > 0) & (u < 1)
    return hit, p + t[:, None] * r


def _quad_areas(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, p4: np.ndarray) -> np.ndarray:
    """Area enclosed by each quadrilateral p1 p2 p3 p4, a crossed one counted as the sum of its
    two lobes (see ``swept_area``). Each argument has shape (K, 2); returns shape (K,)."""
    x = np.stack([p1, p2, p3, p4], axis=1)                       # (K, 4, 2)
    area = 0.5 * np.abs(_cross(x, np.roll(x, -1, axis=1)).sum(axis=1))
    hit, X = _crossing(p1, p2, p4, p3)                           # the curve segments cross
    area = np.where(hit, _tri(p1, X, p4) + _tri(X, p2, p3), area)
    hit2, Y = _crossing(p2, p3, p4, p1)                          # the rungs cross
    return np.where(hit2 & ~hit, _tri(p1, p2, Y) + _tri(Y, p3, p4), area)


def velocity_rmse(field_values: np.ndarray, demo_velocities: np.ndarray) -> float:
    """sqrt( (1/K) sum_k |f(x_k) - v_k|^2 ).

    field_values : array, shape (K, d), f evaluated at the demo positions;
    demo_velocities : array, shape (K, d). Leading axes (e.g. (N, T, d)) are flattened.
    """
    f, v = _velocity_pair(field_values, demo_velocities)
    return float(np.sqrt(np.mean(np.sum((f - v) ** 2, axis=1))))


def cosine_error(field_values: np.ndarray, demo_velocities: np.ndarray,
                 min_speed: float = 1e-3) -> float:
    """Mean direction error (1/K) sum_k (1 - cos theta_k), cos theta_k = <f_k, v_k> / (|f_k| |v_k|).

    Ranges over [0, 2]: 0 for the same direction, 1 for perpendicular (or a zero field value),
    2 for opposite. Points where the demo is at rest, |v_k| <= min_speed max_j |v_j|, have no
    direction and are left out (e.g. the samples at the goal); a demo that never moves gives nan.
    Shapes as ``velocity_rmse``.
    """
    f, v = _velocity_pair(field_values, demo_velocities)
    vn, fn = np.linalg.norm(v, axis=1), np.linalg.norm(f, axis=1)
    keep = vn > min_speed * vn.max() if vn.max() > 0 else np.zeros(len(vn), bool)
    if not keep.any():
        return float("nan")
    denom = np.maximum(fn[keep] * vn[keep], np.finfo(float).tiny)
    cos = np.einsum("kd,kd->k", f[keep], v[keep]) / denom
    return float(np.mean(1.0 - np.clip(cos, -1.0, 1.0)))


def _velocity_pair(f: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f, v = np.asarray(f, dtype=np.float64), np.asarray(v, dtype=np.float64)
    if f.shape != v.shape or f.ndim < 1:
        raise ValueError(f"field values {f.shape} and demo velocities {v.shape} differ in shape")
    return f.reshape(-1, f.shape[-1]), v.reshape(-1, v.shape[-1])


def final_goal_distance(traj: np.ndarray, goal: np.ndarray) -> float | np.ndarray:
    """|x_{T-1} - goal|: distance of a trajectory's last sample to the goal.

    traj : array, shape (T, d) -> float, or (B, T, d) -> array, shape (B,); goal : shape (d,).
    """
    traj = np.asarray(traj, dtype=np.float64)
    dist = np.linalg.norm(traj[..., -1, :] - np.asarray(goal, dtype=np.float64), axis=-1)
    return float(dist) if traj.ndim == 2 else dist


def convergence_rate(final_points: np.ndarray, goal: np.ndarray, radius: float) -> float:
    """Fraction of rollouts whose final point lies within ``radius`` of the goal:
    (1/B) #{b : |x_b - goal| <= radius}; non-finite points count as not converged.

    final_points : array, shape (B, d); goal : array, shape (d,).
    """
    x = np.asarray(final_points, dtype=np.float64).reshape(-1, np.shape(goal)[-1])
    dist = np.linalg.norm(x - np.asarray(goal, dtype=np.float64), axis=1)
    return float(np.mean(np.isfinite(dist) & (dist <= radius)))


def grid_starts(lo: np.ndarray, hi: np.ndarray, n: int = 35) -> np.ndarray:
    """The n x n grid of starts over the 2-D box [lo, hi], corners included, shape (n^2, 2),
    x varying fastest: start (i n + j) = (lo_x + j (hi_x - lo_x) / (n - 1), lo_y + i (...)).
    lo, hi : array, shape (2,)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if lo.shape != (2,) or hi.shape != (2,) or n < 2:
        raise ValueError(f"grid_starts needs 2-D corners and n >= 2, got {lo.shape}, {hi.shape}, n={n}")
    xx, yy = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


def spurious_attractor_fraction(final_points: np.ndarray, goal: np.ndarray, radius: float) -> float:
    """Fraction of rollouts that do NOT reach the goal, 1 - ``convergence_rate``: with the final
    points of rollouts from the 35 x 35 ``grid_starts`` over the demos' box, the spurious-attractor
    measure of CONDOR and PUMA. final_points : (B, d); goal : (d,)."""
    return 1.0 - convergence_rate(final_points, goal, radius)


PER_DEMO_METRICS: tuple[str, ...] = (
    "rmse", "dtw", "chamfer_dtwd", "frechet", "swept_area", "velocity_rmse", "cosine_error",
    "final_goal_distance",
)
