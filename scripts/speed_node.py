"""Speed and accuracy of the NODE learner on torchdiffeq's spiral (examples/ode_demo.py).

True dynamics dy/dt = y^3 A (y a row vector, cube elementwise), A = [[-0.1, 2.0], [-2.0, -0.1]],
y0 = (2, 0), t in [0, 25], 1000 samples (dopri5, rtol 1e-10). The baseline is torchdiffeq's own
script (dopri5, batch_time 10, batch_size 20, 2000 iterations; its time and error are in the README's
measured results). Target: MAE <= 0.05 in <= 13 s, from a plain MLP on y.

What runs is ``lfd.train("node", ...)``: the learner's normalisation (goal = last sample, unit
box), multiple shooting with stratified batches, a curriculum on the segment length and a cosine
Adam schedule (see ``lfd.learners.node``). The goal is not an equilibrium here (the spiral still
turns at t = 25), so ``goal_equilibrium=False``.

MAE = mean |y_hat(t_k) - y(t_k)| over the 1000 samples and both coordinates, in the original
units, with y_hat integrated from y0 over the whole span by dopri5 (rtol 1e-7) in float64: the
learned field's own flow, not the training solver. Also times ``field.single_point_evaluator()``, the numpy
single-point path of the control loop (median and p95). Prints numbers; never asserts a time.

    python scripts/speed_node.py [--seeds 0 1 2] [--iters 800] [--progress]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import torch

import lfd
from lfd import integrate

A = ((-0.1, 2.0), (-2.0, -0.1))
Y0 = (2.0, 0.0)
T_END, N_SAMPLES = 25.0, 1000
# Options of the run. Unlike the learner's defaults (tuned for ~100-sample robot demos): all 1000
# samples (samples=0), batch 256 and 800 iterations, lr 2e-2 (over seeds 0-4 a smaller lr or fewer
# iterations gave a larger worst MAE), no equilibrium imposed at the goal.
OPTIONS = dict(hidden=(64, 64), activation="tanh", iterations=800, lr=2e-2, lr_final=1e-4, seg=10, seg_start=2,
               curriculum=0.5, batch=256, samples=0, solver="rk4", dtype="float32",
               goal_equilibrium=False)


def spiral_data() -> tuple[np.ndarray, np.ndarray]:
    """The true trajectory: t (1000,), y (1000, 2), from dy/dt = y^3 A by dopri5."""
    a = torch.tensor(A, dtype=torch.float64)
    t = torch.linspace(0.0, T_END, N_SAMPLES, dtype=torch.float64)
    with torch.no_grad():
        y = integrate.solve(lambda _t, y: y ** 3 @ a, torch.tensor([Y0], dtype=torch.float64), t,
                            **integrate.odeint_kwargs("dopri5", rtol=1e-10, atol=1e-12))
    return t.numpy(), y[:, 0].numpy()


def point_fn_us(field: lfd.VelocityField, x: np.ndarray, blocks: int = 200,
                calls: int = 100) -> tuple[float, float]:
    """Median and p95 time of one ``field.single_point_evaluator()`` call, in us, over blocks of ``calls`` calls."""
    f = field.single_point_evaluator()
    times = []
    for b in range(blocks):
        xb = x[(b * calls) % len(x):][:calls]
        t0 = time.perf_counter()
        for xi in xb:
            f(xi)
        times.append((time.perf_counter() - t0) / len(xb) * 1e6)
    return float(np.median(times)), float(np.percentile(times, 95))


def run(seed: int, t: np.ndarray, y: np.ndarray, progress: bool, **options: object) -> dict[str, float]:
    """Train on (t, y) with ``seed``; return train wall/CPU seconds, the full-trajectory MAE and
    the single-point evaluation time of the numpy path."""
    demos = lfd.DemoSet(t, y[None], name="torchdiffeq-spiral")
    w0, c0 = time.perf_counter(), time.process_time()
    field = lfd.train("node", demos, seed=seed, progress=progress, **{**OPTIONS, **options})
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    y_hat = field.rollout(y[0], t, method="dopri5")
    median_us, p95_us = point_fn_us(field, y)
    return {"wall_s": wall, "cpu_s": cpu, "mae": float(np.mean(np.abs(y_hat - y))),
            "point_us": median_us, "point_p95_us": p95_us, "interrupted": bool(field.history["interrupted"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--iters", type=int, default=OPTIONS["iterations"])
    ap.add_argument("--progress", action="store_true", help="show the training progress bar")
    args = ap.parse_args()
    torch.set_num_threads(1)  # small batches: a second intra-op thread only waits (see the learner)
    t, y = spiral_data()
    print(f"torchdiffeq spiral: {N_SAMPLES} samples, t in [0, {T_END:g}]; NODE {OPTIONS['hidden']} "
          f"{OPTIONS['activation']}, {args.iters} iterations; load {os.getloadavg()[0]:.2f}")
    results = []
    for seed in args.seeds:
        r = run(seed, t, y, args.progress, iterations=args.iters)
        results.append(r)
        print(f"seed {seed}: train wall {r['wall_s']:6.2f} s  cpu {r['cpu_s']:6.2f} s  MAE {r['mae']:.4f}  "
              f"point_fn {r['point_us']:.1f} us (p95 {r['point_p95_us']:.1f})"
              + ("  (interrupted)" if r["interrupted"] else ""), flush=True)
    if len(results) > 1:
        walls, maes = [r["wall_s"] for r in results], [r["mae"] for r in results]
        print(f"median: train wall {statistics.median(walls):.2f} s  MAE {statistics.median(maes):.4f}  "
              f"(max MAE {max(maes):.4f}, max wall {max(walls):.2f} s)")
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
