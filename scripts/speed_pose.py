"""Speed: one pose field at one point, per learner, the control loop's path.

A pose (x (3,), R (3, 3)) goes to its chart point (Eq. (P1)), through the field, and back to the
twist (v, omega) (Eq. (P3)); for the tracking learner the field is its phase evaluator at a phase
(the loop's path, Eqs. (T3)-(T4)). Prints the median and p95 in microseconds over blocks of calls,
and the chart's own share. Asserts nothing. Target: <= 30 us per point.

    python scripts/speed_pose.py
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from _speed import run_main
from speed_field import time_calls


def _pose_point(field: Any, demos: Any, rot: np.ndarray, phased: bool) -> tuple[Callable[[np.ndarray], np.ndarray],
                                                                             Callable[[np.ndarray], np.ndarray]]:
    """(pose -> twist through the field, pose -> twist through the chart alone) for positions p (3,)
    at the rotation rot (3, 3)."""
    from lfd.pose import quaternion_matrices

    chart = field.chart
    if phased:
        phase_fn = field.phase_point_fn(chart.point(demos.x[0, 0], quaternion_matrices(demos.q[0, 0])))

        def fn(z: np.ndarray) -> np.ndarray:
            return phase_fn(z, 0.3)[0]
    else:
        fn = field.single_point_evaluator()
    z0 = chart.point(demos.x[0, 40], rot)

    def pose_point(p: np.ndarray) -> np.ndarray:
        z = chart.point(p, rot)
        return chart.twist(z, fn(z))

    def chart_only(p: np.ndarray) -> np.ndarray:
        return chart.twist(chart.point(p, rot), z0)

    return pose_point, chart_only


def main() -> int:
    import torch

    import lfd
    from lfd.demos import DemoSet, robottasks
    from lfd.field import is_phased
    from lfd.pose import quaternion_matrices

    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    d = robottasks("pouring")
    demos = DemoSet(d.t[:, ::4], d.x[:, ::4], name="pouring", q=d.q[:, ::4])
    x, rot = demos.x[0, 40].copy(), quaternion_matrices(demos.q[0, 40])
    rows = []
    for learner, opts in (("node", {"iterations": 50}), ("contraction", {"iterations": 30}), ("tracking", {})):
        field = lfd.train(learner, demos, seed=0, progress=False, **opts)
        assert field.chart is not None
        pose_point, chart_only = _pose_point(field, demos, rot, is_phased(field))
        pose_point(x)
        med, p95 = time_calls(pose_point, x)
        chart_med, _ = time_calls(chart_only, x)
        rows.append((learner, med, p95, chart_med))
    print(f"{'learner':12s} {'median us':>10s} {'p95 us':>8s} {'chart us':>9s}")
    for learner, med, p95, chart_med in rows:
        print(f"{learner:12s} {med:10.2f} {p95:8.2f} {chart_med:9.2f}")
    return 0


if __name__ == "__main__":
    run_main(main, "speed_pose")
