"""The arm job as one library call: demos -> model -> placement -> experiment -> metrics -> files.

::

    import sim
    job = sim.ArmJob(robot="planar", learners=("contraction",), scenarios=("none", "push"),
                     videos=False, out="out/quick")
    report = sim.run_job(job)          # trains or takes cached models, runs, writes, returns
    report.results[0].metrics          # sim.metrics' scores of the first run

``run_job`` checks everything it can before any training or simulation (the options, every output
path, the demos, obstacles and moving goal, the placement's reach, the push window), so a bad job
fails at once with an ``lfd.LfdError``, ``robots.RobotError`` or ``sim.SimError``. Models come from
``lfd.cache`` (trained once per learner, demos, seed and options) or from a model file. Each learner
runs every scenario on one ``sim.Experiment``; obstacles and a moving goal wrap the fields
(``lfd.avoid``, ``lfd.goal``) and go into the scene. Files are written by ``sim.outputs.OutputSet``:
staged, then moved into place together, ``metrics.json`` last (see ``sim.job_files``).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import lfd
from lfd import goal as moving_goal
from lfd.cache import cached_field
from lfd.errors import ConfigError
from lfd.field import Field, space_mismatch
from lfd.learners import get_learner
from lfd.obstacles import MIN_GOAL_GAMMA, Obstacle, parse_obstacle
from robots import RobotError, load_robot
from sim.collision import hand_margin_m
from sim.controller import Gains
from sim.errors import PlacementError
from sim.experiment import Experiment, RunResult
from sim.gl import require_backend
from sim.job import (
    DEFAULT_LEARNERS,
    OBSTACLE_LEAD_S,
    OBSTACLE_TIME_FACTOR,
    SIDE_BY_SIDE_LEARNERS,
    ArmJob,
    PushSpec,
)
from sim.job_files import JobFiles
from sim.obstacles import obstacle_contacts
from sim.perturbations import Perturbation
from sim.setup import RunSetup

__all__ = ["ArmJob", "JobReport", "OBSTACLE_LEAD_S", "OBSTACLE_TIME_FACTOR", "PushSpec", "grown", "run_job"]

@dataclass
class JobReport:
    """What ``run_job`` did: the scored runs, the models and where the files went."""

    results: list[RunResult]
    side_by_side: list[RunResult]
    grid: list[RunResult]
    models: dict[str, dict[str, Any]]
    out: Path
    json_path: Path
    n_videos: int
    report: dict[str, Any]


def iters_option(learner: str, iters: int) -> dict[str, int]:
    """``{'iters': n}`` or ``{'iterations': n}``, as the learner's Config names it (empty if neither)."""
    names = {f.name for f in dataclasses.fields(get_learner(learner).Config)}
    key = next((k for k in ("iters", "iterations") if k in names), None)
    return {} if key is None else {key: iters}


def grown(obstacles: list[Obstacle], margin: float) -> list[Obstacle]:
    """The obstacles with ``margin`` (task units) added to each one's own."""
    return [dataclasses.replace(o, margin=o.margin + margin) if margin > 0 else o for o in obstacles]


GoalMotion = tuple[str, Any]


def goal_motion_of(job: ArmJob, dim: int) -> GoalMotion | None:
    """The goal's motion, ``("shift", (t, dx))`` or ``("path", (times, goals))``, read and checked, or None."""
    if job.goal_shift:
        return "shift", moving_goal.parse_goal_shift(job.goal_shift, dim)
    if job.goal_path:
        times, goals = moving_goal.load_goal_path(job.goal_path)
        if goals.ndim != 2 or goals.shape[1] != dim:
            raise ConfigError(f"--goal-path {job.goal_path}: {goals.shape[-1]}-D goals for {dim}-D demos")
        return "path", (times, goals)
    return None


def check_goal_motion(motion: GoalMotion, exp: Experiment, obstacles: list[Obstacle]) -> None:
    """Every goal the runs visit must be reachable and clear of the obstacles, as the demos' goal
    is, and a shift must come before the run ends."""
    kind, spec = motion
    if kind == "shift":
        t, dx = spec
        if t >= exp.duration_s:
            raise ConfigError(f"--goal-shift at t = {t:g} s comes after the run ends ({exp.duration_s:g} s)")
        goals = np.stack([exp.setup.goal, exp.setup.goal + dx])
    else:
        goals = spec[1]
    flag = "--goal-shift" if kind == "shift" else "--goal-path"
    for o in obstacles:
        if float(np.min(o.gamma(goals))) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{flag}: the moving goal comes inside or too close to the {o.describe()}")
    try:
        exp.placement.check_reachable(exp.robot, goals, rotation=exp.setup.rotation_ref)
    except PlacementError as e:
        raise ConfigError(f"{flag}: the moving goal leaves the arm's reach ({e})") from None


def moving(field_: Field, motion: GoalMotion) -> Field:
    """``field_`` re-centred on the moving goal (``lfd.goal.shift_goal`` / ``follow_goal_path``)."""
    kind, spec = motion
    return moving_goal.shift_goal(field_, *spec) if kind == "shift" else moving_goal.follow_goal_path(field_, *spec)


def describe_goal_motion(job: ArmJob) -> dict[str, Any] | None:
    """The moving goal's options, for metrics.json."""
    if job.goal_shift:
        return {"shift": job.goal_shift, "blend_s": moving_goal.BLEND_S}
    if job.goal_path:
        return {"path": str(job.goal_path), "blend_s": moving_goal.BLEND_S}
    return None


def _say(job: ArmJob, text: str) -> None:
    if not job.quiet:
        print(text, file=sys.stderr)


def run_job(job: ArmJob, on_run: Callable[[RunResult], None] | None = None) -> JobReport:
    """Run ``job`` (module docstring): check, train or load, simulate, score, write.

    Parameters
    ----------
    job : ArmJob
        The job's options.
    on_run : callable, optional
        Called with each scored run as it finishes.

    Returns
    -------
    JobReport
        The runs and where their files are (all written when this returns).
    """
    job.check()
    progress = not job.quiet and sys.stderr.isatty()   # bars only on a terminal
    planned = list(job.learners) if job.learners else (["node"] if job.model else list(DEFAULT_LEARNERS))
    files = JobFiles(job, planned)                     # every output path checked before any work
    demos = lfd.load_demos(job.demos)
    if demos.has_orientation and (job.obstacles or job.goal_shift or job.goal_path):
        flag = "--obstacle" if job.obstacles else "--goal-shift/--goal-path"
        raise ConfigError(f"{flag} is for position demos; {demos.name} are poses (the goal pose shift "
                          "is the scenario 'goal')")
    obstacles = [parse_obstacle(text, demos.dim) for text in job.obstacles]
    goal_motion = goal_motion_of(job, demos.dim)
    # the goal the runs head for: --goal, or the demos' mean end (obstacles are for positions only)
    goal, whose = (demos.goal, "the demos' goal") if job.goal is None or demos.has_orientation else \
        (np.asarray(job.goal, dtype=np.float64), "the goal")
    if goal.shape != (demos.dim,) and not demos.has_orientation:
        raise ConfigError(f"--goal needs {demos.dim} coordinates for the {demos.dim}-D demos {demos.name}, "
                          f"got {goal.shape[0]}")
    for o in obstacles:
        if float(o.gamma(goal)) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{whose} lies inside or too close to the {o.describe()}")
    ee_frame = job.ee_frame
    if ee_frame is None and demos.frame is not None:   # poses run with the frame they were recorded in
        ee_frame = demos.frame
        try:
            robot = load_robot(job.robot, ee_frame, actuation=job.actuation, table=job.table)
        except RobotError as e:
            raise ConfigError(f"{demos.name} holds poses of the frame '{ee_frame}', which robot '{job.robot}' "
                              f"cannot use ({e}); name the tool frame with --ee-frame") from None
    else:
        robot = load_robot(job.robot, ee_frame, actuation=job.actuation, table=job.table)
    if job.camera is not None:
        try:
            job.camera.check(robot.mj_model)
        except ValueError as e:
            raise ConfigError(str(e)) from None
    # the placement's reach, on the scene with the obstacles (moving ones move), before any training
    setup = RunSetup.resolve(robot, demos, plane=job.plane, size_m=job.size_m, origin=job.origin, scale=job.scale,
                             shift=job.shift, recorded=job.placement == "recorded", obstacles=obstacles,
                             time_factor=OBSTACLE_TIME_FACTOR if obstacles else 1.0, goal=job.goal)
    exp = Experiment(setup, control_hz=job.control_hz, ik=job.ik, fps=job.fps,
                     gains=Gains(lead_s=OBSTACLE_LEAD_S) if obstacles else Gains(),
                     clearance="auto" if job.arm_clearance else None)
    hand = hand_margin_m(robot) if job.arm_clearance else 0.0
    avoided = grown(obstacles, hand / exp.placement.scale)
    for o, g in zip(obstacles, avoided):
        if float(g.gamma(goal)) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{whose} lies within the hand's size ({hand * 1e3:.0f} mm) "
                              f"of the {o.describe()}: move the obstacle, or give --no-arm-clearance")
    if goal_motion is not None:
        check_goal_motion(goal_motion, exp, avoided)
    if exp.placement.pose:   # a pose task's offset start is turned too: its reach, before any training
        for name in {*job.scenarios, *([job.side_by_side] if job.side_by_side else [])} & {"offset"}:
            try:
                exp.check_start(job.perturbations(name, job.seed, True))
            except PlacementError as e:
                raise ConfigError(f"scenario '{name}': {e}") from None
    pushes = "push" in job.scenarios or job.side_by_side == "push" or job.grid
    if pushes and job.push.start_s + job.push.duration_s > exp.duration_s:
        raise ConfigError(f"the push ends at {job.push.start_s + job.push.duration_s:g} s, after the run "
                          f"({exp.duration_s:g} s)")
    if job.videos:
        require_backend()                              # a missing or broken GL back-end: one line, now

    fields: dict[str, Field] = {}
    models: dict[str, dict[str, Any]] = {}

    def train(name: str) -> None:
        options = {} if job.iters is None else iters_option(name, job.iters)
        t0 = time.perf_counter()
        trained_field, path, trained = cached_field(name, demos, job.seed, options, progress=progress,
                                                    verbose=not job.quiet)
        fields[name] = trained_field
        models[name] = {"path": str(path), "trained_now": trained, "options": options,
                        "train_time_s": trained_field.history.get("train_time_s"),
                        "load_or_train_s": time.perf_counter() - t0}
        _say(job, f"{name}: {'trained' if trained else 'cached'} model {path}")

    if job.model:
        loaded = lfd.load(job.model)
        if job.learners and job.learners[0] != loaded.learner:
            raise ConfigError(f"{job.model} holds a '{loaded.learner}' model, not '{job.learners[0]}'")
        fields[loaded.learner] = loaded
        models[loaded.learner] = {"path": job.model, "trained_now": False}
    else:
        for name in planned:
            train(name)
    main_learners = list(fields)
    if job.side_by_side:
        for name in SIDE_BY_SIDE_LEARNERS:
            if name not in fields:
                train(name)
    for name, f in list(fields.items()):
        if job.goal is not None:   # the learned motion, toward the job's goal
            f = fields[name] = f.toward(np.asarray(job.goal, dtype=np.float64))
        mismatch = space_mismatch(f, exp.placement.chart)
        if mismatch is not None:
            raise ConfigError(f"the {name} model does not fit the demos {demos.name}: {mismatch}")
        if f.dim != exp.placement.dim:
            raise ConfigError(f"the {name} model is {f.dim}-D but the demos {demos.name} are {demos.dim}-D")
        if goal_motion is not None:
            f = fields[name] = moving(f, goal_motion)
        if avoided:
            fields[name] = lfd.avoid(f, avoided)
    if main_learners != planned:   # the model file named its own learner: the planned names follow it
        files = JobFiles(job, main_learners)

    def run(learner: str, name: str, perts: tuple[Perturbation, ...], seed: int, note: str = "") -> RunResult:
        _say(job, f"running {learner} / {name}{note}")
        result = exp.run(fields[learner], name, perts, seed=seed, progress=progress)
        m = result.metrics
        if m.get("blocked"):
            print(f"blocked: {learner} / {name}{note} stopped {m['final_goal_error_m'] * 1e3:.0f} mm from its goal, "
                  f"held {m['final_clearance_m'] * 1e3:.0f} mm clear of what is in its way", file=sys.stderr)
        elif m.get("stopped_short"):
            print(f"short: {learner} / {name}{note} ended {m['final_goal_error_m'] * 1e3:.0f} mm from its goal with "
                  f"nothing holding it back: the field did not bring it there in {exp.duration_s:g} s",
                  file=sys.stderr)
        if on_run is not None:
            on_run(result)
        return result

    t_sim = time.perf_counter()
    results = [run(learner, name, job.perturbations(name, job.seed, exp.placement.pose), job.seed)
               for learner in main_learners for name in job.scenarios]
    side: list[RunResult] = []
    if job.side_by_side:
        pose = exp.placement.pose
        for learner in SIDE_BY_SIDE_LEARNERS:
            done = [r for r in results if r.learner == learner and r.scenario == job.side_by_side]
            side.append(done[0] if done else run(learner, job.side_by_side,
                                                 job.perturbations(job.side_by_side, job.seed, pose), job.seed,
                                                 " (side by side)"))
    grid = [run(main_learners[0], "push", job.perturbations("push", job.seed + i), job.seed + i,
                f", seed {job.seed + i} (grid)") for i in range(job.grid or 0)]
    t_sim = time.perf_counter() - t_sim
    if obstacles:
        for r in {id(r): r for r in results + side + grid}.values():
            contacts = obstacle_contacts(exp.robot, r.trace.q, r.trace.t, r.trace.mocap_pos)
            r.metrics.update(obstacle_contacts=contacts.contacts,
                             obstacle_steps_in_contact=contacts.steps_in_contact,
                             obstacle_min_clearance_m=contacts.min_clearance_m)
    report = files.write(exp, results, side, grid, fields, models, t_sim, progress,
                         settings={"seed": job.seed, "goal_motion": describe_goal_motion(job),
                                   "goal": None if job.goal is None else list(job.goal)})
    return JobReport(results, side, grid, models, files.out, files.json_path, files.n_videos, report)
