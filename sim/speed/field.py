"""Speed: one single-point call ``field(x)`` per learner, the control-loop path.

Prints the median and p95 in microseconds over blocks of calls, the first-call time (numba compiles
or loads the contraction kernel then), the ratio to the NODE, and the targets (``TARGETS_US``).
Asserts nothing.
"""

from __future__ import annotations

import argparse
import time
import warnings

import torch

import lfd
from sim.speed.timing import per_call_us, train_each

__all__ = ["TARGETS_US", "add_arguments", "run"]

#: learner -> the single-point time it should stay within, microseconds
TARGETS_US = {"contraction": 20.0, "node": 10.0}


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """No options but ``--quick``."""


def run(args: argparse.Namespace) -> int:
    """Train each field on the spiral and time ``field(x)`` at one demo point; print the table."""
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    demos = lfd.spiral()
    x = demos.x[0, 10].copy()
    rows = []
    for learner, field in train_each(demos, args.quick):
        t0 = time.perf_counter()
        field(x)
        first_ms = (time.perf_counter() - t0) * 1e3
        med, p95 = per_call_us(field, x, blocks=5 if args.quick else 200)
        rows.append((learner, med, p95, first_ms))
    node = rows[0][1]
    print(f"{'learner':12s} {'median us':>10s} {'p95 us':>8s} {'first call ms':>14s} {'/ node':>7s}")
    for learner, med, p95, first in rows:
        print(f"{learner:12s} {med:10.2f} {p95:8.2f} {first:14.1f} {med / node:7.2f}")
    print("targets: " + ", ".join(f"{learner} <= {us:g} us" for learner, us in TARGETS_US.items()))
    return 0
