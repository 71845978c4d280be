"""What the speed measurements (``sim.speed``) share: blocks of timed calls, their median and 95th
percentile, ratios of medians, the machine's load, the fields they train and the runs they score.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import lfd

__all__ = ["TRAINING", "each_call_s", "load", "median_ratio", "none_and_push", "per_call_us", "stats", "train_each"]

#: the fields that ``field`` and ``pose`` time: learner -> training options (few iterations: the cost
#: of one call does not depend on how well the field is trained)
TRAINING: dict[str, dict[str, Any]] = {"node": {"iterations": 50}, "stable_node": {"iterations": 50},
                                      "contraction": {"iterations": 30}, "contracting_node": {"iterations": 30},
                                      "tracking": {}}


def load() -> float:
    """The machine's load average over the last minute (quote it with every wall time)."""
    return os.getloadavg()[0]


def per_call_us(f: Callable[[np.ndarray], Any], x: np.ndarray, blocks: int = 200,
                calls: int = 50) -> tuple[float, float]:
    """Median and p95 of the per-call time of ``f(x)`` in us, over ``blocks`` blocks of ``calls`` calls.

    Parameters
    ----------
    f : callable
        Called on x, shape (d,).
    x : array, shape (d,)
    blocks, calls : int
    """
    per = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(calls):
            f(x)
        per.append((time.perf_counter() - t0) / calls * 1e6)
    return float(np.median(per)), float(np.percentile(per, 95))


def stats(seconds: np.ndarray) -> str:
    """``median ... us   p95 ... us`` of times in seconds, shape (n,)."""
    return f"median {np.median(seconds) * 1e6:7.1f} us   p95 {np.percentile(seconds, 95) * 1e6:7.1f} us"


def median_ratio(a: np.ndarray, b: np.ndarray) -> float:
    """median(a) / median(b) of two sets of times."""
    return float(np.median(a) / np.median(b))


def train_each(demos: lfd.DemoSet, quick: bool) -> list[tuple[str, Any]]:
    """(learner, field) of every learner of ``TRAINING`` on ``demos``, seed 0 (``quick``: 2 iterations)."""
    out = []
    for learner, opts in TRAINING.items():
        if quick and "iterations" in opts:
            opts = {**opts, "iterations": 2}
        out.append((learner, lfd.train(learner, demos, seed=0, progress=False, **opts)))
    return out


def none_and_push(exp: Any, field: Any) -> tuple[dict[str, Any], dict[str, Any], str]:
    """(metrics unperturbed, metrics pushed, recovery time as ``' 0.42 s'`` or ``'never'``) of
    ``field`` run by the ``sim.Experiment`` ``exp`` under the scenarios ``none`` and ``push``."""
    a = exp.run(field, "none").metrics
    b = exp.run(field, "push").metrics
    rec = b["recovery_time_s"]
    return a, b, "never" if rec is None else f"{rec:5.2f} s"


def each_call_s(f: Callable[[np.ndarray], Any], x: np.ndarray, n: int = 20000) -> np.ndarray:
    """Wall time of each of ``n`` calls ``f(x_k)``, x_k cycling through the points x, shape (K, d):
    shape (n,), in seconds."""
    out = np.empty(n)
    clock = time.perf_counter
    for k in range(n):
        xk = x[k % len(x)]
        t0 = clock()
        f(xk)
        out[k] = clock() - t0
    return out
