"""What the objects of a task cost the control loop: the control step in the scene with objects against
the same step in the empty scene, each net of its own scene's physics.

For the RoboTasks9 demos of each task (pour, place, lid) and the tracking learner's field (cached), two
scenes: the arm on its table (``empty``), and the task's scene with its objects (the pour's cup and
12 balls, the placement's bottle and shelf, the lid's box). Each runs the job's closed loop ``--repeats`` times
(``sim.control.step.ControlStep``), every step timed, and inside it its own physics calls
(``mj_step1``, ``mj_step2``: the step's module attributes, wrapped by a timer while this runs). The
control step's own cost is each step's time less its physics', medians; the target is that the objects
do not raise it (a ratio to the empty scene's at most 1). Real-time factor: simulated s per wall s.
Last, how far the objects move the tool from its path in the empty scene (RMSE, position and angle;
the placement's also without its load fed forward, Eq. (H1)).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

import sim
from sim.control import step as control_step
from sim.run.plan import plan_job
from sim.run.tasks import TASK_DEMOS, TASK_SHIFTS
from sim.speed.timing import load

__all__ = ["add_arguments", "run", "scene_cost"]

def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--repeats", type=int, default=3, help="runs per scene (default 3)")


def scene_cost(plan: Any, repeats: int, steps: int | None = None, feed_load: bool = True) -> dict[str, Any]:
    """Run ``plan``'s tracking field ``repeats`` times in its experiment's scene; returns the medians
    (s) of the control step (``step``), of its own physics calls (``physics``: ``mj_step1``, ``mj_step2``,
    timed inside it) and of the step less its physics (``own``), the real-time factor (``rtf``), and the
    first run's tool positions ``p`` (K, 3) and rotations ``rot`` (K, 3, 3). ``steps`` cuts each run
    short (None: the whole run); ``feed_load`` False runs without the held load's feed-forward
    (``ControlStep.feed_load``)."""
    exp = plan.exp
    field = plan.fields["tracking"]
    env = exp.environment()
    task = env.task
    task.step.feed_load = feed_load
    clock = time.perf_counter
    spent = [0.0]
    calls = (control_step.physics_step1, control_step.physics_step2, control_step.physics_step)

    def timed(call: Any) -> Any:
        def run(*args: Any) -> None:
            t0 = clock()
            call(*args)
            spent[0] += clock() - t0
        return run

    path: list[np.ndarray] = []
    turn: list[np.ndarray] = []
    ctl: list[float] = []
    own: list[float] = []
    sim_s = wall_s = 0.0
    control_step.physics_step1, control_step.physics_step2, control_step.physics_step = map(timed, calls)
    try:
        for _ in range(repeats):
            env.reset()
            step, data = task.step, env.physics.data.ptr
            runner = field.runner(task.start_task - task.schedule.goal_offset_task, task.control_dt)
            n = task.n_steps if steps is None else min(steps, task.n_steps)
            t_run = clock()
            for _k in range(n):
                spent[0] = 0.0
                t0 = clock()
                x = step.begin_at_point()
                step.command(runner(x, data.time))
                step.end()
                dt = clock() - t0
                ctl.append(dt)
                own.append(dt - spent[0])
                if len(ctl) <= n:   # the first run's tool poses (outside the timed step)
                    path.append(step.p.copy())
                    turn.append(step.measured_rotation().copy())
            wall_s += clock() - t_run
            sim_s += n * task.control_dt
    finally:
        control_step.physics_step1, control_step.physics_step2, control_step.physics_step = calls
    return {"step": float(np.median(ctl)), "own": float(np.median(own)),
            "physics": float(np.median(np.array(ctl) - np.array(own))), "rtf": sim_s / max(wall_s, 1e-9),
            "p": np.array(path), "rot": np.array(turn)}


def path_gap(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, float]:
    """RMSE between two runs' tool paths (``scene_cost``'s ``p``, ``rot``): m and deg, over their common steps."""
    n = min(len(a["p"]), len(b["p"]))
    pos = float(np.sqrt(np.mean(np.sum((a["p"][:n] - b["p"][:n]) ** 2, axis=1))))
    rel = np.einsum("kji,kjl->kil", a["rot"][:n], b["rot"][:n])
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
    return pos, float(np.degrees(np.sqrt(np.mean(ang ** 2))))


def run(args: argparse.Namespace) -> int:
    """Print, per task, the scenes' control step, bare physics, own cost and real-time factor, then how far
    the objects move the tool from its path in the empty scene."""
    repeats = 1 if args.quick else max(1, int(args.repeats))
    steps = 500 if args.quick else None
    print(f"tracking learner, {repeats} run(s) per scene, load average {load():.2f}")
    print(f"{'task':6s} {'scene':8s} {'physics':>10s} {'control step':>13s} {'own cost':>9s} "
          f"{'own / empty':>11s} {'RTF':>6s}")
    gaps = []
    for name, demos in TASK_DEMOS.items():
        base = dict(demos=demos, learners=("tracking",), scenarios=("none",), videos=False, plots=False, quiet=True,
                    overwrite=True, out=f"/tmp/speed_tasks_{name}")
        empty = scene_cost(plan_job(sim.ArmJob(table=True, shift=TASK_SHIFTS.get(name), **base)),  # type: ignore[arg-type]
                           repeats, steps)
        objects = plan_job(sim.ArmJob(task=name, **base))                            # type: ignore[arg-type]
        full = scene_cost(objects, repeats, steps)
        for label, c in (("empty", empty), ("objects", full)):
            print(f"{name:6s} {label:8s} {c['physics'] * 1e6:7.1f} us {c['step'] * 1e6:10.1f} us "
                  f"{c['own'] * 1e6:6.1f} us {c['own'] / empty['own']:11.2f} {c['rtf']:6.1f}")
        gaps.append((name, "held, fed forward" if name == "place" else "held", path_gap(full, empty)))
        if name == "place":
            unfed = scene_cost(objects, 1, steps, feed_load=False)
            gaps.append((name, "held, not fed forward", path_gap(unfed, empty)))
    print("\nthe tool's path with the objects against the empty scene's (RMSE)")
    for name, how, (pos, ang) in gaps:
        print(f"{name:6s} {how:22s} {pos * 1e3:8.3f} mm {ang:8.3f} deg")
    return 0
