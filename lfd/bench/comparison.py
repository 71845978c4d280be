"""The paper's experiments on the noisy spiral, measured: the learners side by side (Table 2).

``lfd bench comparison`` (``lfd.bench.comparison_report.run_comparison``) trains the learners
(``trained``, cached), wraps each model (``lfd.bench.model.Model``) in an ``Entry`` and fills
``Entry.numbers`` with ``measure``, and its certificate with ``certificate``. With the same starts,
solver (RK4, ``DT``: ``Model.simulate``) and horizon for every model, ``measure`` gives the paper's
Table 2:

- accuracy: RMSE and DTW of the rollouts from the demo starts, mean over demos;
- robustness: ``N_STARTS`` seeded starts perturbed around the demo starts, and as many task-space
  kicks at mid-demo; final distance to the goal and worst distance from the demo path;
- convergence: 5 starts within ``FIVE_RADIUS`` of the extent around the true spiral's start, time
  until all are within ``FIVE_TOL`` of the extent of the true path; the exponential rate fitted to
  the distance between neighbouring trajectories, beside the certified one; the worst transient
  growth |dx(t)|/|dx(0)| of neighbouring trajectories from the demos' box grown by 50%, beside
  sqrt(b/a);
- stability: the fraction of rollouts that end within ``GOAL_RADIUS`` of the extent of the goal,
  also from starts anywhere in the demos' box grown to 3x;
- computational efficiency and real time: training time, one control-loop field step,
  evaluations per second.

The figures and the report: ``lfd.bench.comparison_report``.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any, cast

import numpy as np
from scipy.spatial import cKDTree

from lfd import metrics
from lfd.bench.dmp import DMPModel
from lfd.bench.fields import FieldModel
from lfd.bench.model import Model
from lfd.certify import certify
from lfd.demos import DemoSet, spiral
from lfd.errors import ModelError
from lfd.field import VelocityField
from lfd.learners import load, train
from lfd.learners.tracking import TrackingField, check_tracking_contraction

WEAK_RATE, STRONG_RATE = 0.5, 3.0     # 1/s
N_STARTS = 100                        # perturbed starts and kicks
START_SPREAD = 0.10                   # perturbation std, fraction of the demos' extent
KICK = 0.10                           # kick size, fraction of the extent
HORIZON_FACTOR = 3.0                  # rollouts run 3 demo durations
DT = 0.025                            # s, RK4 step of every rollout
GOAL_RADIUS = 0.01                    # "reached the goal": within 1% of the extent
REACTION_S = 1.0                      # path deviation counts from 1 s after a start or a kick
FAR_GROWTH = 2.0                      # far starts: uniform in the demos' box grown by 200% (3x its size)
FAR_HORIZON_FACTOR = 4.0
NEIGHBOUR_EPS = 1e-4                  # neighbour offset, fraction of the extent
N_PAIRS = 20
TRANSIENT_GROWTH = 0.5                # transient growth: starts in the demos' box grown by 50%
FIVE_RADIUS, FIVE_TOL = 0.10, 0.05    # the convergence test: 5 starts within 10% of the extent, converged within 5%
SEED = 0


@dataclass
class Cert:
    """A learner's certified contraction, whatever the check: rate (1/s, None: none), condition
    number b/a of the metric (None: none), verdict and one line of detail."""

    rate: float | None
    condition: float | None
    certified: bool
    detail: str
    worst: float = float("nan")
    bound: float = float("nan")


@dataclass
class Entry:
    """One learner's model (``lfd.bench.model.Model``, run through its fixed-step methods), and its
    certificate and measurements."""

    label: str
    model: Model
    cert: Cert | None = None
    numbers: dict[str, float] = dc_field(default_factory=dict)
    starts_rollout: np.ndarray | None = None

    @property
    def field(self) -> VelocityField:
        """The trained field of a field learner's entry."""
        return cast(FieldModel, self.model).field


def path_deviation(xs: np.ndarray, tree: cKDTree) -> np.ndarray:
    """max over time, after the first REACTION_S, of the distance to the nearest demo point:
    (B, T, d) -> (B,). (Before that the distance is the perturbation itself, the same for all.)"""
    xs = xs[:, int(round(REACTION_S / DT)):]
    d, _ = tree.query(np.nan_to_num(xs.reshape(-1, xs.shape[-1]), nan=1e9, posinf=1e9, neginf=-1e9))
    return d.reshape(xs.shape[:2]).max(axis=1)


def neighbour_pairs(e: Entry, x0: np.ndarray, eps: float, horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """Times (T,) and distances |x_a(t) - x_b(t)| (B, T) for each start and a neighbour eps away."""
    u = np.random.default_rng(SEED + 3).normal(size=x0.shape)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = np.arange(0.0, horizon + 1e-9, DT)
    xs = e.model.simulate(np.concatenate([x0, x0 + eps * u]), t)
    return t, np.linalg.norm(xs[: len(x0)] - xs[len(x0):], axis=-1)


def fitted_rates(e: Entry, x0: np.ndarray, eps: float, horizon: float) -> np.ndarray:
    """Rate r of |x_a(t) - x_b(t)| ~ c e^{-r t} for each start and a neighbour eps away (least squares)."""
    t, dist = neighbour_pairs(e, x0, eps, horizon)
    return np.array([-np.polyfit(t, np.log(np.maximum(d, 1e-300)), 1)[0] for d in dist])


def five_starts(demos: DemoSet, extent: float, n: int = 5) -> np.ndarray:
    """n starts uniform in the disc of radius FIVE_RADIUS x extent around the true spiral's start."""
    rng = np.random.default_rng(SEED + 5)
    ang, rad = rng.uniform(0, 2 * np.pi, n), FIVE_RADIUS * extent * np.sqrt(rng.uniform(0, 1, n))
    return nominal_spiral().x[0, 0] + rad[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)


def time_to_path(traj: np.ndarray, t: np.ndarray, path: np.ndarray, tol: float) -> float:
    """First time after which every trajectory (B, T, d) stays within tol of the dense path (P, d)."""
    dist = cKDTree(path).query(np.nan_to_num(traj.reshape(-1, traj.shape[-1]), nan=1e9))[0]
    dist = dist.reshape(traj.shape[:2]).max(0)
    outside = np.nonzero(dist > tol)[0]
    return 0.0 if len(outside) == 0 else (float(t[outside[-1] + 1]) if outside[-1] + 1 < len(t) else float("inf"))


def time_call(fn: Callable[[np.ndarray], Any], x: np.ndarray, n: int = 3000) -> float:
    """Median wall time of one call, in microseconds."""
    fn(x)
    ts = np.empty(n)
    clock = time.perf_counter
    for k in range(n):
        t0 = clock()
        fn(x)
        ts[k] = clock() - t0
    return float(np.median(ts) * 1e6)


def time_batched(e: Entry, pts: np.ndarray, repeats: int = 7) -> float:
    """Evaluations per second through the model's batched step (``Model.batch_step``), median of
    ``repeats`` (nan: the model has none)."""
    if e.model.batch_step(pts) is None:
        return float("nan")
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        e.model.batch_step(pts)
        ts.append(time.perf_counter() - t0)
    return float(len(pts) / np.median(ts))


def measure(entry: Entry, demos: DemoSet, extent: float, duration: float) -> None:
    """Fill ``entry.numbers`` (see the module docstring)."""
    n = entry.numbers
    tree = cKDTree(demos.x.reshape(-1, demos.dim))
    ys = entry.model.simulate_demos(demos)
    n["rmse"] = float(np.mean([metrics.rmse(y, x) for y, x in zip(ys, demos.x)]))
    n["dtw"] = float(np.mean([metrics.dtw(y, x) for y, x in zip(ys, demos.x)]))
    rng = np.random.default_rng(SEED)
    base = demos.x[np.arange(N_STARTS) % demos.n_demos, 0]
    x0 = base + rng.normal(scale=START_SPREAD * extent, size=base.shape)
    t = np.arange(0.0, HORIZON_FACTOR * duration + 1e-9, DT)
    xs = entry.model.simulate(x0, t)
    entry.starts_rollout = xs
    final = metrics.final_goal_distance(xs, demos.goal)
    n["start_final"] = float(np.nanmax(np.where(np.isfinite(final), final, np.inf)))
    n["start_dev"] = float(path_deviation(xs, tree).max())
    n["start_reached"] = metrics.convergence_rate(xs[:, -1], demos.goal, GOAL_RADIUS * extent)
    # kicks: from each demo start, displaced by KICK * extent at mid-demo, continued
    u = rng.normal(size=base.shape)
    kicks = KICK * extent * u / np.linalg.norm(u, axis=1, keepdims=True)
    mid = int(round(duration / 2 / DT))
    xk = entry.model.simulate(base, t, kick_at=mid, kicks=kicks)[:, mid:]
    final = metrics.final_goal_distance(xk, demos.goal)
    n["kick_final"] = float(np.nanmax(np.where(np.isfinite(final), final, np.inf)))
    n["kick_dev"] = float(path_deviation(xk, tree).max())
    n["kick_reached"] = metrics.convergence_rate(xk[:, -1], demos.goal, GOAL_RADIUS * extent)
    xf0 = np.random.default_rng(SEED + 4).uniform(*demos.bounds(FAR_GROWTH), size=(N_STARTS, demos.dim))
    xf = entry.model.simulate(xf0, np.arange(0.0, FAR_HORIZON_FACTOR * duration + 1e-9, DT))
    n["far_reached"] = metrics.convergence_rate(xf[:, -1], demos.goal, GOAL_RADIUS * extent)
    # convergence: the five starts, neighbouring trajectories, transient growth
    t8 = np.arange(0.0, 8.0 + 1e-9, DT)
    path = nominal_spiral(4000).x[0]
    x5 = entry.model.simulate(five_starts(demos, extent), t8)
    n["five_time"] = time_to_path(x5, t8, path, FIVE_TOL * extent)
    n["five_cover"] = float(max(cKDTree(np.nan_to_num(x, nan=1e9)).query(path)[0].max() for x in x5))
    n["rate_fit"] = float(np.median(fitted_rates(entry, x0[:N_PAIRS], NEIGHBOUR_EPS * extent, duration)))
    xg = np.random.default_rng(SEED + 6).uniform(*demos.bounds(TRANSIENT_GROWTH), size=(N_PAIRS, demos.dim))
    _, dist = neighbour_pairs(entry, xg, NEIGHBOUR_EPS * extent, duration)
    n["growth"] = float(np.max(dist / dist[:, :1]))
    err = entry.model.phase_error(x0[:N_PAIRS], np.arange(0.0, 2.0 + 1e-9, DT))
    if err is not None:   # the in-phase error |x - r(s)| of Eq. (T5), fitted like the pairs
        te = np.arange(err.shape[1]) * DT
        n["error_rate_fit"] = float(np.median([-np.polyfit(te, np.log(np.maximum(e, 1e-300)), 1)[0] for e in err]))
    n["train_s"] = entry.model.train_time_s
    n["step_us"] = time_call(entry.model.control_step(demos.x[0, 0]), demos.x[0, 10])
    n["evals_single"] = 1e6 / n["step_us"]
    grid = np.random.default_rng(SEED + 1).uniform(*demos.bounds(0.5), size=(10_000, demos.dim))
    n["evals_batched"] = time_batched(entry, grid)


def _dmp_certificate(e: Entry, lo: np.ndarray, hi: np.ndarray) -> Cert:
    """None: the DMP is time-indexed; its spring-damper's double eigenvalue -alpha_y / (2 tau)."""
    a = float(e.model.config["alpha_y"]) / (2.0 * cast(DMPModel, e.model).duration)
    return Cert(None, None, False, f"none (time-indexed; its spring-damper has a double eigenvalue "
                                   f"-alpha_y/(2 tau) = -{a:.2f}/s)")


def _tracking_certificate(e: Entry, lo: np.ndarray, hi: np.ndarray) -> Cert:
    """``check_tracking_contraction`` (Eq. (T5), J = -K I)."""
    t = check_tracking_contraction(cast(TrackingField, e.field), lo, hi)
    return Cert(t["rate"], t["condition_number"], t["certified"],
                f"max eig sym(J) = {t['worst_eig']:.4f} <= -{t['rate']:g}; |e(t)| - |e(0)|e^(-Kt) <= "
                f"{t['worst_error_excess']:.1e}", t["worst_eig"], t["bound"])


def _field_certificate(e: Entry, lo: np.ndarray, hi: np.ndarray) -> Cert:
    """``lfd.certify`` (Eq. (C1)): the identity metric of a field without one, else its own."""
    c = certify(e.field, lo, hi)
    if c.metric == "identity":
        return Cert(None, None, c.certified, f"none (worst max eig(J+J') = {c.worst:.2f} > 0)", c.worst, c.bound)
    cond = c.condition_bound                         # analytic, for a field with a metric
    measured = c.sampled_metric_max_eig / c.sampled_metric_min_eig
    op = "<=" if c.worst <= c.bound else ">"
    return Cert(c.rate, float(cond) if cond is not None else measured, c.certified,
                f"{'' if c.certified else c.verdict + ': '}worst {c.worst:.6f} {op} {c.bound:.4f}; "
                f"b/a sampled on the box {measured:.3g}", c.worst, c.bound)


#: the check of each learner by its registry name (``lfd.certify`` for any other)
CERTIFICATES: dict[str, Callable[[Entry, np.ndarray, np.ndarray], Cert]] = {
    "dmp": _dmp_certificate, "tracking": _tracking_certificate}


def certificate(e: Entry, lo: np.ndarray, hi: np.ndarray) -> Cert:
    """The learner's own certificate on the box [lo, hi] (``CERTIFICATES``)."""
    return CERTIFICATES.get(e.model.learner, _field_certificate)(e, lo, hi)


def nominal_spiral(n_samples: int = 200) -> DemoSet:
    """The noise-free spiral the demos were drawn around: the true trajectory."""
    return spiral(n_demos=1, start_spread=0.0, noise=0.0, n_samples=n_samples)


def sources_hash(learner: str) -> str:
    """sha256 of the sources a learner's training depends on (its module, the learner base, the
    flows, the field, the integrator, the normalisation), first 12 hex digits: a change invalidates its cache."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))   # the lfd package
    h = hashlib.sha256()
    for rel in (f"learners/{learner}.py", "learners/base.py", "learners/flows.py", "field.py", "integrate.py",
                "normalization.py"):
        p = os.path.join(root, rel)
        if os.path.exists(p):
            with open(p, "rb") as fh:
                h.update(fh.read())
    return h.hexdigest()[:12]


def trained(learner: str, demos: DemoSet, cache: str | None, **options: Any) -> VelocityField:
    """``lfd.train(learner, demos, seed=SEED, **options)``, read from / written to ``cache`` if given."""
    if cache is None:
        return train(learner, demos, seed=SEED, **options)
    key = json.dumps({"learner": learner, "options": options, "seed": SEED, "src": sources_hash(learner)},
                     sort_keys=True)
    path = os.path.join(cache, f"{learner}_{hashlib.sha256(key.encode()).hexdigest()[:16]}.pt")
    if os.path.exists(path):
        try:
            return load(path)
        except ModelError:
            pass
    field = train(learner, demos, seed=SEED, **options)
    field.save(path)
    return field

