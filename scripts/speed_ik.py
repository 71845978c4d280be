#!/usr/bin/env python
"""Differential IK back-ends, dls against pink, on the same rollout.

1. Speed: the joint states and twists of one closed-loop rollout (recorded with dls) are replayed
   through each back-end's ``solve``; prints median and p95 microseconds per solve (identical inputs).
2. Tracking: the closed loop is run with each back-end; prints tracking RMSE, final goal error,
   push deviation and recovery, IK limit hits and the whole control step's median cost.

Timings are wall clock: note the machine load (printed) when you quote them.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from _speed import run_main

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import lfd  # noqa: E402
import sim  # noqa: E402  (sets MUJOCO_GL before mujoco is imported)
from lfd.cache import cached_field  # noqa: E402
from robots import IK_BACKENDS, RobotError, load_robot  # noqa: E402
from sim.controller import (
    ACTUATIONS,  # noqa: E402
    FieldController,  # noqa: E402
)


def replay_cost(exp: sim.Experiment, field: lfd.VelocityField, q_path: np.ndarray, backend: str) -> np.ndarray:
    """Wall time of ``solve`` (s), shape (K,), for the twists of the field along q_path (K, n)."""
    ctl = FieldController(exp.robot, exp.placement, 1.0 / exp.options["control_hz"], ik=backend,
                          rotation_ref=exp.rotation_ref, mj_model=exp.physics.model.ptr)
    ctl.reset(q_path[0])
    f = field.single_point_evaluator()
    out = np.empty(len(q_path))
    clock = time.perf_counter
    for k, q in enumerate(q_path):
        p = ctl.measure(q)
        tw = ctl.twist(f(ctl.to_task(p))).copy()
        t0 = clock()
        ctl.solve_ik(q, tw)
        out[k] = clock() - t0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--learner", default="node", help="learner of the field (trained and cached if needed)")
    ap.add_argument("--model", help="a model file instead of training")
    ap.add_argument("--demos", default="spiral")
    ap.add_argument("--actuation", default="torque", choices=ACTUATIONS)
    args = ap.parse_args()
    try:
        demos = lfd.load_demos(args.demos)
        field = lfd.load(args.model) if args.model else cached_field(args.learner, demos)[0]
        robot = load_robot(args.robot, actuation=args.actuation)
        exps = {b: sim.Experiment(robot, demos, ik=b) for b in IK_BACKENDS}
    except (lfd.LfdError, sim.SimError, RobotError) as e:
        print(f"speed_ik: error: {e}", file=sys.stderr)
        return 2
    print(f"robot {robot.name}, field {field.learner} ({args.demos}), actuation {args.actuation}, "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    ref = exps["dls"].run(field, "none")
    q_path = ref.trace.q[:-1]
    print(f"\nspeed: solve() on the {len(q_path)} states of one dls rollout")
    for b in IK_BACKENDS:
        t = replay_cost(exps[b], field, q_path, b)
        print(f"  {b:5s} median {np.median(t) * 1e6:8.1f} us/solve   p95 {np.percentile(t, 95) * 1e6:8.1f} us")
    print("\ntracking (closed loop)  tracking_rmse  final_goal  push max_dev  recovery  ik_limit_hits  step")
    for b in IK_BACKENDS:
        a = ref.metrics if b == "dls" else exps[b].run(field, "none").metrics
        p = exps[b].run(field, "push").metrics
        rec = p["recovery_time_s"]
        print(f"  {b:5s}                {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['final_goal_error_m'] * 1e3:7.2f} mm"
              f"  {p['max_deviation_m'] * 1e3:8.2f} mm  {'never' if rec is None else f'{rec:5.2f} s':>8s}"
              f"  {a['ik_limit_hits']:13d}  {a['control_step_us']:5.0f} us")
    return 0


if __name__ == "__main__":
    run_main(main, "speed_ik")
