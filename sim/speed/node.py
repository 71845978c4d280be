"""Speed and accuracy of the NODE learner on torchdiffeq's spiral (its examples/ode_demo.py).

True dynamics dy/dt = y^3 A (y a row vector, cube elementwise), A = [[-0.1, 2.0], [-2.0, -0.1]],
y0 = (2, 0), t in [0, 25], 1000 samples (dopri5, rtol 1e-10). The baseline is torchdiffeq's own
script (dopri5, batch_time 10, batch_size 20, 2000 iterations; its time and error are in the README's
measured results). Target: MAE <= 0.05 in <= 13 s, from a plain MLP on y.

What runs is ``lfd.train("node", ...)``: the learner's normalisation (goal = last sample, unit
box), multiple shooting with stratified batches, a curriculum on the segment length and a cosine
Adam schedule (``lfd.learners.node``). The goal is not an equilibrium here (the spiral still turns
at t = 25), so ``goal_equilibrium=False``. MAE = mean |y_hat(t_k) - y(t_k)| over the 1000 samples
and both coordinates, y_hat integrated from y0 over the whole span by dopri5 (rtol 1e-7) in float64:
the learned field's own flow, not the training solver. Also times ``field.single_point_evaluator()``,
the control loop's single-point path (median and p95). Prints numbers; never asserts a time.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import torch

import lfd
from lfd import integrate
from sim.speed.timing import load

__all__ = ["OPTIONS", "add_arguments", "point_fn_us", "run", "spiral_data", "train_and_score"]

A = ((-0.1, 2.0), (-2.0, -0.1))
Y0 = (2.0, 0.0)
T_END, N_SAMPLES = 25.0, 1000
# Options of the run. Unlike the learner's defaults (tuned for ~100-sample robot demos): all 1000
# samples (samples=0), batch 256 and 800 iterations, lr 2e-2 (over seeds 0-4 a smaller lr or fewer
# iterations gave a larger worst MAE), no equilibrium imposed at the goal.
OPTIONS: dict[str, Any] = dict(hidden=(64, 64), activation="tanh", iterations=800, lr=2e-2, lr_final=1e-4, seg=10,
                               seg_start=2, curriculum=0.5, batch=256, samples=0, solver="rk4", dtype="float32",
                               goal_equilibrium=False)
QUICK_ITERATIONS = 5


def spiral_data(rtol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """The true trajectory: t (1000,), y (1000, 2), from dy/dt = y^3 A by dopri5 at ``rtol``
    (atol = rtol / 100)."""
    a = torch.tensor(A, dtype=torch.float64)
    t = torch.linspace(0.0, T_END, N_SAMPLES, dtype=torch.float64)
    with torch.no_grad():
        y = integrate.solve(lambda _t, y: y ** 3 @ a, torch.tensor([Y0], dtype=torch.float64), t,
                            **integrate.odeint_kwargs("dopri5", rtol=rtol, atol=rtol / 100))
    return t.numpy(), y[:, 0].numpy()


def point_fn_us(field: lfd.VelocityField, x: np.ndarray, blocks: int = 200,
                calls: int = 100) -> tuple[float, float]:
    """Median and p95 time of one ``field.single_point_evaluator()`` call, in us, over ``blocks``
    blocks of ``calls`` calls on consecutive points of x, shape (K, d)."""
    f = field.single_point_evaluator()
    times = []
    for b in range(blocks):
        xb = x[(b * calls) % len(x):][:calls]
        t0 = time.perf_counter()
        for xi in xb:
            f(xi)
        times.append((time.perf_counter() - t0) / len(xb) * 1e6)
    return float(np.median(times)), float(np.percentile(times, 95))


def train_and_score(seed: int, t: np.ndarray, y: np.ndarray, progress: bool, blocks: int = 200,
                    **options: Any) -> dict[str, float]:
    """Train on (t (T,), y (T, 2)) with ``seed``; return train wall/CPU seconds, the full-trajectory MAE
    and the single-point evaluation time of the numpy path."""
    demos = lfd.DemoSet(t, y[None], name="torchdiffeq-spiral")
    w0, c0 = time.perf_counter(), time.process_time()
    field = lfd.train("node", demos, seed=seed, progress=progress, **{**OPTIONS, **options})
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    y_hat = field.rollout(y[0], t, method="dopri5")
    median_us, p95_us = point_fn_us(field, y, blocks=blocks)
    return {"wall_s": wall, "cpu_s": cpu, "mae": float(np.mean(np.abs(y_hat - y))),
            "point_us": median_us, "point_p95_us": p95_us, "interrupted": bool(field.history["interrupted"])}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--seeds``, ``--iters``, ``--progress``."""
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--iters", type=int, default=OPTIONS["iterations"])
    ap.add_argument("--progress", action="store_true", help="show the training progress bar")


def run(args: argparse.Namespace) -> int:
    """Train once per seed and print each training's time, MAE and single-point time (``--quick``:
    5 iterations, the true trajectory at rtol 1e-6)."""
    torch.set_num_threads(1)  # small batches: a second intra-op thread only waits (see the learner)
    iters = QUICK_ITERATIONS if args.quick else args.iters
    t, y = spiral_data(1e-6 if args.quick else 1e-10)
    print(f"torchdiffeq spiral: {N_SAMPLES} samples, t in [0, {T_END:g}]; NODE {OPTIONS['hidden']} "
          f"{OPTIONS['activation']}, {iters} iterations; load {load():.2f}")
    results = []
    for seed in args.seeds:
        r = train_and_score(seed, t, y, args.progress, blocks=5 if args.quick else 200, iterations=iters)
        results.append(r)
        print(f"seed {seed}: train wall {r['wall_s']:6.2f} s  cpu {r['cpu_s']:6.2f} s  MAE {r['mae']:.4f}  "
              f"point_fn {r['point_us']:.1f} us (p95 {r['point_p95_us']:.1f})"
              + ("  (interrupted)" if r["interrupted"] else ""), flush=True)
    if len(results) > 1:
        walls, maes = [r["wall_s"] for r in results], [r["mae"] for r in results]
        print(f"median: train wall {statistics.median(walls):.2f} s  MAE {statistics.median(maes):.4f}  "
              f"(max MAE {max(maes):.4f}, max wall {max(walls):.2f} s)")
    print(f"load after: {load():.2f}")
    return 0
