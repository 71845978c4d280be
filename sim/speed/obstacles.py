"""Obstacle avoidance and moving goals in task space: what they cost and achieve. Prints, asserts nothing.

1. Spiral and 5 LASA shapes, a contraction field trained with default options, a sphere on the
   demonstrated path (centre on the mean demo at 45% of its arc length, radius 8% of the extent):
   100 seeded starts (demo starts + uniform noise of +-15% of the extent, outside the obstacle);
   goal reached (final error < 1% of the extent after 4 demo durations), penetrations (a start
   with Gamma < 1 anywhere on its path), path-length overhead against the same starts without
   the obstacle (mean, and over the paths the obstacle actually blocks).
2. The same on the spiral with two overlapping obstacles (a sphere and a box, merged) and with a
   moving sphere that sweeps across the path (it is on the nominal path from the mean start at 30%
   of the demo duration, when the robot gets there).
3. A goal moved by 20% of the extent mid-run: final error, peak speed against the nominal one.
4. Cost per control step with 3 obstacles (a sphere, a box, a capsule): ``point_fn`` of the
   avoiding field against the bare field's ``point_fn``, interleaved; median and p95 of each and of
   the extra per call, and the ratio. Wall clock: note the load average printed with it.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

import lfd
from lfd.goal import shift_goal
from lfd.obstacles import Box, Capsule, Obstacle, Sphere, avoid, starts_outside
from sim.run.parsing import names
from sim.speed.timing import load

__all__ = ["add_arguments", "cost", "on_path", "reach", "run"]

SHAPES = ("Angle", "CShape", "GShape", "Sshape", "Worm")


def extent_of(demos: lfd.DemoSet) -> float:
    """The largest side of the demos' bounding box."""
    return float(np.max(np.ptp(demos.x.reshape(-1, demos.dim), axis=0)))


def on_path(demos: lfd.DemoSet, fraction: float, radius: float) -> Sphere:
    """A sphere of ``radius`` times the extent on the mean demo at ``fraction`` of its arc length."""
    x = demos.x.mean(axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    return Sphere(x[np.searchsorted(s, fraction * s[-1])], radius * extent_of(demos))


def length(y: np.ndarray) -> np.ndarray:
    """Path lengths of paths y, shape (..., T, d): shape (...)."""
    return np.linalg.norm(np.diff(y, axis=-2), axis=-1).sum(axis=-1)


def reach(name: str, field: Any, demos: lfd.DemoSet, obstacles: Sequence[Obstacle], n: int,
          check: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None, samples: int = 401) -> None:
    """Print what the avoiding field does from ``n`` starts outside the obstacles, rolled out over
    4 demo durations on ``samples`` times (parts 1, 2)."""
    f = avoid(field, list(obstacles))
    starts = starts_outside(f, demos, n)
    t = np.linspace(0.0, 4.0 * float(demos.t[0, -1]), samples)
    t0 = time.perf_counter()
    y = f.rollout(starts, t)
    wall = time.perf_counter() - t0
    gam = np.stack([f.gamma(y[:, j], float(tj)) for j, tj in enumerate(t)], axis=1)   # (B, T)
    if check is not None:
        gam = np.minimum(gam, check(y, t))
    ext = extent_of(demos)
    reached = np.linalg.norm(y[:, -1] - field.goal, axis=1) < 0.01 * ext
    y0 = field.rollout(starts, t)
    nominal_ok = np.linalg.norm(y0[:, -1] - field.goal, axis=1) < 0.01 * ext
    blocked = np.array([np.any(np.concatenate([o.gamma(y0[i]) for o in obstacles if not o.moving] or [np.ones(1)]) < 1)
                        for i in range(len(y0))])
    over = length(y) / length(y0) - 1
    blk = f"{over[blocked].mean():6.1%}" if blocked.any() else "   n/a"
    print(f"{name:<28} reach {reached.mean():6.1%} (nominal {nominal_ok.mean():6.1%})  penetrations "
          f"{int(np.sum(gam.min(axis=1) < 1.0)):3d}  min Gamma {gam.min():.4f}  overhead mean {over.mean():6.1%}"
          f"  blocked {blk} ({int(blocked.sum())} paths)  rollout {wall:.1f} s", flush=True)


def interleaved_us(fa: Callable[[np.ndarray], Any], fb: Callable[[np.ndarray], Any], x: np.ndarray,
                   calls: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-call times in us of fa(x) and fb(x), called alternately ``calls`` times: shape (calls,) each."""
    ta, tb = np.empty(calls), np.empty(calls)
    pc = time.perf_counter
    for i in range(calls):
        t0 = pc()
        fa(x)
        t1 = pc()
        fb(x)
        t2 = pc()
        ta[i], tb[i] = t1 - t0, t2 - t1
    return ta * 1e6, tb * 1e6


def cost(name: str, field: Any, obstacles: Sequence[Obstacle], x: np.ndarray, calls: int) -> None:
    """Print the single-point cost of the avoiding field against the bare one at x, shape (d,) (part 4)."""
    bare, mod = field.single_point_evaluator(), avoid(field, list(obstacles)).single_point_evaluator()
    for _ in range(2000):
        bare(x), mod(x)
    tb, tm = interleaved_us(bare, mod, x, calls)
    extra = tm - tb
    print(f"{name:<28} bare median {np.median(tb):6.2f} us p95 {np.percentile(tb, 95):6.2f} | with 3 obstacles "
          f"median {np.median(tm):6.2f} us p95 {np.percentile(tm, 95):6.2f} | extra median {np.median(extra):6.2f} us "
          f"p95 {np.percentile(extra, 95):6.2f} | ratio {np.median(tm) / np.median(tb):.2f}x  "
          f"(load average {load():.1f})", flush=True)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--shapes``, ``--starts``, ``--calls``."""
    ap.add_argument("--shapes", default=",".join(SHAPES), help="LASA shapes besides the spiral, comma-separated")
    ap.add_argument("--starts", type=int, default=100)
    ap.add_argument("--calls", type=int, default=20000)


def run(args: argparse.Namespace) -> int:
    """Parts 1-4 (module docstring); ``--quick``: the spiral alone, 5 starts, rollouts on a tenth of the
    times, 200 calls, 2 training iterations."""
    torch.set_num_threads(1)
    n, calls = (5, 200) if args.quick else (args.starts, args.calls)
    grid = 10 if args.quick else 1   # rollouts on every grid-th time
    training: dict[str, Any] = {"iterations": 2} if args.quick else {}

    print("== 1. obstacle on the demonstrated path (contraction field, default options)")
    fields = {}
    for spec in ["spiral"] + ([] if args.quick else [f"lasa:{s}" for s in names(args.shapes)]):
        demos = lfd.load_demos(spec)
        t0 = time.perf_counter()
        field = lfd.train("contraction", demos, seed=0, **training)
        print(f"   trained {spec} in {time.perf_counter() - t0:.1f} s", flush=True)
        fields[spec] = (field, demos)
        reach(spec, field, demos, [on_path(demos, 0.45, 0.08)], n, samples=400 // grid + 1)

    print("== 2. two overlapping obstacles; a moving obstacle (spiral)")
    field, demos = fields["spiral"]
    a = on_path(demos, 0.4, 0.06)
    reach("spiral, sphere + box overlap", field, demos, [a, Box(a.center + [0.08, 0.05], [0.07, 0.05])], n,
          samples=400 // grid + 1)
    tc = 0.3 * float(demos.t[0, -1])          # the sphere crosses the nominal path when the robot is there
    meet = field.rollout(demos.x[:, 0].mean(axis=0), np.linspace(0.0, tc, 200))[-1]
    v = np.array([-0.15, 0.1])
    moving = Sphere(meet - tc * v, 0.07 * extent_of(demos), velocity=v)
    reach("spiral, moving sphere", field, demos, [moving], n,
          check=lambda y, t: np.stack([moving.gamma(y[:, j], float(tj)) for j, tj in enumerate(t)], axis=1),
          samples=400 // grid + 1)

    print("== 3. goal moved by 20% of the extent at half the demo duration (blend 0.5 s)")
    for spec, (field, demos) in fields.items():
        ext = extent_of(demos)
        dx = np.array([0.2 * ext, 0.0])
        T = float(demos.t[0, -1])
        moved = shift_goal(field, 0.5 * T, dx, blend=0.5)
        t = np.linspace(0.0, 5.0 * T, 1000 // grid + 1)
        y, y0 = moved.rollout(demos.x[:, 0], t), field.rollout(demos.x[:, 0], t)
        sp = np.linalg.norm(np.diff(y, axis=1), axis=2).max() / (t[1] - t[0])
        sp0 = np.linalg.norm(np.diff(y0, axis=1), axis=2).max() / (t[1] - t[0])
        err = np.linalg.norm(y[:, -1] - (field.goal + dx), axis=1).max()
        print(f"{spec:<28} final error {err / ext:.2e} x extent ({err:.3g} units); peak speed {sp:.3g} vs "
              f"nominal {sp0:.3g} units/s (blend adds at most {15 / 8 * np.linalg.norm(dx) / 0.5:.3g})", flush=True)

    print("== 4. cost per control step with 3 obstacles (sphere, box, capsule)")
    field, demos = fields["spiral"]
    obs2 = [on_path(demos, 0.45, 0.08), Box(demos.goal + [0.5, 0.5], [0.05, 0.1]),
            Capsule(demos.goal + [-0.6, 0.4], demos.goal + [-0.4, 0.6], 0.05)]
    cost("2-D contraction field", field, obs2, demos.x[0, 0], calls)
    d3 = lfd.load_demos("spiral3d")
    node3 = lfd.train("node", d3, seed=0, iterations=2)   # timing only: the cost does not depend on training
    g = d3.goal
    obs3 = [Sphere(g + [0.3, 0.2, 0.1], 0.1), Box(g + [-0.4, 0.2, 0.1], [0.1, 0.1, 0.2]),
            Capsule(g + [0.2, -0.4, 0.0], g + [0.4, -0.4, 0.3], 0.05)]
    cost("3-D NODE field", node3, obs3, d3.x[0, 0], calls)
    return 0
