#!/usr/bin/env python
"""Cost of one closed-loop control step against a bare ``mj_step`` of the same model, and the
choice of actuation by measurement.

Part 1 (cost): the control step of ``sim.rollout.execute`` (read state, Pinocchio FK, field at
the measured position, twist, IK, actuator command, perturbation hooks, ``mj_step``) timed step
by step, and a bare ``mujoco.mj_step`` of the same model and state, measured in the same run in
interleaved blocks (so machine load hits both alike). Prints median and p95 of each and their
ratio, then where the time goes (an instrumented copy of the same step), and what dm_control's
``Environment.step`` costs for the same step.

Part 2 (actuation): tracking and push metrics of the same field with position servos (velocity
feed-forward, and the plain u = q + qdot dt) and with computed torque (``sim.controller``).
Part 3 (plane): the same for a 2-D field on a horizontal and on a vertical task plane.

Timings are wall clock: note the machine load (printed) when you quote them.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import pinocchio as pin

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import sim  # noqa: E402  (sets MUJOCO_GL before mujoco is imported)
import mujoco  # noqa: E402

import lfd  # noqa: E402
from robots import RobotError, load_robot  # noqa: E402
from sim.modelcache import cached_field  # noqa: E402


def stats(x: np.ndarray) -> str:
    return f"median {np.median(x) * 1e6:7.1f} us   p95 {np.percentile(x, 95) * 1e6:7.1f} us"


def bare_steps(model: mujoco.MjModel, data: mujoco.MjData, n: int) -> np.ndarray:
    """Wall time of n bare mj_step calls, each timed, shape (n,)."""
    out = np.empty(n)
    clock = time.perf_counter
    for k in range(n):
        t0 = clock()
        mujoco.mj_step(model, data)
        out[k] = clock() - t0
    return out


def holding_data(exp: sim.Experiment, q: np.ndarray) -> mujoco.MjData:
    """Fresh MjData at rest at q, shape (n,), with controls that hold it there (the servo target q,
    or the gravity torque g(q)), so bare steps neither fall nor hit limits."""
    m, robot = exp.physics.model.ptr, exp.robot
    d = mujoco.MjData(m)
    d.qpos[robot.mj_qpos_adr] = q
    if exp.options["actuation"] == "position":
        d.ctrl[robot.mj_actuator_ids] = q
    else:
        d.ctrl[robot.mj_actuator_ids] = pin.computeGeneralizedGravity(robot.pin_model, robot.pin_model.createData(), q)
    mujoco.mj_forward(m, d)
    return d


def breakdown(exp: sim.Experiment, field: lfd.VelocityField, steps: int) -> dict[str, np.ndarray]:
    """Per-stage wall times of ``steps`` control steps of the rollout loop (same calls, timed)."""
    env = sim.make_environment(exp.robot, exp.placement, exp.start, field.goal, duration_s=exp.duration_s,
                               rotation_ref=exp.rotation_ref, physics=exp.physics, **exp.options)
    env.reset()
    task = env.task
    m, d = env.physics.model.ptr, env.physics.data.ptr
    ctl, f = task.controller, field.point_fn()
    qadr, dadr, acts = exp.robot.mj_qpos_adr, exp.robot.mj_dof_adr, exp.robot.mj_actuator_ids
    names = ("read state", "FK (Pinocchio)", "field f(x)", "twist", "IK", "actuation", "mj_step")
    t = {k: np.empty(steps) for k in names}
    clock = time.perf_counter
    for k in range(min(steps, task.n_steps)):
        c0 = clock()
        q = d.qpos[qadr]
        qd = d.qvel[dadr]
        c1 = clock()
        p = ctl.measure(q)
        c2 = clock()
        v = f(ctl.to_task(p))
        c3 = clock()
        tw = ctl.twist(v)
        c4 = clock()
        qd_ref = ctl.solve_ik(q, tw)
        c5 = clock()
        d.ctrl[acts] = ctl.actuate(q, qd, qd_ref)
        c6 = clock()
        mujoco.mj_step(m, d)
        c7 = clock()
        for name, a, b in zip(names, (c0, c1, c2, c3, c4, c5, c6), (c1, c2, c3, c4, c5, c6, c7)):
            t[name][k] = b - a
    return t


def env_steps(exp: sim.Experiment, field: lfd.VelocityField, steps: int) -> np.ndarray:
    """Wall time of dm_control ``Environment.step`` with the field as policy, shape (steps,)."""
    env = sim.make_environment(exp.robot, exp.placement, exp.start, field.goal, duration_s=exp.duration_s,
                               rotation_ref=exp.rotation_ref, physics=exp.physics, **exp.options)
    ts = env.reset()
    f, to_task = field.point_fn(), exp.placement.to_task
    out = np.empty(steps)
    clock = time.perf_counter
    for k in range(steps):
        t0 = clock()
        ts = env.step(f(to_task(ts.observation["ee_position"])))
        out[k] = clock() - t0
    return out


def cost(exp: sim.Experiment, field: lfd.VelocityField, repeats: int) -> None:
    m = exp.physics.model.ptr
    bare, loop = [], []
    for _ in range(repeats):
        ro = exp.rollout(field)
        loop.append(ro.step_time_s)
        d = holding_data(exp, ro.q[0])
        bare.append(bare_steps(m, d, len(ro.step_time_s)))
    bare_t, loop_t = np.concatenate(bare), np.concatenate(loop)
    print(f"bare mj_step          : {stats(bare_t)}   ({len(bare_t)} steps)")
    print(f"closed-loop step      : {stats(loop_t)}   ({len(loop_t)} steps)")
    print(f"ratio (median)        : {np.median(loop_t) / np.median(bare_t):.2f}    "
          f"ratio (p95) {np.percentile(loop_t, 95) / np.percentile(bare_t, 95):.2f}    (target <= 3)")
    parts = breakdown(exp, field, 2000)
    total = sum(np.median(v) for v in parts.values())
    print("breakdown (instrumented, medians):")
    for name, v in parts.items():
        print(f"  {name:16s} {np.median(v) * 1e6:7.1f} us  {np.median(v) / total:5.1%}")
    envt = env_steps(exp, field, 2000)
    print(f"dm_control Environment.step with the same controller: {stats(envt)}  "
          f"({np.median(envt) / np.median(loop_t):.1f}x the lean loop)")


def actuation(robot_name: str, demos: lfd.DemoSet, field: lfd.VelocityField, ik: str, plane: str) -> None:
    print("\nactuation    variant                  tracking_rmse  final_goal  push max_dev  recovery  step")
    for act, ff, label in (("position", False, "servo u = q + qdot dt"),
                           ("position", True, "servo + velocity ff"),
                           ("torque", True, "computed torque (RNEA)")):
        robot = load_robot(robot_name, actuation=act)
        exp = sim.Experiment(robot, demos, plane=plane, ik=ik, actuation=act, feedforward=ff)
        a = exp.run(field, "none").metrics
        b = exp.run(field, "push").metrics
        rec = b["recovery_time_s"]
        print(f"{act:12s} {label:24s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['final_goal_error_m'] * 1e3:7.2f} mm"
              f"  {b['max_deviation_m'] * 1e3:8.2f} mm  {'never' if rec is None else f'{rec:5.2f} s':>8s}"
              f"  {a['control_step_us']:5.0f} us")


def planes(robot_name: str, demos: lfd.DemoSet, field: lfd.VelocityField, ik: str, act: str) -> None:
    robot = load_robot(robot_name, actuation=act)
    if robot.planar or demos.dim != 2:
        return
    print(f"\ntask plane ({act})   tracking_rmse  imitation_rmse  final_goal  push max_dev  recovery")
    for plane in ("horizontal", "vertical"):
        exp = sim.Experiment(robot, demos, plane=plane, ik=ik, actuation=act)
        a = exp.run(field, "none").metrics
        b = exp.run(field, "push").metrics
        rec = b["recovery_time_s"]
        print(f"{plane:18s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['imitation_rmse_m'] * 1e3:9.2f} mm"
              f"  {a['final_goal_error_m'] * 1e3:7.2f} mm  {b['max_deviation_m'] * 1e3:8.2f} mm"
              f"  {'never' if rec is None else f'{rec:5.2f} s':>8s}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--learner", default="node", help="learner of the field (trained and cached if needed)")
    ap.add_argument("--model", help="a model file instead of training")
    ap.add_argument("--demos", default="spiral")
    ap.add_argument("--ik", default="dls")
    ap.add_argument("--actuation", default="torque", choices=sim.ACTUATIONS)
    ap.add_argument("--plane", default="auto")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rollout / bare blocks")
    ap.add_argument("--skip-actuation", action="store_true", help="only the cost part (no parts 2, 3)")
    args = ap.parse_args()
    try:
        demos = lfd.load_demos(args.demos)
        field = lfd.load(args.model) if args.model else cached_field(args.learner, demos)[0]
        robot = load_robot(args.robot, actuation=args.actuation)
        exp = sim.Experiment(robot, demos, plane=args.plane, ik=args.ik, actuation=args.actuation)
    except (lfd.LfdError, sim.SimError, RobotError) as e:
        print(f"bench_loop: error: {e}", file=sys.stderr)
        return 2
    print(f"robot {robot.name}, field {field.learner} ({args.demos}), ik {args.ik}, actuation {args.actuation}, "
          f"control {exp.options['control_hz']:g} Hz, load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} CPUs")
    cost(exp, field, args.repeats)
    if not args.skip_actuation:
        actuation(args.robot, demos, field, args.ik, args.plane)
        planes(args.robot, demos, field, args.ik, args.actuation)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("bench_loop: interrupted", file=sys.stderr)
        sys.exit(130)
