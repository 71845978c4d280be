#!/usr/bin/env python
"""Obstacles on the arm: the Panda runs an avoiding field around a sphere on its path. Prints, asserts nothing.

For each learner (contraction, NODE; trained once on the default spiral and cached like
scripts/demo_arm.py), a sphere is put on the demonstrated path (the mean demo at ``--at`` of its
arc length), in the scene as a MuJoCo geom and in the field (``lfd.avoid``) with a clearance
margin for the hand around the tool point (``--hand-clearance-mm``). Scenarios: none, the
standard push (20 N, 0.2 s, on the hand) and the goal moved by 20% of the extent mid-run (at
``--shift-at`` s, blended over 0.5 s, ``lfd.goal.shift_goal``; the loop passes the time to the
field). Per run: robot-obstacle contacts (the joint trajectory replayed
through MuJoCo's collision detection, ``sim.obstacles.obstacle_contacts``), the smallest clearance,
the final goal error, joint-limit violations and the peak joint speed against the limits. The bare
field (no avoidance) is run too, to show what the obstacle does without it (both with the
controller's ``--lead-ms`` phase lead, ``sim.controller.Gains.lead_s``, which keeps the arm from
lagging outward where the avoiding field turns fast), and the bare field with
the goal shift in a scene without the sphere ("free"). The peak joint speed is
the largest measured |qdot_j| / v_max_j over the run.

Usage: python scripts/panda_obstacles.py [--radius 0.05] [--at 0.2] [--hand-clearance-mm 22]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
os.environ.setdefault("MUJOCO_GL", "egl")

import lfd  # noqa: E402
import sim  # noqa: E402
from lfd.cache import cached_field  # noqa: E402
from lfd.goal import shift_goal  # noqa: E402
from lfd.obstacles import Sphere, avoid  # noqa: E402
from robots import load_robot  # noqa: E402
from sim.controller import Gains  # noqa: E402
from sim.obstacles import obstacle_contacts  # noqa: E402


def on_path(demos: lfd.DemoSet, fraction: float, radius: float, margin: float) -> Sphere:
    """A sphere of ``radius`` (fraction of the extent) centred on the mean demo at ``fraction`` of its length."""
    x = demos.x.mean(axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    extent = demos.extent
    return Sphere(x[np.searchsorted(s, fraction * s[-1])], radius * extent, margin=margin)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", type=float, default=0.05, help="sphere radius, fraction of the demos' extent")
    ap.add_argument("--at", type=float, default=0.2, help="fraction of the mean demo's arc length")
    ap.add_argument("--hand-clearance-mm", type=float, default=22.0,
                    help="margin the field keeps around the sphere for the hand, mm")
    ap.add_argument("--learners", default="contraction,node")
    ap.add_argument("--settle", type=float, default=1.5, help="seconds the run continues after the demo duration")
    ap.add_argument("--shift-at", type=float, default=2.0, help="time of the goal shift, s")
    ap.add_argument("--lead-ms", type=float, default=10.0,
                    help="the controller's phase lead on the task velocity with the sphere (sim.controller.Gains)")
    args = ap.parse_args()

    demos = lfd.spiral()
    robot = load_robot("panda")
    placement = sim.Placement.auto(robot, demos.x)
    extent = demos.extent
    margin = args.hand_clearance_mm / 1000.0 / placement.scale
    sphere = on_path(demos, args.at, args.radius, margin)
    print(f"sphere: centre {np.round(sphere.center, 3).tolist()} radius {sphere.radius:.3f} units "
          f"({1000 * sphere.radius * placement.scale:.1f} mm), margin {margin:.3f} units "
          f"({args.hand_clearance_mm:.0f} mm); path extent {extent:.2f} units "
          f"({1000 * extent * placement.scale:.0f} mm)")
    exp = sim.Experiment(robot, demos, placement=placement, settle_s=args.settle, obstacles=[sphere],
                         gains=Gains(lead_s=args.lead_ms / 1000.0))
    scene = exp.robot
    free = sim.Experiment(robot, demos, placement=placement, settle_s=args.settle)
    angle = np.random.default_rng(0).uniform(0.0, 2.0 * np.pi)
    dx = 0.2 * extent * np.array([np.cos(angle), np.sin(angle)])
    print(f"goal shift: {np.round(dx, 3).tolist()} units ({1000 * 0.2 * extent * placement.scale:.1f} mm) "
          f"at t = {args.shift_at:g} s")
    print(f"{'learner':<12} {'field':<6} {'scenario':<6} {'contacts':>8} {'clear mm':>9} {'goal mm':>8} "
          f"{'jl viol':>7} {'peak |qd|/limit':>15}")
    for learner in args.learners.split(","):
        field, _, _ = cached_field(learner, demos, 0, {}, progress=True)
        moved = shift_goal(field, args.shift_at, dx)
        for name, f, g in (("bare", field, moved), ("avoid", avoid(field, [sphere]), avoid(moved, [sphere]))):
            for scen, run_field, perts in (("none", f, None), ("push", f, None), ("goal", g, ())):
                r = exp.run(run_field, scen, perturbations=perts)
                ro = r.trace
                rep = obstacle_contacts(scene, ro.q, ro.t)
                peak = float(np.max(np.abs(ro.qdot) / np.asarray(robot.v_max)))
                print(f"{learner:<12} {name:<6} {scen:<6} {rep.contacts:>8d} {1000 * rep.min_clearance_m:>9.2f} "
                      f"{1000 * r.metrics['final_goal_error_m']:>8.2f} {r.metrics['joint_limit_violations']:>7d} "
                      f"{peak:>15.3f}", flush=True)
        r = free.run(moved, "goal", perturbations=())   # the goal shift alone, in a scene without the sphere
        peak = float(np.max(np.abs(r.trace.qdot) / np.asarray(robot.v_max)))
        print(f"{learner:<12} {'free':<6} {'goal':<6} {'-':>8} {'-':>9} {1000 * r.metrics['final_goal_error_m']:>8.2f} "
              f"{r.metrics['joint_limit_violations']:>7d} {peak:>15.3f}", flush=True)


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
