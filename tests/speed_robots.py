"""Speed of the robots hot path (not a test): prints median and p95 in microseconds per call, and the load average.

Run: python tests/speed_robots.py
"""
# ruff: noqa: B023  (each lambda is timed inside the loop that defines it)

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from robots import BUILTIN_ROBOTS, DifferentialIK, Kinematics, load_robot


def _time(fn: Callable[[], object], calls: int, repeats: int = 7) -> tuple[float, float]:
    """(median, p95) over ``repeats`` batches of the mean time per call, in microseconds."""
    batches = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        batches.append((time.perf_counter() - start) / calls * 1e6)
    return float(np.median(batches)), float(np.percentile(batches, 95))


def main() -> None:
    print(f"load average (1, 5, 15 min): {os.getloadavg()}, cpus: {os.cpu_count()}")
    for name in BUILTIN_ROBOTS:
        start = time.perf_counter()
        robot = load_robot(name)
        print(f"\n{name}: load_robot {1e3 * (time.perf_counter() - start):.0f} ms, n = {robot.n}")
        q = robot.q_home + 0.05
        twist = np.array([0.1, -0.05, 0.05, 0.0, 0.0, 0.1])
        kin = Kinematics(robot)
        dls, pink = DifferentialIK(robot, "dls"), DifferentialIK(robot, "pink")
        kin.update(q)
        rows = {
            "Kinematics.update": (lambda: kin.update(q), 20000),
            "update + ee_position + ee_jacobian": (lambda: (kin.update(q), kin.ee_position(), kin.ee_jacobian()),
                                                   20000),
            "dls solve (kin=updated)": (lambda: dls.solve(q, twist, 0.002, kin=kin), 5000),
            "dls solve (own update)": (lambda: dls.solve(q, twist, 0.002), 5000),
            "pink solve": (lambda: pink.solve(q, twist, 0.002), 500),
        }
        for label, (fn, calls) in rows.items():
            median, p95 = _time(fn, calls)
            print(f"  {label:38s} median {median:8.1f} us   p95 {p95:8.1f} us")


if __name__ == "__main__":
    main()
