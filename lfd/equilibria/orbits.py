"""Long rollouts of a field's autonomous view from many starts, and where they end: still, escaped,
or moving on a closed orbit, found by recurrence (docs/equations.md, Eqs. (E3)-(E4))."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfd.equilibria.roots import PointsFn, evaluate

WINDOW = 0.25          # the last quarter of the horizon is kept to judge how a rollout ends
RETURN_AWAY = 0.5      # Eq. (E4): a recurrence first goes away by half the window's reach ...
RETURN_NEAR = 0.05     # ... then comes back within 5% of it (or two steps' travel)
PATH_POINTS = 120      # points kept along one period of an orbit


@dataclass
class Rollouts:
    """Where rollouts from P starts end.

    end : (P, d) the last points (NaN where not finite); travel : (P,) the path length over the
    window, user units; escaped : (P,) left the box grown by its size, or not finite; window : (P, K, d)
    the points of the window; t : (K,) their times, s; step : (P,) the longest step in the window.
    """

    end: np.ndarray
    travel: np.ndarray
    escaped: np.ndarray
    window: np.ndarray
    t: np.ndarray
    step: np.ndarray


def rollout(f: PointsFn, x0: np.ndarray, horizon: float, steps: int, lo: np.ndarray, hi: np.ndarray,
            sinks: np.ndarray, settle: float, far: tuple[np.ndarray, np.ndarray] | None = None) -> Rollouts:
    """Classic RK4 (the paper's Eq. (8)) of dx/dt = f(x) from every start at once over ``horizon`` s in
    ``steps`` steps, Eq. (E3). A start that leaves the box [lo, hi] grown by its size on every side (or
    stops being finite) is frozen there and marked escaped; one within ``settle`` of one of the
    ``sinks`` (K, d) (attractors: the goal, the roots found) stays there. x0 : (P, d); lo, hi : (d,);
    far : the (lo, hi) a start escapes by leaving, instead of the box grown by its size."""
    width = hi - lo
    far_lo, far_hi = (lo - width, hi + width) if far is None else far
    x = np.array(x0, dtype=np.float64)
    p, d = x.shape
    dt = horizon / steps
    first = steps - max(2, int(round(WINDOW * steps)))
    window = np.full((p, steps - first + 1, d), np.nan)
    escaped = np.zeros(p, dtype=bool)
    settled = np.zeros(p, dtype=bool)
    for k in range(steps + 1):
        if k >= first:
            window[:, k - first] = x
        if k == steps:
            break
        if len(sinks):
            settled |= (np.linalg.norm(x[:, None] - sinks[None], axis=2) <= settle).any(1)
        live = np.flatnonzero(~escaped & ~settled)
        if len(live) == 0:
            window[:, k - first + 1 if k >= first else 0:] = x[:, None]
            break
        xa = x[live]
        k1 = evaluate(f, xa)
        k2 = evaluate(f, xa + 0.5 * dt * k1)
        k3 = evaluate(f, xa + 0.5 * dt * k2)
        k4 = evaluate(f, xa + dt * k3)
        xn = xa + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out = ~np.isfinite(xn).all(1) | ((xn < far_lo) | (xn > far_hi)).any(1)
        x[live[~out]] = xn[~out]
        escaped[live[out]] = True
    steps_len = np.linalg.norm(np.diff(window, axis=1), axis=2)
    travel = np.nansum(steps_len, axis=1)
    end = np.where(escaped[:, None], np.nan, window[:, -1])
    t = horizon - dt * np.arange(window.shape[1])[::-1]
    return Rollouts(end, travel, escaped, window, t, np.nanmax(steps_len, axis=1, initial=0.0))


def recurrence(path: np.ndarray, t: np.ndarray, step: float) -> float | None:
    """The period of a path that closes on itself, Eq. (E4), or None.

    Going back in time from the path's last point x_K: the path first goes farther from x_K than
    ``RETURN_AWAY`` times its largest distance from x_K in the window, then comes back within
    max(``RETURN_NEAR`` times that distance, 2 ``step``); the period is the time from the closest
    point of that return to the end. path : (K, d); t : (K,), s.
    """
    dist = np.linalg.norm(path - path[-1], axis=1)
    reach = float(np.nanmax(dist))
    if not reach > 0:
        return None
    near = max(RETURN_NEAR * reach, 2.0 * step)
    away = np.flatnonzero(dist[::-1] > RETURN_AWAY * reach)
    if len(away) == 0:
        return None
    back = dist[::-1][away[0]:]
    close = np.flatnonzero(back <= near)
    if len(close) == 0:
        return None
    start = away[0] + close[0]                       # first index (from the end) back within reach
    stop = start + (np.flatnonzero(back[close[0]:] > near)[:1].tolist() or [len(back) - close[0]])[0]
    j = start + int(np.argmin(dist[::-1][start:stop]))
    return float(t[-1] - t[::-1][j])


def one_period(path: np.ndarray, t: np.ndarray, period: float) -> np.ndarray:
    """The points of the last ``period`` s of ``path`` (K, d) at times t (K,), at most ``PATH_POINTS`` of them."""
    last = path[t >= t[-1] - period * (1 + 1e-9)]
    keep = np.unique(np.linspace(0, len(last) - 1, min(PATH_POINTS, len(last))).round().astype(int))
    return last[keep]
