"""Speed: one single-point call ``field(x)`` per learner, the control-loop path.

Prints the median and p95 in microseconds over blocks of calls, the first-call time (numba compiles
or loads the contraction kernel then), and the ratio to the NODE. Asserts nothing. Targets:
contraction <= 20 us, NODE <= 10 us.

    python scripts/speed_field.py
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from _speed import run_main


def time_calls(f, x: np.ndarray, blocks: int = 200, calls: int = 50) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Median and p95 of the per-call time in us over ``blocks`` blocks of ``calls`` calls."""
    per = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(calls):
            f(x)
        per.append((time.perf_counter() - t0) / calls * 1e6)
    return float(np.median(per)), float(np.percentile(per, 95))


def main() -> int:
    import torch

    import lfd

    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    demos = lfd.spiral()
    x = demos.x[0, 10].copy()
    rows = []
    for learner, opts in (("node", {"iterations": 50}), ("contraction", {"iterations": 30}), ("tracking", {})):
        field = lfd.train(learner, demos, seed=0, progress=False, **opts)
        t0 = time.perf_counter()
        field(x)
        first_ms = (time.perf_counter() - t0) * 1e3
        med, p95 = time_calls(field, x)
        rows.append((learner, med, p95, first_ms))
    node = rows[0][1]
    print(f"{'learner':12s} {'median us':>10s} {'p95 us':>8s} {'first call ms':>14s} {'/ node':>7s}")
    for learner, med, p95, first in rows:
        print(f"{learner:12s} {med:10.2f} {p95:8.2f} {first:14.1f} {med / node:7.2f}")
    return 0


if __name__ == "__main__":
    run_main(main, "speed_field")
