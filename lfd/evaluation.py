"""Evaluation: roll a field out from the demos' starts (or a box of starts) and score it with
``lfd.metrics``.

``lfd.metrics`` holds the metrics themselves (pure numpy/scipy on given curves); this module is
the orchestration that produces the curves first, through ``lfd.integrate``:

- ``reproduce``: the field's reproduction of every demo, on that demo's time grid;
- ``evaluate``: every per-demo metric of ``PER_DEMO_METRICS`` on those reproductions;
- ``converged_fraction``: the fraction of random starts in a box that reach the goal.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from lfd import integrate
from lfd.metrics import (
    PER_DEMO_METRICS,
    chamfer_dtwd,
    convergence_rate,
    cosine_error,
    dtw,
    dtw_step_for,
    final_goal_distance,
    frechet,
    rmse,
    swept_area,
    velocity_rmse,
)

if TYPE_CHECKING:
    from lfd.demos import DemoSet
    from lfd.field import VelocityField

__all__ = ["converged_fraction", "evaluate", "reproduce"]


def converged_fraction(field: VelocityField, lo: np.ndarray, hi: np.ndarray, n: int,
                       horizon: float, radius: float, seed: int = 0, n_steps: int = 200,
                       method: str = "rk4") -> float:
    """Fraction of n starts drawn uniformly in the box [lo, hi] (seeded) whose rollout of the
    field ends within ``radius`` of ``field.goal`` after ``horizon`` seconds.

    Starts x0 ~ U(lo, hi), shape (n, d), from ``np.random.default_rng(seed)``; rollouts over
    t = linspace(0, horizon, n_steps) with ``field.rollout``; then ``lfd.metrics.convergence_rate``.
    lo, hi : array, shape (d,).
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if lo.shape != (field.dim,) or hi.shape != (field.dim,):
        raise ValueError(f"box corners must have shape ({field.dim},), got {lo.shape} and {hi.shape}")
    x0 = np.random.default_rng(seed).uniform(lo, hi, size=(n, field.dim))
    with np.errstate(all="ignore"):
        y = field.rollout(x0, np.linspace(0.0, horizon, n_steps), method=method)
    return convergence_rate(y[:, -1], field.goal, radius)


def reproduce(field: VelocityField, demos: DemoSet, method: str = "rk4") -> np.ndarray:
    """Roll the field out from each demo's start over that demo's time grid.

    y_i = rollout(x_i[0], t_i), shape (T, d), for each demo i. Demos that share a time grid
    (t_i - t_i[0] equal) are integrated in one batch by ``field.rollout``. Demos on different
    uniform grids t_i[k] = t_i[0] + k h_i (LASA) are batched too for an autonomous field (whose
    rollout is Eq. (5) through ``lfd.integrate``; a phased or time-varying one carries its phase or
    time as well) and a one-step fixed-step method (``lfd.integrate.rollout_sample_units``).
    Returns shape (N, T, d); a diverging rollout holds inf/nan.
    """
    from lfd.field import FieldKind, by_kind  # imports torch and pinocchio

    rel = demos.t - demos.t[:, :1]
    h = rel[:, 1:2]
    k = np.arange(demos.n_samples)
    uniform = np.allclose(rel, h * k, rtol=0.0, atol=1e-9 * float(rel.max()))
    solver = integrate.check_method(method)
    own_grids = by_kind(field, {FieldKind.AUTONOMOUS: True, FieldKind.PHASED: False, FieldKind.TIME_VARYING: False})
    if uniform and not solver.adaptive and solver.one_step and own_grids:
        return integrate.rollout_sample_units(field, demos.x[:, 0], h, demos.n_samples, method)
    out = np.empty_like(demos.x)
    todo = list(range(demos.n_demos))
    with np.errstate(all="ignore"):
        while todo:
            same = [j for j in todo if np.array_equal(rel[j], rel[todo[0]])]
            out[same] = field.rollout(demos.x[same, 0], rel[todo[0]], method=method)
            todo = [j for j in todo if j not in same]
    return out


def evaluate(field: VelocityField, demos: DemoSet, dtw_step: int = 1,
             method: str = "rk4") -> dict[str, Any]:
    """Score the field's reproductions of the demos (``reproduce``) against the demos.

    For demo i with positions x_i, shape (T, d), and reproduction y_i, shape (T, d): position
    metrics compare y_i with x_i, velocity metrics compare f(x_i) with the demo's smoothed
    velocity, and final_goal_distance is |y_i[T-1] - demos.goal|. ``swept_area`` is reported
    for 2-D demos only. Returns {"per_demo": [{metric: float}] * N, "mean": {metric: float}};
    a diverged rollout scores inf on every position metric, and the mean carries it along.
    DTW and Frechet run on every k-th sample, k = ``dtw_step_for(T, T, dtw_step)``: ``dtw_step``
    unless the full T x T table would exceed ``lfd.metrics.MAX_DTW_CELLS``.
    """
    if demos.dim != field.dim:
        raise ValueError(f"demos are {demos.dim}-D but the field is {field.dim}-D")
    names = [m for m in PER_DEMO_METRICS if m != "swept_area" or demos.dim == 2]
    ys = reproduce(field, demos, method)
    with np.errstate(all="ignore"):
        fs = field(demos.x)
    rows: list[dict[str, float]] = []
    for x, xd, y, f in zip(demos.x, demos.xd, ys, fs):
        row = {"velocity_rmse": velocity_rmse(f, xd), "cosine_error": cosine_error(f, xd)}
        if np.isfinite(y).all():
            k = dtw_step_for(len(y), len(x), dtw_step)
            row.update(rmse=rmse(y, x), dtw=dtw(y, x, step=k), chamfer_dtwd=chamfer_dtwd(y, x),
                       frechet=frechet(y[::k] if k > 1 else y, x[::k] if k > 1 else x),
                       final_goal_distance=float(final_goal_distance(y, demos.goal)))
            if demos.dim == 2:
                row["swept_area"] = swept_area(y, x)
        else:
            row.update({m: float("inf") for m in names if m not in row})
        rows.append({m: float(row[m]) for m in names})
    mean = {m: float(np.mean([r[m] for r in rows])) for m in names}
    return {"per_demo": rows, "mean": mean}
