"""Scaling curves of the learners: training time, single-point time and accuracy against the size
of the problem (``sim.studies.scaling``, run by ``scripts/scaling.py``, writes them into reports/scaling.md).

Three sizes, each on LASA demos (``lfd.demos.lasa``):

- the dimension d: d / 2 LASA shapes stacked into d-dimensional demos (``stacked_lasa``), the way
  ELCD and CLFD build their 4-D to 32-D sets: demo i of the stacked set is the concatenation of demo i
  of each shape, every demo resampled in time to a common number of samples;
- the number of demos N (the first N demos of one shape);
- the samples per demo T (every demo resampled in time to T samples, ``resample_demos``).

One measurement (``measure``) trains a learner with ``lfd.bench.spaces.fit`` (``lfd.train`` for
the field learners, the DMP baseline of ``lfd.bench.dmp`` for ``dmp``), records its training CPU time
(``time.process_time``, the field learners' ``history["train_cpu_s"]``) and wall time, times one
single-point evaluation (``VelocityField.single_point_evaluator`` on demo points; a ``DMP.step``
for the DMP), and scores the reproductions from the demos' starts (``Model.reproduce`` of
``lfd.bench.model``) of the same motions at LASA's own 1000 samples (``cached_measure``), so every
point of the T curve is scored alike: the time-aligned RMSE and the DTW distance per sample, both per
2-D shape (``block_errors``). ``fit_exponent`` gives the least-squares slope of log(cost) against
log(size). ``cached_measure`` keeps one JSON file per point, so an interrupted run resumes;
``profile_fit`` says where a training's time goes.
"""

from __future__ import annotations

import cProfile
import dataclasses
import hashlib
import json
import math
import pstats
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from scipy.interpolate import CubicSpline

from lfd import metrics
from lfd.bench.fields import FieldModel
from lfd.bench.model import Model
from lfd.bench.spaces import DMP, fit, resolve_config
from lfd.demos import LASA_SHAPES, DemoSet, lasa
from lfd.io import write_json
from lfd.learners import train
from lfd.threads import torch_threads

__all__ = ["STACK_SHAPES", "DIMS", "DEMO_COUNTS", "SAMPLE_COUNTS", "CURVES", "BASE_DEMOS", "BASE_SAMPLES", "BASE_DIM",
           "Point", "resample_demos", "stacked_lasa", "fit_exponent", "block_errors", "single_point_us",
           "measure", "cached_measure", "curve_points", "full_config", "point_function", "profile_fit", "FORMAT"]

#: the shapes stacked for d = 2, 4, ..., 32, in this order (the first d / 2 of them): the first 16
#: single-pattern LASA shapes in the data set's order (the Multi_Models sets are left out)
STACK_SHAPES: tuple[str, ...] = tuple(s for s in LASA_SHAPES if not s.startswith("Multi_Models"))[:16]
DIMS: tuple[int, ...] = (2, 4, 8, 16, 32)
DEMO_COUNTS: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7)
SAMPLE_COUNTS: tuple[int, ...] = (250, 500, 1000, 2000, 4000)
#: every curve's points share these values of the other two sizes: N = 7 demos of T = 1000 samples, d = 2
BASE_DEMOS, BASE_SAMPLES, BASE_DIM = 7, 1000, 2
#: curve name -> (the size it varies, its values)
CURVES: dict[str, tuple[str, tuple[int, ...]]] = {"dim": ("d", DIMS), "demos": ("N", DEMO_COUNTS),
                                                   "samples": ("T", SAMPLE_COUNTS)}
#: bumped when what a cached point holds changes (older files are measured again)
FORMAT = 1


def resample_demos(demos: DemoSet, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Every demo of ``demos`` resampled in time to ``n_samples`` samples evenly spaced over its own
    duration, by a cubic spline through its samples (``scipy.interpolate.CubicSpline``): the end points
    are kept exactly.

    Parameters
    ----------
    demos : DemoSet
        N demos of T samples in d dimensions.
    n_samples : int
        Samples per demo of the result, at least ``lfd.demos.MIN_SAMPLES``.

    Returns
    -------
    t : array, shape (N, n_samples)
        Times, from each demo's first time to its last.
    x : array, shape (N, n_samples, d)
        Positions.
    """
    t_out = np.stack([np.linspace(ti[0], ti[-1], n_samples) for ti in demos.t])
    x_out = np.stack([CubicSpline(ti, xi, axis=0)(to) for ti, xi, to in zip(demos.t, demos.x, t_out)])
    x_out[:, 0], x_out[:, -1] = demos.x[:, 0], demos.x[:, -1]
    return t_out, x_out


def stacked_lasa(dim: int, n_demos: int = BASE_DEMOS, n_samples: int = BASE_SAMPLES,
                 shapes: Sequence[str] = STACK_SHAPES,
                 load: Callable[[str], DemoSet] = lasa) -> DemoSet:
    """LASA shapes stacked into ``dim``-dimensional demos (module docstring).

    Coordinates 2k, 2k + 1 of demo i are demo i of ``shapes[k]``, resampled to ``n_samples`` samples
    (``resample_demos``). All demos run on one clock, ``n_samples`` times evenly from 0 to the mean
    duration of the stacked demos (LASA demos differ slightly in duration: each is re-timed to that
    common clock, its path unchanged). Every LASA shape ends at the origin, so the stacked demos share
    a goal.

    Parameters
    ----------
    dim : int
        Even, 2 to 2 len(shapes).
    n_demos : int
        The first ``n_demos`` demos of every shape (LASA has 7).
    n_samples : int
        Samples per demo.
    shapes : sequence of str
        The shapes to stack, the first dim / 2 of them.
    load : callable
        Shape name -> its DemoSet (``lfd.lasa``).

    Returns
    -------
    DemoSet
        x of shape (n_demos, n_samples, dim), named ``lasa-stack:<shape>+<shape>...``.
    """
    if dim < 2 or dim % 2 or dim // 2 > len(shapes):
        raise ValueError(f"dim must be even, 2 to {2 * len(shapes)}, got {dim}")
    parts = [load(s) for s in shapes[:dim // 2]]
    if not 1 <= n_demos <= min(p.n_demos for p in parts):
        raise ValueError(f"n_demos must be 1 to {min(p.n_demos for p in parts)}, got {n_demos}")
    xs, durations = [], []
    for p in parts:
        sub = p.subset(list(range(n_demos)))
        t, x = resample_demos(sub, n_samples)
        xs.append(x)
        durations.append(t[:, -1] - t[:, 0])
    t = np.broadcast_to(np.linspace(0.0, float(np.mean(durations)), n_samples), (n_demos, n_samples)).copy()
    name = "lasa-stack:" + "+".join(shapes[:dim // 2])
    return DemoSet(t, np.concatenate(xs, axis=-1), name=name)


def fit_exponent(sizes: Sequence[float] | np.ndarray, costs: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """The least-squares line log(cost) = b log(size) + log(c): (b, c).

    Points whose size or cost is not positive and finite are left out; fewer than two distinct
    sizes left give (nan, nan).

    Parameters
    ----------
    sizes, costs : array-like, shape (n,)

    Returns
    -------
    (float, float)
        The exponent b and the factor c of cost = c size^b.
    """
    x, y = np.asarray(sizes, dtype=np.float64), np.asarray(costs, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if len(np.unique(x[ok])) < 2:
        return math.nan, math.nan
    b, a = np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)
    return float(b), float(np.exp(a))


def block_errors(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """Reproduction errors of a stacked set per 2-D shape: (RMSE, DTW per sample), in the data's units.

    For each demo and each 2-D block (one stacked shape): ``lfd.metrics.rmse`` and
    ``lfd.metrics.dtw`` divided by the number of samples (curves subsampled by
    ``lfd.metrics.dtw_step_for`` where the full table would be too large, the DTW then divided by
    the subsampled count); each is averaged over demos and blocks. A non-finite reproduction gives inf.

    Parameters
    ----------
    y : array, shape (N, T, d)
        Reproductions.
    x : array, shape (N, T, d)
        Demos, d even.

    Returns
    -------
    (float, float)
    """
    if not np.isfinite(y).all():
        return math.inf, math.inf
    rmse, dtw = [], []
    T = x.shape[1]
    step = metrics.dtw_step_for(T, T)
    n = len(range(0, T, step))
    for yi, xi in zip(y, x):
        for k in range(0, x.shape[2], 2):
            a, b = yi[:, k:k + 2], xi[:, k:k + 2]
            rmse.append(metrics.rmse(a, b))
            dtw.append(metrics.dtw(a, b, step=step) / n)
    return float(np.mean(rmse)), float(np.mean(dtw))


def single_point_us(fn: Callable[[np.ndarray], Any], points: np.ndarray, blocks: int = 200,
                    calls: int = 20) -> float:
    """Median microseconds of one call ``fn(p)``: ``blocks`` blocks of ``calls`` calls each over the
    points in turn (as ``scripts/speed.py field`` times ``field(x)``), the median of the blocks'
    per-call means; 20 untimed calls warm up first.

    Parameters
    ----------
    fn : callable
        x, shape (d,) -> anything.
    points : array, shape (P, d)
    blocks, calls : int
    """
    pts = [np.array(p) for p in points]
    for k in range(20):
        fn(pts[k % len(pts)])
    per = np.empty(blocks)
    clock = time.perf_counter
    k = 0
    for b in range(blocks):
        t0 = clock()
        for _ in range(calls):
            fn(pts[k % len(pts)])
            k += 1
        per[b] = (clock() - t0) / calls
    return float(np.median(per) * 1e6)


def measure(learner: str, demos: DemoSet, options: dict[str, Any] | None = None, seed: int = 0,
            truth: DemoSet | None = None, timing_points: int = 200, min_cpu_s: float = 1.0,
            max_fits: int = 5) -> dict[str, Any]:
    """Train ``learner`` on ``demos`` and measure it (module docstring), torch on one thread
    (``lfd.threads``).

    A training that takes less than ``min_cpu_s`` of CPU time is repeated (same seed, same model) until
    the fits together take that long or ``max_fits`` are done, and the medians are kept: one fit of a
    few milliseconds is too short to time alone.

    Parameters
    ----------
    learner : str
        ``dmp`` or a field learner (``lfd.LEARNERS``).
    demos : DemoSet
        The training demos (``stacked_lasa``).
    options : dict, optional
        The learner's options (default: its defaults).
    seed : int
    truth : DemoSet, optional
        The demos the reproductions are scored against, started from their starts on their times
        (default ``demos``): the same motions at another sampling, so that every point of a curve is
        scored alike.
    timing_points : int
        Demo points (evenly spread over all samples) the single-point timing cycles through.
    min_cpu_s : float
    max_fits : int

    Returns
    -------
    dict
        ``train_cpu_s``, ``train_wall_s``, ``fits`` (how many the medians are of), ``single_point_us``,
        ``rmse``, ``dtw_per_sample`` (per 2-D shape, the data's units), ``reproduce_s`` (wall time of
        the reproductions), ``iterations`` (the learner's, where it reports them), ``config`` and
        ``reproduce`` (the solver the reproductions ran with).
    """
    options = dict(options or {})
    truth = demos if truth is None else truth
    cpus, walls = [], []
    with warnings.catch_warnings(), torch_threads(1):
        warnings.simplefilter("ignore")
        while True:
            t0, cpu0 = time.perf_counter(), time.process_time()
            model = fit(learner, demos, seed, options)
            wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
            if model.history.get("interrupted"):
                raise KeyboardInterrupt   # a partly trained field is no measurement
            if "train_cpu_s" in model.history:   # the learner's own timers (lfd.train's): the fit alone
                cpu, wall = float(model.history["train_cpu_s"]), model.train_time_s
            cpus.append(cpu)
            walls.append(wall)
            if sum(cpus) >= min_cpu_s or len(cpus) >= max_fits:
                break
        points = demos.x.reshape(-1, demos.dim)
        points = points[np.linspace(0, len(points) - 1, timing_points).round().astype(int)]
        fn = point_function(learner, model)
        step_us = model.step_time_us(points, 1000) if fn is None else single_point_us(fn, points)
        t0 = time.perf_counter()
        y, _ = model.reproduce(truth.x, truth.t)
        reproduce_s = time.perf_counter() - t0
    rmse, dtw = block_errors(y, truth.x)
    return {"train_cpu_s": float(np.median(cpus)), "train_wall_s": float(np.median(walls)), "fits": len(cpus),
            "single_point_us": step_us, "rmse": rmse, "dtw_per_sample": dtw, "reproduce_s": reproduce_s,
            "iterations": model.history.get("iterations"), "config": model.config,
            "reproduce": model.integrators.get("reproduce")}


def point_function(learner: str, model: Model) -> Callable[[np.ndarray], Any] | None:
    """The single-point function of a trained model: a field learner's
    ``single_point_evaluator()`` (the control loop's path), or None for the DMP baseline, which has
    no field (its ``DMP.step`` is timed by ``DMPModel.step_time_us``).

    Parameters
    ----------
    learner : str
        ``dmp`` or a field learner.
    model : Model
        What ``lfd.bench.spaces.fit`` returned for it.
    """
    if learner == DMP:
        return None
    return cast(FieldModel, model).field.single_point_evaluator()


@dataclass(frozen=True)
class Point:
    """One measurement: a learner on ``stacked_lasa(dim, n_demos, n_samples)`` with ``options``."""

    learner: str
    dim: int
    n_demos: int
    n_samples: int
    options: tuple[tuple[str, Any], ...] = ()

    @property
    def stem(self) -> str:
        """The cache file's name without suffix."""
        extra = "".join(f"_{k}{v}" for k, v in self.options)
        return f"{self.learner}_d{self.dim}_n{self.n_demos}_t{self.n_samples}{extra}"

    def key(self) -> str:
        """A hash of everything the measurement depends on: the point, the learner's full config (its
        defaults as they are now filled in), the stacked shapes and ``FORMAT``."""
        text = json.dumps({"format": FORMAT, **dataclasses.asdict(self), "shapes": STACK_SHAPES,
                           "config": full_config(self.learner, dict(self.options))},
                          sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def demos(self) -> DemoSet:
        """Its demos (``stacked_lasa``)."""
        return stacked_lasa(self.dim, self.n_demos, self.n_samples)


def full_config(learner: str, options: dict[str, Any]) -> dict[str, Any]:
    """The learner's config for ``options``, its defaults filled in as they are now (``dmp``: the
    DMP baseline's; ``lfd.bench.spaces.resolve_config``)."""
    return resolve_config(learner, options)


def curve_points(learner: str, curve: str, options: dict[str, Any] | None = None,
                 sizes: Sequence[int] | None = None) -> list[Point]:
    """The points of one curve (``CURVES``) of ``learner``, the other two sizes at their base values.

    Parameters
    ----------
    learner : str
    curve : str
        ``dim``, ``demos`` or ``samples``.
    options : dict, optional
        The learner's options.
    sizes : sequence of int, optional
        A subset of the curve's values (default: all).
    """
    _, values = CURVES[curve]
    opts = tuple(sorted((options or {}).items()))
    out = []
    for v in (values if sizes is None else sizes):
        dim = v if curve == "dim" else BASE_DIM
        n = v if curve == "demos" else BASE_DEMOS
        T = v if curve == "samples" else BASE_SAMPLES
        out.append(Point(learner, dim, n, T, opts))
    return out


def cached_measure(point: Point, directory: str | Path) -> tuple[dict[str, Any], bool]:
    """The measurement of ``point``, from ``<directory>/<stem>.json`` when that file holds this point's
    key, else measured now (``measure``) and written there atomically (``lfd.io.write_json``).

    Returns
    -------
    (dict, bool)
        The record (the measurement, the point's fields and ``elapsed_s``, the wall time it took) and
        whether it was measured now.
    """
    path = Path(directory) / f"{point.stem}.json"
    key = point.key()
    if path.is_file():
        try:
            record = json.loads(path.read_text())
            if record.get("key") == key:
                return record, False
        except (OSError, ValueError):
            pass
    t0 = time.perf_counter()
    truth = stacked_lasa(point.dim, point.n_demos, BASE_SAMPLES)
    result = measure(point.learner, point.demos(), dict(point.options), truth=truth)
    record = {"key": key, **dataclasses.asdict(point), "options": dict(point.options), **result,
              "elapsed_s": time.perf_counter() - t0}
    write_json(path, record)
    return record, True


def profile_fit(learner: str, demos: DemoSet, options: dict[str, Any] | None = None, seed: int = 0,
                top: int = 40) -> dict[str, Any]:
    """Where one training's time goes: torch operators and the learner's own functions.

    The fit runs twice (torch on one thread, after a warm-up fit of the same options): under
    ``torch.profiler`` (self CPU time per operator, ``key_averages``, and the time of the autograd
    backward pass, the operators' ``autograd::engine::evaluate_function`` events) and under ``cProfile``
    (cumulative wall time of each Python function defined in ``lfd/learners/``: the forward pass and the
    learner's own code; the backward pass runs in torch's engine, outside them). Nested functions
    overlap: a function's cumulative time holds that of the functions it calls.

    Parameters
    ----------
    learner : str
        A field learner (``lfd.LEARNERS``).
    demos : DemoSet
    options : dict, optional
        The learner's options (e.g. fewer iterations, to keep the profile short).
    seed : int
    top : int
        Operators and functions kept, the most expensive first.

    Returns
    -------
    dict
        ``cpu_s`` and ``wall_s`` (of the cProfile'd fit), ``ops`` {operator: self CPU s}, ``ops_total_s``
        (all operators' self time), ``backward_s`` and ``functions`` {"file:function": cumulative wall s}.
    """
    from torch.profiler import ProfilerActivity, profile  # (loads torch's profiler only when asked)

    options = dict(options or {})
    with warnings.catch_warnings(), torch_threads(1):
        warnings.simplefilter("ignore")
        train(learner, demos, seed=seed, **options)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            train(learner, demos, seed=seed, **options)
        averages = prof.key_averages()
        ops = {e.key: e.self_cpu_time_total / 1e6 for e in averages}
        backward = sum(e.cpu_time_total / 1e6 for e in averages
                       if e.key.startswith("autograd::engine::evaluate_function:"))
        profiled = sum(ops.values())
        pr = cProfile.Profile()
        t0, cpu0 = time.perf_counter(), time.process_time()
        pr.enable()
        train(learner, demos, seed=seed, **options)
        pr.disable()
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    stats = pstats.Stats(pr).stats  # type: ignore[attr-defined]
    functions: dict[str, float] = {}
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.items():
        if "lfd/learners/" not in file.replace("\\", "/"):
            continue
        key = f"{Path(file).name}:{name}"
        functions[key] = functions.get(key, 0.0) + float(ct)
    keep_ops = dict(sorted(ops.items(), key=lambda kv: -kv[1])[:top])
    keep_fns = dict(sorted(functions.items(), key=lambda kv: -kv[1])[:top])
    return {"cpu_s": cpu, "wall_s": wall, "ops": keep_ops, "ops_total_s": profiled, "backward_s": backward,
            "functions": keep_fns}
