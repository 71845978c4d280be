"""Speed: one pose field at one point, per learner, the control loop's path.

A pose (x (3,), R (3, 3)) goes to its chart point (Eq. (P1)), through the field's runner at a phase
of 0.3 (the tracking learner's phase, Eqs. (T3)-(T4); the other fields take none), and back to the
twist (v, omega) (Eq. (P3)). Prints the median and p95 in microseconds over blocks of calls, the
chart's own share, and the target (``TARGET_US``). Asserts nothing.
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from lfd.demos import DemoSet, robottasks
from lfd.errors import ConfigError
from lfd.pose import PoseChart, quaternion_matrices
from sim.speed.timing import per_call_us, train_each

__all__ = ["TARGET_US", "add_arguments", "pose_point", "run"]

#: the time one pose should stay within, microseconds
TARGET_US = 30.0
PHASE = 0.3
CONTROL_DT = 0.002


def pose_point(field: Any, demos: DemoSet, start_rot: np.ndarray, rot: np.ndarray
               ) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """(pose -> twist through the field, pose -> twist through the chart alone) for positions p, shape
    (3,), at the rotation rot, shape (3, 3); the field's runner starts at demo 0's start, its
    rotation start_rot, shape (3, 3)."""
    chart = PoseChart.of(demos)
    runner = field.runner(chart.point(demos.x[0, 0], start_rot), CONTROL_DT)
    z0 = chart.point(demos.x[0, 40], rot)

    def through_field(p: np.ndarray) -> np.ndarray:
        z = chart.point(p, rot)
        return chart.twist(z, runner.command_at(z, 0.0, PHASE))

    def chart_only(p: np.ndarray) -> np.ndarray:
        return chart.twist(chart.point(p, rot), z0)

    return through_field, chart_only


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """No options but ``--quick``."""


def run(args: argparse.Namespace) -> int:
    """Train each field on the recorded pours (every 4th sample) and time one pose; print the table."""
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    d = robottasks("pouring")
    if d.q is None:
        raise ConfigError("robottasks:pouring holds no orientations")
    q = d.q[:, ::4]
    demos = DemoSet(d.t[:, ::4], d.x[:, ::4], name="pouring", q=q)
    x, rot = demos.x[0, 40].copy(), quaternion_matrices(q[0, 40])
    blocks = 5 if args.quick else 200
    rows = []
    for learner, field in train_each(demos, args.quick):
        through_field, chart_only = pose_point(field, demos, quaternion_matrices(q[0, 0]), rot)
        through_field(x)
        med, p95 = per_call_us(through_field, x, blocks=blocks)
        chart_med, _ = per_call_us(chart_only, x, blocks=blocks)
        rows.append((learner, med, p95, chart_med))
    print(f"{'learner':12s} {'median us':>10s} {'p95 us':>8s} {'chart us':>9s}")
    for learner, med, p95, chart_med in rows:
        print(f"{learner:12s} {med:10.2f} {p95:8.2f} {chart_med:9.2f}")
    print(f"target: <= {TARGET_US:g} us per point")
    return 0
