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

import numpy as np

import sim
from lfd.errors import ConfigError
from robots import IK_BACKENDS, load_robot
from sim.run.parsing import names
from sim.speed.instrumented import replay_ik
from sim.speed.timing import load
from sim.speed.trained import add_field_arguments, field_of

__all__ = ["add_arguments", "run"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--robot``, ``--learner``, ``--model``, ``--demos``, ``--actuation``."""
    ap.add_argument("--robot", default="panda")
    add_field_arguments(ap, "node")


def run(args: argparse.Namespace) -> int:
    """Replay one dls rollout through each back-end, then run the loop with each; print both tables."""
    if len(names(args.learner)) > 1:
        raise ConfigError(f"--learner {args.learner}: ik replays one field; name one learner")
    robot = load_robot(args.robot, actuation=args.actuation)   # a bad name fails before any training
    demos, fields = field_of(args)
    field = fields[0]
    exps = {b: sim.Experiment(robot, demos, ik=b) for b in IK_BACKENDS}
    print(f"robot {robot.name}, field {field.learner} ({args.demos}), actuation {args.actuation}, "
          f"load average {load():.2f} on {os.cpu_count()} CPUs")
    ref = exps["dls"].run(field, "none")
    q_path = ref.trace.q[:-1]
    print(f"\nspeed: solve() on the {len(q_path)} states of one dls rollout")
    for b in IK_BACKENDS:
        t = replay_ik(exps[b], field, q_path, b)
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
