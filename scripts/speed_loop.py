#!/usr/bin/env python
"""Cost of one closed-loop control step against a bare ``mj_step`` of the same model, and the
choice of actuation by measurement.

Part 1 (cost), for each field of ``--learner`` (default: node and contraction): the control
step of ``sim.loop.execute`` (``mj_step1``, read state, FK, field at the measured position,
the fused twist + IK + actuator command, perturbation hooks, ``mj_step2``) timed step by step,
and a bare ``mujoco.mj_step`` of the same model at the run's start, at rest, measured in the
same run in interleaved blocks (so machine load hits both alike). Prints median and p95 of each
and their ratio; the same ratio in CPU time (``time.thread_time`` over the whole loop and over
as many bare steps: preemption by other processes does not count), and the real-time factor
(simulated s per wall s, and per CPU s); the targets (ratio <= 3, real-time factor >= 100) are
marked MET / NOT MET. Then where the time goes (an instrumented copy of the same step),
the field alone, and what the dm_env ``Environment.step`` of ``sim.make_environment`` costs for
the same step (same controller, same field, timed step by step in blocks interleaved with the
loop's; target: its median <= 1.3x the loop's), and the same ratio against a copy of the loop's
step in short alternating blocks (load hits both alike). A summary closes the run.

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
from typing import Any

import numpy as np
from _speed import none_and_push, run_main

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import mujoco  # noqa: E402

import lfd  # noqa: E402
import sim  # noqa: E402  (sets MUJOCO_GL before mujoco is imported)
from lfd.cache import cached_field  # noqa: E402
from robots import RobotError, load_robot  # noqa: E402
from sim.controller import ACTUATIONS  # noqa: E402
from sim.scaling import bare_steps, holding_data  # noqa: E402


def stats(x: np.ndarray) -> str:
    return f"median {np.median(x) * 1e6:7.1f} us   p95 {np.percentile(x, 95) * 1e6:7.1f} us"


def breakdown(exp: sim.Experiment, field: lfd.VelocityField, steps: int) -> dict[str, np.ndarray]:
    """Per-stage wall times of ``steps`` control steps of the rollout loop (the same calls as
    ``sim.loop.execute``, timed one by one; "field f(x)" includes the task point x), shape
    (steps,) each."""
    env = environment(exp, field)
    env.reset()
    task = env.task
    m, d = env.physics.model.ptr, env.physics.data.ptr
    ctl, f = task.controller, field.single_point_evaluator()
    qadr = exp.robot.mj_qpos_adr
    split = ctl.split
    ctl.bind(d)
    # as sim.loop: after mj_step1 MuJoCo's tool site and its Jacobian, else Pinocchio's FK
    measure = ctl.measure_site if split else ctl.measure
    names = ("mj_step1", "read state", "tool pose, Jacobian", "field f(x)", "twist+IK+command", "mj_step2")
    steps = min(steps, task.n_steps)
    t = {k: np.empty(steps) for k in names}
    clock = time.perf_counter
    for k in range(steps):
        c0 = clock()
        if split:
            mujoco.mj_step1(m, d)
        c1 = clock()
        q = d.qpos[qadr]
        c2 = clock()
        p = measure(q)
        c3 = clock()
        v = f(ctl.to_task(p))
        c4 = clock()
        task.apply(d, q, None, v, m)
        c5 = clock()
        if split:
            mujoco.mj_step2(m, d)
        else:
            mujoco.mj_step(m, d)
        c6 = clock()
        for name, a, b in zip(names, (c0, c1, c2, c3, c4, c5), (c1, c2, c3, c4, c5, c6)):
            t[name][k] = b - a
    return t


def field_cost(field: lfd.VelocityField, x: np.ndarray, n: int = 20000) -> np.ndarray:
    """Wall time of n single-point field evaluations at the points x, shape (K, d), shape (n,)."""
    f = field.single_point_evaluator()
    out = np.empty(n)
    clock = time.perf_counter
    for k in range(n):
        xk = x[k % len(x)]
        t0 = clock()
        f(xk)
        out[k] = clock() - t0
    return out


def environment(exp: sim.Experiment, field: lfd.VelocityField) -> Any:
    """The dm_env environment (``sim.make_environment``) of the rollouts that ``cost`` times: the same
    robot, placement, start, goal, controller options and compiled model."""
    return sim.make_environment(exp.robot, exp.placement, exp.start, field.goal, duration_s=exp.duration_s,
                                rotation_ref=exp.rotation_ref, physics=exp.physics, **exp.options)


def env_steps(env: Any, field: lfd.VelocityField, steps: int) -> tuple[np.ndarray, float]:
    """Wall time of dm_env ``Environment.step`` with the field as policy, shape (steps,), from a reset
    (untimed), at most one episode (a step past its end would time a reset), and the CPU time of
    all of them (``time.thread_time``, as ``RunTrace.cpu_s`` for the loop).

    The policy feeds the field the observed ``task_position``, the point the lean loop feeds it (the
    environment computes it for the observation, as the loop does for the field); each timed call
    covers the field and the step, as the lean loop's step does.
    """
    ts = env.reset()
    f = field.single_point_evaluator()
    out = np.empty(min(steps, env.task.n_steps))
    clock = time.perf_counter
    cpu0 = time.thread_time()
    for k in range(len(out)):
        t0 = clock()
        ts = env.step(f(ts.observation["task_position"]))
        out[k] = clock() - t0
    return out, time.thread_time() - cpu0


def interleaved_steps(exp: sim.Experiment, field: lfd.VelocityField, blocks: int,
                      block: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Wall times of dm_env ``Environment.step`` (policy as ``env_steps``) and of a copy of the lean
    loop's step (the calls of ``sim.loop``'s loop, recording q, qdot, p and v as it does), in
    ``blocks`` pairs of ``block`` steps each, alternating, on two copies of the model: short
    blocks, so that load on the machine hits both alike, each warm in its block (alternating
    every step would leave both cold, which flatters the environment). Returns each one's
    per-block medians, shape (blocks,). Episodes restart as needed (untimed)."""
    from sim.task import ArmPhysics

    env, twin = (sim.make_environment(exp.robot, exp.placement, exp.start, field.goal, duration_s=exp.duration_s,
                                      rotation_ref=exp.rotation_ref, physics=ArmPhysics.from_robot(exp.robot),
                                      **exp.options) for _ in range(2))
    task, clock = twin.task, time.perf_counter
    ctl, qadr, dadr, n = task.controller, exp.robot.mj_qpos_adr, exp.robot.mj_dof_adr, exp.robot.n
    split = ctl.split
    measure = ctl.measure_site if split else ctl.measure
    n_sub = int(round(task.control_dt / twin.physics.model.opt.timestep))
    K = task.n_steps
    Q, Qd, P, V = np.empty((K, n)), np.empty((K, n)), np.empty((K, 3)), np.empty((K, exp.placement.dim))
    t_env, t_loop, out = np.empty(blocks), np.empty(blocks), np.empty(block)
    ts, f_env, k_env = env.reset(), field.single_point_evaluator(), 0
    k = K
    for b in range(blocks):
        if k_env + block >= K:   # a new episode (untimed)
            ts, f_env, k_env = env.reset(), field.single_point_evaluator(), 0
        for i in range(block):
            t0 = clock()
            ts = env.step(f_env(ts.observation["task_position"]))
            out[i] = clock() - t0
        k_env += block
        t_env[b] = np.median(out)
        if k + block >= K:
            twin.reset()
            f_loop, k = field.single_point_evaluator(), 0
            m, d = twin.physics.model.ptr, twin.physics.data.ptr
            ctl.bind(d)
            qpos, qvel, warn = d.qpos, d.qvel, d.warning.number
        for i in range(block):
            t0 = clock()
            if split:
                mujoco.mj_step1(m, d)
            q = qpos[qadr]
            p = measure(q)
            Q[k], Qd[k], P[k] = q, qvel[dadr], p
            v = V[k] = f_loop(ctl.to_task(p))
            task.apply(d, q, None, v, m)
            if split:
                mujoco.mj_step2(m, d)
                if n_sub > 1:
                    mujoco.mj_step(m, d, n_sub - 1)
            else:
                mujoco.mj_step(m, d, n_sub)
            if warn[0] or warn[1] or warn[2] or warn[3]:
                raise sim.SimError("the copy of the loop diverged")
            out[i] = clock() - t0
            k += 1
        t_loop[b] = np.median(out)
    return t_env, t_loop


def cost(exp: sim.Experiment, field: lfd.VelocityField, repeats: int) -> dict[str, float]:
    """Print the control step against a bare mj_step and the real-time factor; returns the ratios."""
    m = exp.physics.model.ptr
    exp.simulate(field)                          # warm-up: JIT kernels, caches
    env = environment(exp, field)
    env_steps(env, field, 200)                   # warm-up
    bare, loop, envs, rtf, cpu_ratio, cpu_rtf, env_cpu = [], [], [], [], [], [], []
    for _ in range(repeats):   # interleaved blocks: loop, environment, bare (machine load hits all alike)
        ro = exp.simulate(field)
        loop.append(ro.step_time_s)
        e, e_cpu = env_steps(env, field, len(ro.step_time_s))
        envs.append(e)
        env_cpu.append((e_cpu / len(e)) / (ro.cpu_s / len(ro.step_time_s)))
        rtf.append(ro.realtime_factor)
        d = holding_data(exp, ro.q[0])
        b, b_cpu = bare_steps(m, d, len(ro.step_time_s))
        bare.append(b)
        cpu_ratio.append(ro.cpu_s / b_cpu)
        cpu_rtf.append(float(ro.t[-1] - ro.t[0]) / ro.cpu_s)
    bare_t, loop_t = np.concatenate(bare), np.concatenate(loop)
    ratio = float(np.median(loop_t) / np.median(bare_t))
    c_ratio, c_rtf = float(np.median(cpu_ratio)), float(np.median(cpu_rtf))
    print(f"bare mj_step          : {stats(bare_t)}   ({len(bare_t)} steps)")
    print(f"closed-loop step      : {stats(loop_t)}   ({len(loop_t)} steps)")
    print(f"ratio, wall (median)  : {ratio:.2f}    ratio (p95) "
          f"{np.percentile(loop_t, 95) / np.percentile(bare_t, 95):.2f}")
    print(f"ratio, CPU time       : {c_ratio:.2f} (runs: {', '.join(f'{r:.2f}' for r in cpu_ratio)})    "
          f"target <= 3: {'MET' if c_ratio <= 3 else 'NOT MET'}")
    print(f"real-time factor      : wall {np.median(rtf):.0f} (runs: {', '.join(f'{r:.0f}' for r in rtf)}), "
          f"CPU time {c_rtf:.0f}    target >= 100: {'MET' if c_rtf >= 100 else 'NOT MET'} (CPU time; "
          f"wall under load {os.getloadavg()[0]:.1f})")
    parts = breakdown(exp, field, 2000)
    total = sum(np.median(v) for v in parts.values())
    print("breakdown (instrumented, medians):")
    for name, v in parts.items():
        print(f"  {name:18s} {np.median(v) * 1e6:7.1f} us  {np.median(v) / total:5.1%}")
    fc = field_cost(field, exp.demos.x[exp.demo_index])
    print(f"field alone           : {stats(fc)}   ({np.median(fc) / np.median(bare_t):.2f}x a bare mj_step)")
    envt = np.concatenate(envs)
    env_ratio = float(np.median(envt) / np.median(loop_t))
    pairs = ", ".join(f"{np.median(e) / np.median(lp):.2f}" for e, lp in zip(envs, loop))
    print(f"dm_env Environment.step with the same controller: {stats(envt)}   ({len(envt)} steps, "
          f"interleaved with the loop's)\n  Environment.step / lean loop step, wall medians: {env_ratio:.2f}    "
          f"target <= 1.3: {'MET' if env_ratio <= 1.3 else 'NOT MET'} (load average {os.getloadavg()[0]:.2f})\n"
          f"  per block pair, wall medians: {pairs}"
          f"\n  CPU time per step: {np.median(env_cpu):.2f} (runs: {', '.join(f'{r:.2f}' for r in env_cpu)})")
    t_env, t_loop = interleaved_steps(exp, field, 50 * repeats)
    print(f"  in blocks of 100 steps alternating with a copy of the loop's step: {np.median(t_env) * 1e6:.1f} us / "
          f"{np.median(t_loop) * 1e6:.1f} us, ratio per block pair: median {np.median(t_env / t_loop):.2f}, "
          f"quartiles {np.percentile(t_env / t_loop, 25):.2f} .. {np.percentile(t_env / t_loop, 75):.2f} "
          f"({len(t_env)} pairs)")
    return {"ratio": ratio, "cpu_ratio": c_ratio, "rtf": float(np.median(rtf)), "cpu_rtf": c_rtf,
            "field_ratio": float(np.median(fc) / np.median(bare_t)), "env_ratio": env_ratio}


def actuation(robot_name: str, demos: lfd.DemoSet, field: lfd.VelocityField, ik: str, plane: str) -> None:
    print("\nactuation    variant                  tracking_rmse  final_goal  push max_dev  recovery  step")
    for act, ff, label in (("position", False, "servo u = q + qdot dt"),
                           ("position", True, "servo + velocity ff"),
                           ("torque", True, "computed torque")):
        robot = load_robot(robot_name, actuation=act)
        a, b, rec = none_and_push(sim.Experiment(robot, demos, plane=plane, ik=ik, feedforward=ff), field)
        print(f"{act:12s} {label:24s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['final_goal_error_m'] * 1e3:7.2f} mm"
              f"  {b['max_deviation_m'] * 1e3:8.2f} mm  {rec:>8s}  {a['control_step_us']:5.0f} us")


def planes(robot_name: str, demos: lfd.DemoSet, field: lfd.VelocityField, ik: str, act: str) -> None:
    robot = load_robot(robot_name, actuation=act)
    if robot.planar or demos.dim != 2:
        return
    print(f"\ntask plane ({act})   tracking_rmse  imitation_rmse  final_goal  push max_dev  recovery")
    for plane in ("horizontal", "vertical"):
        a, b, rec = none_and_push(sim.Experiment(robot, demos, plane=plane, ik=ik), field)
        print(f"{plane:18s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['imitation_rmse_m'] * 1e3:9.2f} mm"
              f"  {a['final_goal_error_m'] * 1e3:7.2f} mm  {b['max_deviation_m'] * 1e3:8.2f} mm  {rec:>8s}")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message: str) -> Any:
        self.exit(2, f"speed_loop: error: {message} (see --help)\n")


def main() -> int:
    ap = _Parser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--learner", default="node,contraction",
                    help="learner(s) of the field, comma-separated (trained and cached if needed)")
    ap.add_argument("--model", help="a model file instead of training")
    ap.add_argument("--demos", default="spiral")
    ap.add_argument("--ik", default="dls")
    ap.add_argument("--actuation", default="torque", choices=ACTUATIONS)
    ap.add_argument("--plane", default="auto")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rollout / bare blocks")
    ap.add_argument("--skip-actuation", action="store_true", help="only the cost part (no parts 2, 3)")
    args = ap.parse_args()
    if not 1 <= args.repeats <= 1000:
        print("speed_loop: error: --repeats must be in 1..1000", file=sys.stderr)
        return 2
    learners = [s.strip() for s in args.learner.split(",") if s.strip()]
    try:
        demos = lfd.load_demos(args.demos)
        fields = [lfd.load(args.model)] if args.model else [cached_field(name, demos)[0] for name in learners]
        robot = load_robot(args.robot, actuation=args.actuation)
        exp = sim.Experiment(robot, demos, plane=args.plane, ik=args.ik)
    except (lfd.LfdError, sim.SimError, RobotError) as e:
        print(f"speed_loop: error: {e}", file=sys.stderr)
        return 2
    summary = []
    for field in fields:
        print(f"\nrobot {robot.name}, field {field.learner} ({args.demos}), ik {args.ik}, actuation {args.actuation}, "
              f"control {exp.options['control_hz']:g} Hz, load average {os.getloadavg()[0]:.2f} "
              f"on {os.cpu_count()} CPUs")
        summary.append((field.learner, cost(exp, field, args.repeats)))
    print("\nsummary (targets: step / bare mj_step <= 3, real-time factor >= 100; CPU time, "
          "wall-clock median in brackets)")
    for name, r in summary:
        print(f"  {name:12s} step ratio {r['cpu_ratio']:5.2f} [{r['ratio']:5.2f}] "
              f"({'met' if r['cpu_ratio'] <= 3 else 'not met'})   real-time factor {r['cpu_rtf']:5.0f} "
              f"[{r['rtf']:4.0f}] ({'met' if r['cpu_rtf'] >= 100 else 'not met'})   "
              f"field alone {r['field_ratio']:.2f}x mj_step   env step {r['env_ratio']:.2f}x loop step")
    if not args.skip_actuation:
        for field in fields:
            actuation(args.robot, demos, field, args.ik, args.plane)
            planes(args.robot, demos, field, args.ik, args.actuation)
    return 0


if __name__ == "__main__":
    run_main(main, "speed_loop")
