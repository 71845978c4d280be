"""Cost of one closed-loop control step against a bare ``mj_step`` of the same model, and the
choice of actuation by measurement.

Part 1 (cost), for each field of ``--learner`` (default: node and contraction): the control
step of ``sim.control.loop.execute`` (``sim.control.step.ControlStep``: ``mj_step1``, state, tool pose, the field's
runner at the measured point, twist + IK + actuator command, perturbations, ``mj_step2``) timed step by step,
and a bare ``mujoco.mj_step`` of the same model at the run's start, at rest, measured in the
same run in interleaved blocks (so machine load hits both alike). Prints median and p95 of each
and their ratio; the same ratio in CPU time (``time.thread_time`` over the whole loop and over
as many bare steps: preemption by other processes does not count), and the real-time factor
(simulated s per wall s, and per CPU s); the targets (ratio <= 3, real-time factor >= 100) are
marked MET / NOT MET. Then where the time goes (``sim.speed.instrumented.breakdown``), the
field alone, and what the dm_env ``Environment.step`` of ``sim.make_environment`` costs for the
same step (same controller, same field, timed step by step in blocks interleaved with the loop's;
target: its median <= 1.3x the loop's), and the same ratio against the loop's step in short
alternating blocks on two copies of the model (load hits both alike). A summary closes the run.

Part 2 (actuation): tracking and push metrics of the same field with position servos (velocity
feed-forward, and the plain u = q + qdot dt) and with computed torque (``sim.control.controller``).
Part 3 (plane): the same for a 2-D field on a horizontal and on a vertical task plane.

Timings are wall clock: note the machine load (printed) when you quote them.
"""

from __future__ import annotations

import argparse
import math
import os
from typing import Any

import numpy as np

import lfd
import sim
from lfd.errors import ConfigError
from lfd.field import Field
from robots import load_robot
from sim.speed.instrumented import breakdown, env_steps, interleaved_steps
from sim.speed.timing import each_call_s, load, median_ratio, none_and_push, stats
from sim.speed.trained import add_field_arguments, field_of
from sim.studies.scaling_control import bare_steps, holding_data

__all__ = ["actuation", "add_arguments", "cost", "planes", "run"]


def cost(exp: sim.Experiment, field: Field, repeats: int, quick: bool = False) -> dict[str, float]:
    """Print the control step against a bare mj_step and the real-time factor (part 1); returns the ratios."""
    m = exp.physics.model.ptr
    exp.simulate(field)                          # warm-up: JIT kernels, caches
    env = exp.environment()
    env_steps(env, field, 200)                   # warm-up
    bare, loop, envs, rtf, cpu_ratio, cpu_rtf, env_cpu = [], [], [], [], [], [], []
    for _ in range(repeats):   # interleaved blocks: loop, environment, bare (machine load hits all alike)
        ro = exp.simulate(field)
        run_cpu = math.nan if ro.cpu_s is None else float(ro.cpu_s)
        loop.append(ro.step_time_s)
        e, e_cpu = env_steps(env, field, len(ro.step_time_s))
        envs.append(e)
        env_cpu.append((e_cpu / len(e)) / (run_cpu / len(ro.step_time_s)))
        rtf.append(ro.realtime_factor)
        d = holding_data(exp, ro.q[0])
        b, b_cpu = bare_steps(m, d, len(ro.step_time_s))
        bare.append(b)
        cpu_ratio.append(run_cpu / b_cpu)
        cpu_rtf.append(float(ro.t[-1] - ro.t[0]) / run_cpu)
    bare_t, loop_t = np.concatenate(bare), np.concatenate(loop)
    ratio = median_ratio(loop_t, bare_t)
    c_ratio, c_rtf = float(np.median(cpu_ratio)), float(np.median(cpu_rtf))
    print(f"bare mj_step          : {stats(bare_t)}   ({len(bare_t)} steps)")
    print(f"closed-loop step      : {stats(loop_t)}   ({len(loop_t)} steps)")
    print(f"ratio, wall (median)  : {ratio:.2f}    ratio (p95) "
          f"{np.percentile(loop_t, 95) / np.percentile(bare_t, 95):.2f}")
    print(f"ratio, CPU time       : {c_ratio:.2f} (runs: {', '.join(f'{r:.2f}' for r in cpu_ratio)})    "
          f"target <= 3: {'MET' if c_ratio <= 3 else 'NOT MET'}")
    print(f"real-time factor      : wall {np.median(rtf):.0f} (runs: {', '.join(f'{r:.0f}' for r in rtf)}), "
          f"CPU time {c_rtf:.0f}    target >= 100: {'MET' if c_rtf >= 100 else 'NOT MET'} (CPU time; "
          f"wall under load {load():.1f})")
    parts = breakdown(exp, field, 200 if quick else 2000)
    total = sum(np.median(v) for v in parts.values())
    print("breakdown (instrumented, medians):")
    for name, v in parts.items():
        print(f"  {name:30s} {np.median(v) * 1e6:7.1f} us  {np.median(v) / total:5.1%}")
    fc = each_call_s(field.single_point_evaluator(), exp.task_demos.x[exp.setup.demo_index], 2000 if quick else 20000)
    print(f"field alone           : {stats(fc)}   ({median_ratio(fc, bare_t):.2f}x a bare mj_step)")
    envt = np.concatenate(envs)
    env_ratio = median_ratio(envt, loop_t)
    pairs = ", ".join(f"{median_ratio(e, lp):.2f}" for e, lp in zip(envs, loop))
    print(f"dm_env Environment.step with the same controller: {stats(envt)}   ({len(envt)} steps, "
          f"interleaved with the loop's)\n  Environment.step / lean loop step, wall medians: {env_ratio:.2f}    "
          f"target <= 1.3: {'MET' if env_ratio <= 1.3 else 'NOT MET'} (load average {load():.2f})\n"
          f"  per block pair, wall medians: {pairs}"
          f"\n  CPU time per step: {np.median(env_cpu):.2f} (runs: {', '.join(f'{r:.2f}' for r in env_cpu)})")
    t_env, t_loop = interleaved_steps(exp, field, 2 if quick else 50 * repeats)
    print(f"  in blocks of 100 steps alternating with the loop's step: {np.median(t_env) * 1e6:.1f} us / "
          f"{np.median(t_loop) * 1e6:.1f} us, ratio per block pair: median {np.median(t_env / t_loop):.2f}, "
          f"quartiles {np.percentile(t_env / t_loop, 25):.2f} .. {np.percentile(t_env / t_loop, 75):.2f} "
          f"({len(t_env)} pairs)")
    return {"ratio": ratio, "cpu_ratio": c_ratio, "rtf": float(np.median(rtf)), "cpu_rtf": c_rtf,
            "field_ratio": median_ratio(fc, bare_t), "env_ratio": env_ratio}


def actuation(robot_name: str, demos: lfd.DemoSet, field: Field, ik: str, plane: str) -> None:
    """Print tracking and push metrics with each actuation (part 2)."""
    print("\nactuation    variant                  tracking_rmse  final_goal  push max_dev  recovery  step")
    for act, ff, label in (("position", False, "servo u = q + qdot dt"),
                           ("position", True, "servo + velocity ff"),
                           ("torque", True, "computed torque")):
        robot = load_robot(robot_name, actuation=act)
        a, b, rec = none_and_push(sim.Experiment(robot, demos, plane=plane, ik=ik, feedforward=ff), field)
        print(f"{act:12s} {label:24s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['final_goal_error_m'] * 1e3:7.2f} mm"
              f"  {b['max_deviation_m'] * 1e3:8.2f} mm  {rec:>8s}  {a['control_step_us']:5.0f} us")


def planes(robot_name: str, demos: lfd.DemoSet, field: Field, ik: str, act: str) -> None:
    """Print the same metrics on a horizontal and on a vertical task plane (part 3; 2-D demos on an arm
    that is not planar)."""
    robot = load_robot(robot_name, actuation=act)
    if robot.planar or demos.dim != 2:
        return
    print(f"\ntask plane ({act})   tracking_rmse  imitation_rmse  final_goal  push max_dev  recovery")
    for plane in ("horizontal", "vertical"):
        a, b, rec = none_and_push(sim.Experiment(robot, demos, plane=plane, ik=ik), field)
        print(f"{plane:18s} {a['tracking_rmse_m'] * 1e3:8.2f} mm  {a['imitation_rmse_m'] * 1e3:9.2f} mm"
              f"  {a['final_goal_error_m'] * 1e3:7.2f} mm  {b['max_deviation_m'] * 1e3:8.2f} mm  {rec:>8s}")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The robot, the fields, the IK, the actuation, the task plane, the repeats."""
    ap.add_argument("--robot", default="panda")
    add_field_arguments(ap, "node,contraction")
    ap.add_argument("--ik", default="dls")
    ap.add_argument("--plane", default="auto")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rollout / bare blocks")
    ap.add_argument("--skip-actuation", action="store_true", help="only the cost part (no parts 2, 3)")


def run(args: argparse.Namespace) -> int:
    """Parts 1-3 (module docstring) for each field, and the summary of part 1 (``--quick``: a short
    spiral, fields trained for 2 iterations, one repeat, short breakdown and field timings)."""
    if not 1 <= args.repeats <= 1000:
        raise ConfigError("--repeats must be in 1..1000")
    robot = load_robot(args.robot, actuation=args.actuation)   # a bad name fails before any training
    demos, fields = field_of(args)
    exp = sim.Experiment(robot, demos, plane=args.plane, ik=args.ik)
    summary: list[tuple[str, dict[str, Any]]] = []
    for field in fields:
        print(f"\nrobot {robot.name}, field {field.learner} ({args.demos}), ik {args.ik}, actuation {args.actuation}, "
              f"control {exp.options['control_hz']:g} Hz, load average {load():.2f} on {os.cpu_count()} CPUs")
        summary.append((field.learner, cost(exp, field, 1 if args.quick else args.repeats, args.quick)))
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
