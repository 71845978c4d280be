"""Cost of the closed-loop control step against the number of obstacles and the robot
(``sim.studies.scaling``, run by ``scripts/scaling.py``, writes it into reports/scaling.md).

A measurement (``measure_control``) runs a field on a robot with K spheres in the scene, placed
off the demonstrated path (``off_path_spheres``: on a grid on the far side of the demos from the
robot's base, so the tool never comes near them and the runs stay comparable), with the arm job's
settings among obstacles (``sim.run.obstacle_runs.ObstacleRuns``, runs as long as the bare ones): the
field avoids them (``lfd.avoid``, each grown by the hand's margin, ``sim.scene.collision.hand_margin_m``),
the IK carries the whole-arm collision dampers (``sim.scene.collision.Clearance``; given for K = 0 too,
so every point of a curve has them) and the servo leads by ``OBSTACLE_LEAD_S``. ``Experiment.simulate``
is run ``repeats`` times per point after one warm-up; each run's step times (``RunTrace.step_time_s``,
the loop's own timer) and CPU time (``RunTrace.cpu_s``) are kept, and after each run as many bare
``mujoco.mj_step`` calls of the same compiled model (obstacles included), at rest at the run's start
with controls that hold it there, are timed one by one (interleaved blocks: machine load hits both alike, as in
``scripts/speed.py loop``); the field the loop calls (the avoiding field) is also timed alone. All
points of a robot are measured round-robin (``measure_control``).
"""

from __future__ import annotations

import importlib.metadata
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin

from lfd import DemoSet, VelocityField
from lfd.bench.scaling import single_point_us
from lfd.obstacles import Obstacle, Sphere
from robots import RobotModel, load_robot
from sim.run.experiment import Experiment
from sim.run.obstacle_runs import ObstacleRuns
from sim.scene.placement import base_position

__all__ = ["OBSTACLE_COUNTS", "ROBOTS", "RobotSpec", "load_scaling_robot", "off_path_spheres", "bare_steps",
           "holding_data", "measure_control"]

#: the obstacle counts of the curve
OBSTACLE_COUNTS: tuple[int, ...] = (0, 1, 2, 4, 8, 16)
#: a sphere's radius, as a fraction of the demos' extent
SPHERE_FRACTION = 0.05
#: spheres per row of the grid (rows run across the direction from the base to the demos)
GRID_ROWS = 4


@dataclass(frozen=True)
class RobotSpec:
    """A robot of the curve: ``name`` in the report, ``spec`` and ``ee_frame`` for ``robots.load_robot``
    (a spec starting with ``example-robot-data:`` names a file under that package's ``robots`` folder)."""

    name: str
    spec: str
    ee_frame: str | None = None


#: the robots of the curve: the two built-in arms and a URDF arm from example-robot-data (the UR5, loaded
#: from its file like any user URDF, as tests/test_env.py does)
ROBOTS: tuple[RobotSpec, ...] = (
    RobotSpec("planar", "planar"),
    RobotSpec("panda", "panda"),
    RobotSpec("ur5 (URDF)", "example-robot-data:ur_description/urdf/ur5_joint_limited_robot.urdf", "tool0"),
)


def load_scaling_robot(spec: RobotSpec, actuation: str = "torque") -> RobotModel:
    """``robots.load_robot`` of ``spec`` (its ``example-robot-data:`` prefix resolved)."""
    path = spec.spec
    prefix = "example-robot-data:"
    if path.startswith(prefix):
        root = Path(str(importlib.metadata.distribution("example-robot-data").locate_file(
            "cmeel.prefix/share/example-robot-data/robots")))
        path = str(root / path[len(prefix):])
    return load_robot(path, spec.ee_frame, actuation=actuation)


def off_path_spheres(demos: DemoSet, count: int, base_task: np.ndarray,
                     radius_fraction: float = SPHERE_FRACTION, margin: float = 0.0) -> list[Sphere]:
    """``count`` spheres off the demonstrated path, on a grid on the far side of the demos from the base.

    The grid's columns run away from the base along u = (c - base) / |c - base|, c the centre of the
    demos' bounding box; column j lies (h + (j + 1) s) beyond c, h the box's half diagonal; its
    ``GRID_ROWS`` rows lie (i - (GRID_ROWS - 1) / 2) s across u. The spacing s = 2.5 (r + margin),
    r = ``radius_fraction`` times the demos' extent, keeps the grown spheres apart (they are never
    merged into one unit). Sphere k sits in column k // GRID_ROWS, row k % GRID_ROWS.

    Parameters
    ----------
    demos : DemoSet
        2-D or 3-D demos, task units.
    count : int
        Number of spheres, >= 0.
    base_task : array, shape (d,)
        The robot's base in task coordinates.
    radius_fraction : float
        r over the demos' extent.
    margin : float
        The margin each sphere will be grown by, task units (it widens the spacing; the spheres carry none).

    Returns
    -------
    list of Sphere
    """
    lo, hi = demos.bounds()
    centre = (lo + hi) / 2
    half = float(np.linalg.norm(hi - lo)) / 2
    u = centre - np.asarray(base_task, dtype=np.float64)
    u = u / max(float(np.linalg.norm(u)), 1e-12)
    # an orthonormal direction across u (in the task plane for 2-D, any for 3-D)
    helper = np.zeros_like(u)
    helper[int(np.argmin(np.abs(u)))] = 1.0
    w = helper - (helper @ u) * u
    w = w / np.linalg.norm(w)
    r = radius_fraction * demos.extent
    s = 2.5 * (r + margin)
    out = []
    for k in range(count):
        col, row = divmod(k, GRID_ROWS)
        c = centre + u * (half + (col + 1) * s) + w * (row - (GRID_ROWS - 1) / 2) * s
        out.append(Sphere(c, r))
    return out


def bare_steps(model: mujoco.MjModel, data: mujoco.MjData, n: int) -> tuple[np.ndarray, float]:
    """Wall time of ``n`` bare ``mj_step`` calls, each timed, shape (n,), and the thread CPU time of
    ``n`` more, untimed (``time.thread_time``)."""
    out = np.empty(n)
    clock = time.perf_counter
    for k in range(n):
        t0 = clock()
        mujoco.mj_step(model, data)
        out[k] = clock() - t0
    cpu0 = time.thread_time()
    for _ in range(n):
        mujoco.mj_step(model, data)
    return out, time.thread_time() - cpu0


def holding_data(exp: Experiment, q: np.ndarray) -> mujoco.MjData:
    """Fresh MjData of the experiment's model at rest at q, shape (n,), with controls that hold it there
    (the servo target q, or the gravity torque g(q)), so the bare steps neither fall nor hit limits."""
    m, robot = exp.physics.model.ptr, exp.robot
    d = mujoco.MjData(m)
    d.qpos[robot.mj_qpos_adr] = q
    if robot.actuation == "position":
        d.ctrl[robot.mj_actuator_ids] = q
    else:
        d.ctrl[robot.mj_actuator_ids] = pin.computeGeneralizedGravity(robot.pin_model, robot.pin_model.createData(), q)
    mujoco.mj_forward(m, d)
    return d


@dataclass
class _Setup:
    """One point of a robot's curve: its experiment, the field it runs and what its runs gave."""

    count: int
    dampers: bool
    exp: Experiment
    fn: Any
    steps: list[np.ndarray] = field(default_factory=list)
    bare: list[np.ndarray] = field(default_factory=list)
    step_cpu: list[float] = field(default_factory=list)
    bare_cpu: list[float] = field(default_factory=list)
    field_us: list[float] = field(default_factory=list)
    ee: np.ndarray | None = None
    goal: np.ndarray | None = None


def measure_control(robot: RobotModel, demos: DemoSet, learned: VelocityField,
                    counts: Sequence[int] = OBSTACLE_COUNTS, repeats: int = 5) -> list[dict[str, Any]]:
    """Time the control step of ``learned`` on ``robot`` with each number of off-path spheres in ``counts``,
    and the plain loop (module docstring).

    Every point is built and warmed up first (one run each); then ``repeats`` rounds run every point once
    in turn (its run, as many bare ``mj_step`` calls, and the field alone), so that a change of the
    machine's load hits all points alike.

    Parameters
    ----------
    robot : RobotModel
    demos : DemoSet
        2-D or 3-D demos, task units.
    learned : VelocityField
        The learned field (wrapped by ``lfd.avoid`` for the points with obstacles).
    counts : sequence of int
        Obstacle counts, >= 0.
    repeats : int
        Timed rounds.

    Returns
    -------
    list of dict
        The plain loop first (``dampers`` False, ``count`` 0: no obstacles, no dampers, the field not
        wrapped), then one per count, each with ``step_us`` (median of every timed step, µs),
        ``step_p95_us``, ``step_cpu_us`` (a run's CPU time per step, median over runs), ``bare_us``
        (median bare ``mj_step``), ``bare_cpu_us``, ``ratio`` (step_us / bare_us), ``cpu_ratio``
        (step_cpu_us / bare_cpu_us), ``field_us`` (the field the loop calls, alone:
        ``lfd.bench.scaling.single_point_us`` on the demo's points, median over rounds), ``steps`` (per
        run), ``repeats``, ``obstacles`` (their descriptions), ``final_goal_error_m`` and
        ``max_deviation_m`` (the largest distance of the last run's tool path from that of the count-0
        point with dampers; None where there is none).
    """
    bare_exp = Experiment(robot, demos, clearance=None)
    placement = bare_exp.placement
    base_task = placement.to_task(base_position(robot)[None])[0]
    among = ObstacleRuns(time_factor=1.0)      # a job's settings among obstacles, runs as long as the bare ones
    margin = among.hand_margin_m(robot) / placement.scale
    setups = [_Setup(0, False, bare_exp, learned)]
    for count in counts:
        spheres: list[Obstacle] = list(off_path_spheres(demos, count, base_task, margin=margin))
        exp = among.experiment(robot, demos, spheres, placement=placement)
        setups.append(_Setup(count, True, exp, among.avoiding(learned, spheres, robot, placement.scale)))
    points = demos.x[bare_exp.setup.demo_index]
    for s in setups:
        s.exp.simulate(s.fn)   # warm-up: compiled kernels, caches
    for _ in range(repeats):
        for s in setups:
            ro = s.exp.simulate(s.fn)
            n = len(ro.step_time_s)
            b, b_cpu = bare_steps(s.exp.physics.model.ptr, holding_data(s.exp, ro.q[0]), n)
            s.steps.append(ro.step_time_s)
            s.bare.append(b)
            s.step_cpu.append((float(ro.cpu_s) if ro.cpu_s is not None else math.nan) / n)
            s.bare_cpu.append(b_cpu / n)
            s.field_us.append(single_point_us(s.fn.single_point_evaluator(), points, blocks=50))
            s.ee, s.goal = ro.ee, ro.goal_world
    reference = next((s.ee for s in setups if s.dampers and s.count == 0), None)
    out = []
    for s in setups:
        assert s.ee is not None and s.goal is not None
        st, bt = np.concatenate(s.steps), np.concatenate(s.bare)
        dev = None
        if reference is not None and s.dampers and s.count > 0 and len(reference) == len(s.ee):
            dev = float(np.max(np.linalg.norm(s.ee - reference, axis=1)))
        step_cpu, bare_cpu = float(np.median(s.step_cpu)), float(np.median(s.bare_cpu))
        out.append({"obstacles": [o.describe() for o in s.exp.obstacles], "count": s.count, "dampers": s.dampers,
                    "step_us": float(np.median(st) * 1e6), "step_p95_us": float(np.percentile(st, 95) * 1e6),
                    "step_cpu_us": step_cpu * 1e6, "bare_us": float(np.median(bt) * 1e6),
                    "bare_cpu_us": bare_cpu * 1e6, "ratio": float(np.median(st) / np.median(bt)),
                    "cpu_ratio": step_cpu / bare_cpu, "field_us": float(np.median(s.field_us)),
                    "steps": len(s.steps[0]), "repeats": repeats,
                    "final_goal_error_m": float(np.linalg.norm(s.ee[-1] - s.goal)), "max_deviation_m": dev})
    return out
