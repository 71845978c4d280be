"""What whole-arm clearance costs per control step on the Panda. Prints, asserts nothing.

The user's 3-demo spiral with 3 obstacles on and beside its path (the user's sphere, a box and a
sphere), the contraction field avoiding them (``lfd.avoid``, with the hand margin). Three
variants of the same run, interleaved ``--repeats`` times: ``bare``, no obstacles, the plain field;
``tool point``, the obstacles in the scene and the field, no dampers (``clearance=None``);
``whole arm``, the default, the dampers of ``sim.scene.collision`` and the QP of ``robots.ik.constrained``
(split ``mj_step1``/``mj_step2``; each step checks the dampers against the DLS step with
``ArmClearance.check`` and solves the QP only where one binds).

Per variant: the median control step (wall, the loop's own timer), its 95th percentile, the share
of steps with a pair within the dampers' reach and with a damper at its bound, and the real-time
factor. The extra cost of whole-arm clearance is ``whole arm`` - ``tool point``, median and over
the steps with a pair within reach. Wall clock: note the load average printed with it.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import numpy as np

import lfd
import sim
from lfd.cache import cached_field
from lfd.obstacles import Box, Obstacle, Sphere
from robots import load_robot
from sim.run.obstacle_runs import ObstacleRuns
from sim.speed.timing import load
from sim.speed.trained import QUICK_DURATION_S
from sim.studies.obstacles import arc_point, spiral3, user_case

__all__ = ["add_arguments", "run", "scene"]


def scene(demos: lfd.DemoSet) -> list[Obstacle]:
    """The user's sphere (``sim.studies.obstacles.user_case``), a box beside demo 0 at 70 % of its arc
    length and a smaller sphere beside it at 20 %."""
    ext = demos.extent
    return [*user_case(demos), Box(arc_point(demos, 0.7) + [0.0, 0.05 * ext], [0.04 * ext, 0.03 * ext]),
            Sphere(arc_point(demos, 0.2) - [0.06 * ext, 0.0], 0.04 * ext)]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--repeats``."""
    ap.add_argument("--repeats", type=int, default=5)


def run(args: argparse.Namespace) -> int:
    """Time the three variants (module docstring) and print their table and the extra cost (``--quick``:
    a short spiral, a field trained for 2 iterations, one repeat)."""
    repeats = 1 if args.quick else args.repeats
    demos = lfd.spiral(n_demos=3, radius=0.13, duration=QUICK_DURATION_S) if args.quick else spiral3()
    obstacles = scene(demos)
    robot = load_robot("panda")
    if args.quick:
        field = lfd.train("contraction", demos, seed=0, progress=False, iterations=2)
    else:
        field, _, _ = cached_field("contraction", demos, 0, {}, verbose=False)
    bare = sim.Experiment(robot, demos, clearance=None)
    scale = bare.placement.scale
    among = ObstacleRuns(time_factor=1.0)      # a job's settings among obstacles, runs as long as the bare one
    avoiding = among.avoiding(field, obstacles, robot, scale)
    tool = dataclasses.replace(among, arm_clearance=False).experiment(robot, demos, obstacles)
    arm = among.experiment(robot, demos, obstacles)
    variants: dict[str, tuple[sim.Experiment, Any]] = {"bare": (bare, field), "tool point": (tool, avoiding),
                                                        "whole arm": (arm, avoiding)}
    steps: dict[str, list[np.ndarray]] = {k: [] for k in variants}
    rtf: dict[str, list[float]] = {k: [] for k in variants}
    near: list[np.ndarray] = []
    active: list[np.ndarray] = []
    for exp, f in variants.values():
        exp.simulate(f)   # warm up: compile, caches
    for _ in range(repeats):
        for name, (exp, f) in variants.items():
            ro = exp.simulate(f)
            steps[name].append(ro.step_time_s)
            rtf[name].append(ro.realtime_factor)
            if name == "whole arm":   # the dampers' records: this variant has them
                clear, guard = ro.arm_clearance_m, ro.guard_active
                assert clear is not None and guard is not None
                near.append(np.isfinite(clear[:-1]))
                active.append(guard[:-1])
    print(f"load average {load():.2f}; {repeats} repeats of {len(steps['bare'][0])} steps")
    print(f"{'variant':12s} {'median us':>10s} {'p95 us':>8s} {'RTF':>6s}")
    for name in variants:
        st = np.concatenate(steps[name]) * 1e6
        print(f"{name:12s} {np.median(st):10.1f} {np.percentile(st, 95):8.1f} {np.median(rtf[name]):6.0f}")
    st_tool, st_arm = np.concatenate(steps["tool point"]) * 1e6, np.concatenate(steps["whole arm"]) * 1e6
    nr, ac = np.concatenate(near), np.concatenate(active)
    print(f"steps with a pair within reach: {100 * nr.mean():.1f} %; "
          f"with a damper at its bound: {100 * ac.mean():.1f} %")
    print(f"extra per step (whole arm - tool point): median {np.median(st_arm) - np.median(st_tool):.1f} us, "
          f"mean {st_arm.mean() - st_tool.mean():.1f} us; on steps within reach: "
          f"{np.median(st_arm[nr]) - np.median(st_tool):.1f} us (median), on steps with a bound damper: "
          f"{np.median(st_arm[ac]) - np.median(st_tool) if ac.any() else float('nan'):.1f} us")
    return 0
