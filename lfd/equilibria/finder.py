"""``find_equilibria``: a field's equilibria and closed orbits besides its goal, with their types and basins,
in a box (docs/equations.md, "Equilibria and closed orbits", Eqs. (E1)-(E4)); ``equilibria_summary`` for
one benchmark cell."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lfd.equilibria import orbits as orbits_
from lfd.equilibria import roots
from lfd.equilibria.report import ClosedOrbit, Equilibrium, EquilibriumReport, classify
from lfd.errors import ConfigError
from lfd.field import Field, FieldKind, require_kind

if TYPE_CHECKING:
    from lfd.demos import DemoSet

BOX_GROWTH = 0.5        # the default box: the demos' bounding box grown by half its size
HORIZON = 10.0          # rollouts last this many times the demos' duration
STEPS = 250             # RK4 steps over the horizon, at least ...
STEP_RADIUS = 1.0       # ... and dt <= STEP_RADIUS / (the largest spectral radius of J_f at the seeds)
MAX_STEPS = 20_000
TOLERANCE = 0.01        # a rollout ends at a point when within this fraction of the box's diagonal
FTOL = 1e-9             # |f| <= FTOL times the median |f| over the seeds at a root
MERGE = 1e-5            # roots closer than this fraction of the box's diagonal are one
REFINE = 8              # starts that end neither at the goal nor at a root run again with steps this much finer
SETTLE = 0.1            # a rollout stops within SETTLE x the tolerance of an attractor (the goal, a root)


def find_equilibria(field: Field, lo: np.ndarray, hi: np.ndarray, duration: float | None = None,
                    tolerance: float = TOLERANCE) -> EquilibriumReport:
    """The equilibria and closed orbits of ``field``'s autonomous view in the box [lo, hi], other than its goal.

    Damped Newton from ``roots.seeds`` finds the roots of f (Eq. (E1)), typed by the eigenvalues of
    their central-difference Jacobians (Eq. (E2), ``report.classify``); rollouts of ``HORIZON`` times
    ``duration`` from the same seeds (Eq. (E3)) end at the goal, at a root, on a closed orbit (a
    recurrence, Eq. (E4)) or escape; the still ends that are at no known root seed Newton again. The
    autonomous view is ``field(x)`` on points: a phased field's is Eq. (T3) at the phase of the nearest
    reference point; a pose field's is its chart's R^6.

    Parameters
    ----------
    field : Field
        An autonomous or phased field (``ConfigError`` for a time-varying one).
    lo, hi : arrays, shape (d,)
        The box, user units.
    duration : float, optional
        The demos' duration T, s (default: a phased field's own, else the box's diagonal over the
        median speed in it).
    tolerance : float
        A rollout ends at a point within ``tolerance`` times the box's diagonal of it.

    Returns
    -------
    EquilibriumReport
    """
    require_kind(field, (FieldKind.AUTONOMOUS, FieldKind.PHASED), "the search for equilibria")
    t0 = time.perf_counter()
    lo, hi = check_box(field, lo, hi)
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and 0 < tolerance < 1):
        raise ConfigError(f"tolerance must be in (0, 1), got {tolerance!r}")
    if duration is not None and not (isinstance(duration, (int, float)) and math.isfinite(duration)
                                     and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")
    with np.errstate(all="ignore"):     # a field that overflows somewhere: its points count as not finite
        return _search(field, lo, hi, duration, tolerance, t0)


def _search(field: Field, lo: np.ndarray, hi: np.ndarray, duration: float | None, tolerance: float,
            t0: float) -> EquilibriumReport:
    """``find_equilibria`` after its arguments were checked."""
    side = float(np.max(hi - lo))
    diag = side * float(np.linalg.norm((hi - lo) / side))     # without overflow on a huge box
    reach = tolerance * diag
    goal = np.asarray(field.goal, dtype=np.float64)
    fn = _points(field)
    starts, layout = roots.seeds(lo, hi)
    speed = np.linalg.norm(roots.evaluate(fn, starts), axis=1)
    scale = float(np.nanmedian(speed)) if np.isfinite(speed).any() else 0.0
    scale = scale if scale > 0 else 1.0
    ftol = FTOL * scale
    x, _, ok, radius = roots.newton(fn, starts, lo, hi, ftol)
    pts = _distinct(x[ok & _inside(x, lo, hi)], goal, reach, MERGE * diag)
    if duration is None:
        duration = field.runner(None, 1.0).duration or diag / scale
    horizon = HORIZON * float(duration)
    steps = int(min(MAX_STEPS, max(STEPS, horizon * radius / STEP_RADIUS)))   # radius: finite, >= 0
    sinks = [p for p, e in zip([goal, *pts], roots.eigenvalues(fn, np.vstack([goal, pts]), lo, hi))
             if classify(e) == "attractor"]
    sinks_ = np.array(sinks).reshape(-1, len(goal))
    far = _confinement(field, starts, goal)
    runs = orbits_.rollout(fn, starts, horizon, steps, lo, hi, sinks_, SETTLE * reach, far)

    at_goal = np.linalg.norm(runs.end - goal, axis=1) <= reach
    still = ~runs.escaped & ~at_goal & (runs.travel <= reach)
    if len(pts):
        still &= ~(np.linalg.norm(runs.end[:, None] - pts[None], axis=2) <= reach).any(1)
    if still.any():                       # rollouts that stopped where no root was found yet
        y, _, ok2, _ = roots.newton(fn, runs.end[still], lo, hi, ftol)
        pts = _distinct(np.concatenate([pts, y[ok2]]), goal, reach, MERGE * diag)
    ev = roots.eigenvalues(fn, pts, lo, hi)
    near = np.linalg.norm(runs.end[:, None] - pts[None], axis=2)           # (P, K), NaN where escaped
    owner = np.full(len(starts), -1)
    if len(pts):
        hit = (near <= reach).any(1) & ~at_goal
        owner[hit] = np.nanargmin(near[hit], axis=1)
    n = len(starts)
    escaped = runs.escaped.copy()
    unresolved = ~at_goal & (owner < 0)
    cycles: list[ClosedOrbit] = []
    if unresolved.any():   # again with REFINE times finer steps: what the integrator alone made disappears
        idx = np.flatnonzero(unresolved)
        fine = orbits_.rollout(fn, starts[idx], horizon, max(steps, min(steps * REFINE, MAX_STEPS)), lo, hi,
                               sinks_, SETTLE * reach, far)
        fine_goal = np.linalg.norm(fine.end - goal, axis=1) <= reach
        at_goal[idx[fine_goal]] = True
        escaped[idx] = fine.escaped
        cycles = [replace(c, basin=c.basin * len(idx) / n)
                  for c in _orbits(fine, ~fine.escaped & ~fine_goal & (fine.travel > reach))]
    inside = _inside(pts, lo, hi)
    eqs = [Equilibrium(location=pts[i].tolist(), eigenvalues=[[float(v.real), float(v.imag)] for v in ev[i]],
                       type=classify(ev[i]), residual=float(np.linalg.norm(roots.evaluate(fn, pts[i:i + 1]))),
                       basin=float((owner == i).sum()) / n, in_box=bool(inside[i]))
           for i in range(len(pts)) if inside[i] or (owner == i).any()]
    eqs.sort(key=lambda e: (not e.attracting, -e.basin))
    n_goal, n_out, n_eq = int(at_goal.sum()), int(escaped.sum()), int((owner >= 0).sum())
    n_orbit = sum(round(o.basin * n) for o in cycles)
    method = {"seeds": layout, "n_seeds": int(n), "n_starts": int(n), "newton_iterations": roots.NEWTON_ITERATIONS,
              "jacobian_step": roots.JACOBIAN_STEP, "ftol": ftol, "duration_s": float(duration), "horizon_s": horizon,
              "steps": steps, "tolerance": reach, "merge": MERGE * diag}
    return EquilibriumReport(
        equilibria=eqs, orbits=cycles, goal=goal.tolist(), goal_fraction=n_goal / n, escaped_fraction=n_out / n,
        other_fraction=max(0, n - n_goal - n_out - n_eq - n_orbit) / n,
        box=[lo.tolist(), hi.tolist()], method=method, elapsed_s=time.perf_counter() - t0)


def _distinct(pts: np.ndarray, goal: np.ndarray, reach: float, radius: float) -> np.ndarray:
    """The distinct roots of ``pts`` (P, d) farther than ``reach`` from the goal (``roots.merge``)."""
    pts = roots.merge(pts, radius)
    return pts[np.linalg.norm(pts - goal, axis=1) > reach]


def check_box(field: Field, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi) as float64 arrays of shape (d,); ConfigError unless it is finite, of the field's
    dimension, with hi > lo on every axis."""
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1), np.asarray(hi, dtype=np.float64).reshape(-1)
    d = field.dim
    if lo.shape != (d,) or hi.shape != (d,):
        raise ConfigError(f"the box must have {d} lower and {d} upper bounds for this {d}-D field, "
                          f"got {lo.size} and {hi.size}")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()):
        raise ConfigError(f"the box must be finite with max > min on every axis, got {lo.tolist()} .. {hi.tolist()}")
    return lo, hi


def _confinement(field: Field, starts: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Where a start escapes for a field that states a Lyapunov function whose conditions hold (the
    stable NODE, Eq. (L3)): beyond overshoot x the farthest start's distance from the goal, the
    region the stated bound keeps every trajectory in (leaving it is then a counterexample, and a
    detour inside it is not an escape). None for any other field (the box grown by its size)."""
    constants = field.stability_constants()
    if not constants or not constants.get("holds"):
        return None
    radius = min(float(constants["overshoot"]) * float(np.max(np.linalg.norm(starts - goal, axis=1))), 1e150)
    return goal - radius, goal + radius


def _inside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether each point of x (P, d) lies in the box [lo, hi]: shape (P,) bool."""
    return np.asarray(((x >= lo) & (x <= hi)).all(1))


def _orbits(runs: orbits_.Rollouts, moving: np.ndarray) -> list[ClosedOrbit]:
    """The closed orbits the ``moving`` rollouts settle on: each recurrent one (Eq. (E4)) joins the first
    orbit whose points its end lies near, else starts a new one."""
    n = len(moving)
    groups: list[tuple[np.ndarray, float, list[float]]] = []          # (path, near, periods)
    for i in np.flatnonzero(moving):
        path = runs.window[i]
        period = orbits_.recurrence(path, runs.t, float(runs.step[i]))
        if period is None:
            continue
        reach = float(np.linalg.norm(path - path[-1], axis=1).max())
        near = max(orbits_.RETURN_NEAR * reach, 2.0 * float(runs.step[i]))
        for g in groups:
            if float(np.linalg.norm(g[0] - path[-1], axis=1).min()) <= max(near, g[1]):
                g[2].append(period)
                break
        else:
            groups.append((orbits_.one_period(path, runs.t, period), near, [period]))
    return [ClosedOrbit(point=path[-1].tolist(), period=float(np.median(periods)), basin=len(periods) / n,
                        size=float(np.linalg.norm(path - path[-1], axis=1).max()), path=path.tolist())
            for path, _, periods in groups]


def search_box(field: Field, demos: DemoSet | None = None,
               grow: float = BOX_GROWTH) -> tuple[np.ndarray, np.ndarray]:
    """The box to search: the field's training demos' box (``Field.demo_box``), else that of ``demos``
    when they have the field's dimension, grown by ``grow`` times its size. Returns (lo, hi), each (d,)."""
    box = field.demo_box
    if box is None and demos is not None and demos.dim == field.dim:
        box = demos.bounds()
    if box is None:
        raise ConfigError("no box to search: the model has no demo box; give the box or demos")
    lo, hi = (np.asarray(c, dtype=np.float64) for c in box)
    pad = (hi - lo) * grow / 2
    return lo - pad, hi + pad


def equilibria_summary(field: Field, demos: DemoSet) -> dict[str, Any]:
    """The search of one benchmark cell, JSON-able: ``find_equilibria`` in ``search_box(field, demos)``
    over the demos' mean duration.

    Returns {"clean", "spurious_attractors", "equilibria", "closed_orbits" (counts), "goal_fraction",
    "escaped_fraction", "other_fraction", "points": [{"location", "type", "basin"}], "orbits":
    [{"point", "period", "basin"}], "elapsed_s"}.
    """
    lo, hi = search_box(field, demos)
    duration = float(np.mean(demos.t[:, -1] - demos.t[:, 0]))
    r = find_equilibria(field, lo, hi, duration)
    return {"clean": r.clean, "spurious_attractors": len(r.spurious_attractors), "equilibria": len(r.equilibria),
            "closed_orbits": len(r.orbits), "goal_fraction": r.goal_fraction, "escaped_fraction": r.escaped_fraction,
            "other_fraction": r.other_fraction,
            "points": [{"location": e.location, "type": e.type, "basin": e.basin} for e in r.equilibria],
            "orbits": [{"point": o.point, "period": o.period, "basin": o.basin} for o in r.orbits],
            "elapsed_s": r.elapsed_s}


def _points(field: Field) -> roots.PointsFn:
    """The autonomous view on points, (P, d) -> (P, d): ``field(x)``."""
    return lambda x: np.asarray(field(x), dtype=np.float64)
