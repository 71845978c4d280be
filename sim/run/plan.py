"""An arm job resolved into one plan before any simulation: the demos, the robot and its setup, the
fields wrapped for the goal, the moving goal and the obstacles, every run with its perturbations, and
the files it will write.

``plan_job`` checks everything it can before any training or simulation (the options, every output
path, the demos, obstacles and moving goal, the placement's reach, the push window), so a bad job
fails at once with an ``lfd.LfdError``, ``robots.RobotError`` or ``sim.SimError``; then it trains or
loads the models (``lfd.cache``: once per learner, demos, seed and options). ``sim.run.pipeline``
executes the plan.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

import lfd
from lfd import goal as moving_goal
from lfd.bench.dmp_field import dmp_field
from lfd.cache import cached_field
from lfd.demos import DemoSet
from lfd.demos.recording import loud_note
from lfd.errors import ConfigError
from lfd.field import Field, space_mismatch
from lfd.learners import get_learner
from lfd.obstacles import MIN_GOAL_GAMMA, Obstacle, parse_obstacle
from lfd.retime import at_speed
from lfd.via import parse_via, through
from robots import RobotError, RobotModel, load_robot
from robots.limiter import JointLimiter
from robots.limits import limits_of, load_limits
from sim.control.controller import Gains
from sim.errors import PlacementError
from sim.media.gl import require_backend
from sim.run.experiment import Experiment
from sim.run.job import BASELINES, DEFAULT_LEARNERS, SIDE_BY_SIDE_LEARNERS, ArmJob
from sim.run.job_files import JobFiles
from sim.run.obstacle_runs import ObstacleRuns
from sim.run.tasks import Task, plan_task, shifted
from sim.scene.perturbations import Perturbation
from sim.scene.setup import RunSetup

GoalMotion = tuple[str, Any]


@dataclass(frozen=True)
class PlannedRun:
    """One run of a job: ``learner`` under ``scenario``'s ``perturbations`` with ``seed``. ``group``:
    ``main`` (the table's runs), ``side`` (a panel of the side-by-side video; a main run of the same
    learner and scenario is reused) or ``grid`` (one push of the grid video); ``note`` for the messages."""

    learner: str
    scenario: str
    perturbations: tuple[Perturbation, ...]
    seed: int
    group: str = "main"
    note: str = ""


@dataclass
class JobPlan:
    """What a job runs, resolved and checked (module docstring)."""

    job: ArmJob
    demos: DemoSet
    obstacles: list[Obstacle]
    exp: Experiment
    fields: dict[str, Field]        # by learner, wrapped for the goal, the moving goal and the obstacles
    models: dict[str, dict[str, Any]]
    files: JobFiles
    runs: list[PlannedRun]
    progress: bool                   # progress bars (a terminal, not quiet)
    task: Task | None = None     # the task with objects (``sim.run.tasks``), scored per run

    def say(self, text: str) -> None:
        """``text`` on stderr unless the job is quiet."""
        if not self.job.quiet:
            print(text, file=sys.stderr)


def plan_job(job: ArmJob) -> JobPlan:
    """Resolve and check ``job``, then train or load its models (module docstring).

    Parameters
    ----------
    job : ArmJob
        The job's options.

    Returns
    -------
    JobPlan
        Everything ``sim.run.pipeline.run_job`` executes.
    """
    job.check()
    progress = not job.quiet and sys.stderr.isatty()   # bars only on a terminal
    planned = list(job.learners) if job.learners else (["node"] if job.model else list(DEFAULT_LEARNERS))
    files = JobFiles(job, planned)                     # every output path checked before any work
    demos = _demos(job)
    trained_on = _held_out(job, demos)
    task = None if job.task is None else plan_task(job.task, trained_on, job.target)
    if task is not None:   # the goal follows the object; the pose's orientation is the demos'
        task, shift = shifted(task, job.demo_spec, job.shift)   # a lid's box moves with its demos
        job = dataclasses.replace(job, goal=tuple(float(v) for v in task.goal), table=True, shift=shift)
    obstacles = [parse_obstacle(text, demos.dim) for text in job.obstacles]
    vias = [parse_via(text, demos.dim) for text in job.via]
    motion = goal_motion_of(job, demos.dim)
    goal = _goal(job, demos, obstacles)
    exp, task = _experiment(job, demos, obstacles, task, trained_on)
    avoided = _avoided(job, exp, obstacles, goal, motion)
    _check_runs(job, exp, vias)
    fields, models, main = _fields(job, planned, trained_on, progress)
    fields = {name: _wrapped(name, f, job, demos, exp, motion, avoided, vias) for name, f in fields.items()}
    if main != planned:   # the model file named its own learner: the planned names follow it
        files = JobFiles(job, main)
    return JobPlan(job, demos, obstacles, exp, fields, models, files, _runs(job, main, exp.placement.pose), progress,
                   task)


def _held_out(job: ArmJob, demos: DemoSet) -> DemoSet:
    """The demos the learners train on: all, or all but ``job.held_out`` (checked against their number)."""
    if job.held_out is None:
        return demos
    if not 0 <= job.held_out < demos.n_demos or demos.n_demos < 2:
        raise ConfigError(f"--held-out must name one of the {demos.n_demos} demos (0 to {demos.n_demos - 1}) "
                          f"and leave at least one, got {job.held_out}")
    return demos.subset([i for i in range(demos.n_demos) if i != job.held_out])


def _demos(job: ArmJob) -> DemoSet:
    """The job's demos, cleaned as it asks; each note on stderr (a loud one even when quiet)."""
    demos = lfd.load_demos(job.demo_spec, clean=job.clean)
    for note in demos.notes:
        if not job.quiet or loud_note(note):
            print(f"note: {note}", file=sys.stderr)
    if demos.has_orientation and (job.obstacles or job.goal_shift or job.goal_path):
        flag = "--obstacle" if job.obstacles else "--goal-shift/--goal-path"
        raise ConfigError(f"{flag} is for position demos; {demos.name} are poses (the goal pose shift "
                          "is the scenario 'goal')")
    return demos


def _robot(job: ArmJob, demos: DemoSet) -> RobotModel:
    """The job's robot; poses run with the tool frame they were recorded in unless the job names one."""
    if job.ee_frame is not None or demos.frame is None:
        return load_robot(job.robot, job.ee_frame, actuation=job.actuation, table=job.table)
    try:
        return load_robot(job.robot, demos.frame, actuation=job.actuation, table=job.table)
    except RobotError as e:
        raise ConfigError(f"{demos.name} holds poses of the frame '{demos.frame}', which robot '{job.robot}' "
                          f"cannot use ({e}); name the tool frame with --ee-frame") from None


def _experiment(job: ArmJob, demos: DemoSet, obstacles: list[Obstacle], task: Task | None = None,
                trained_on: DemoSet | None = None) -> tuple[Experiment, Task | None]:
    """The job's experiment: the placement's reach checked on the scene with the obstacles (moving ones
    move), before any training; among obstacles with ``ObstacleRuns``' settings; a task's objects in
    the scene, placed at every episode's start, and its motion's end that of the run's own demo at the
    job's speed (returned with it). Held out, the placement (and a pose task's chart) is the training
    demos', and the run starts at the held-out demo's start."""
    robot = _robot(job, demos)
    if task is not None:
        robot = task.with_scene(robot)
    if job.camera is not None:
        try:
            job.camera.check(robot.mj_model)
        except ValueError as e:
            raise ConfigError(str(e)) from None
    among = ObstacleRuns(arm_clearance=job.arm_clearance)
    options: dict[str, Any] = dict(plane=job.plane, size_m=job.size_m, origin=job.origin, scale=job.scale,
                                   shift=job.shift, recorded=job.placement == "recorded", obstacles=obstacles,
                                   time_factor=among.time_factor if obstacles else 1.0, goal=job.goal)
    if trained_on is not None and trained_on is not demos:   # where the fields were learned
        placement = RunSetup.resolve(robot, trained_on, **options).placement
        setup = RunSetup.resolve(robot, demos, placement=placement, obstacles=obstacles, goal=job.goal,
                                 time_factor=options["time_factor"], demo_index=job.held_out or 0)
    else:
        setup = RunSetup.resolve(robot, demos, **options)
    if job.speed != 1.0:   # the motion takes 1/S of the demos' time, then the same settling time
        setup = setup.retimed(job.speed)
    limits = None
    if job.limits is not None:   # a RobotError (bad file) is the job's one line
        limits = load_limits(job.limits)
        if limits.n != robot.n:
            raise ConfigError(f"--limits: {limits.n} joints in {job.limits}, but '{robot.name}' has {robot.n}")
    if job.limiter:   # the limiter's limits, before any training
        JointLimiter(limits_of(robot) if limits is None else limits, 1.0 / job.control_hz)
    if task is not None:   # the release and the judging follow the motion as this run makes it
        task = task.timed(float(setup.demo_t[-1]))
    return Experiment(setup, control_hz=job.control_hz, ik=job.ik, fps=job.fps, limiter=job.limiter,
                      gains=among.gains() if obstacles else Gains(), limits=limits,
                      clearance="auto" if job.arm_clearance else None,
                      on_reset=None if task is None else task.on_reset(robot),
                      events=() if task is None else task.events()), task


def _goal(job: ArmJob, demos: DemoSet, obstacles: list[Obstacle]) -> tuple[np.ndarray, str]:
    """The goal the runs head for, shape (d,), and whose it is: ``--goal``, or the demos' mean end
    (obstacles are for positions only); checked clear of the obstacles."""
    goal, whose = (demos.goal, "the demos' goal") if job.goal is None or demos.has_orientation else \
        (np.asarray(job.goal, dtype=np.float64), "the goal")
    if goal.shape != (demos.dim,) and not demos.has_orientation:
        raise ConfigError(f"--goal needs {demos.dim} coordinates for the {demos.dim}-D demos {demos.name}, "
                          f"got {goal.shape[0]}")
    for o in obstacles:
        if float(o.gamma(goal)) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{whose} lies inside or too close to the {o.describe()}")
    return goal, whose


def _avoided(job: ArmJob, exp: Experiment, obstacles: list[Obstacle], goal: tuple[np.ndarray, str],
             motion: GoalMotion | None) -> list[Obstacle]:
    """The obstacles as the fields avoid them (grown by the hand's size), after checking that the goal,
    and every goal a moving goal visits, stays clear of them and within reach."""
    among = ObstacleRuns(arm_clearance=job.arm_clearance)
    avoided = among.avoided(obstacles, exp.robot, exp.placement.scale)
    for o, g in zip(obstacles, avoided):
        if float(g.gamma(goal[0])) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{goal[1]} lies within the hand's size ({among.hand_margin_m(exp.robot) * 1e3:.0f} "
                              f"mm) of the {o.describe()}: move the obstacle, or give --no-arm-clearance")
    if motion is not None:
        check_goal_motion(motion, exp, avoided)
    return avoided


def _check_runs(job: ArmJob, exp: Experiment, vias: list[tuple[np.ndarray, float | None]]) -> None:
    """The runs' own checks: via-points on positions and within reach, a pose
    task's offset start within reach, the push within the run, and a GL back-end for the videos."""
    if vias:
        if exp.placement.pose:
            raise ConfigError("--via takes position demos (a pose task's via-points are not supported)")
        try:
            exp.placement.check_reachable(exp.robot, np.stack([p for p, _ in vias]), rotation=exp.setup.rotation_ref)
        except PlacementError as e:
            raise ConfigError(f"--via: a via-point leaves the arm's reach ({e})") from None
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


def _fields(job: ArmJob, planned: list[str], demos: DemoSet, progress: bool
            ) -> tuple[dict[str, Field], dict[str, dict[str, Any]], list[str]]:
    """The trained (cached) or loaded fields by learner, their model records, and the main learners
    (those the table runs; the side-by-side video may add others)."""
    fields: dict[str, Field] = {}
    models: dict[str, dict[str, Any]] = {}
    if job.model:
        loaded = lfd.load(job.model)
        if job.learners and job.learners[0] != loaded.learner:
            raise ConfigError(f"{job.model} holds a '{loaded.learner}' model, not '{job.learners[0]}'")
        fields[loaded.learner] = loaded
        models[loaded.learner] = {"path": job.model, "trained_now": False}
    main = list(fields) or planned
    for name in [*main, *(SIDE_BY_SIDE_LEARNERS if job.side_by_side else ())]:
        if name in fields:
            continue
        if name in BASELINES:   # the DMP: fitted here (milliseconds), no model file
            fields[name] = dmp_field(demos)
            models[name] = {"path": None, "trained_now": True, "options": {},
                            "train_time_s": fields[name].history["train_time_s"], "load_or_train_s": 0.0}
            continue
        options = {} if job.iters is None else iters_option(name, job.iters)
        t0 = time.perf_counter()
        fields[name], path, trained = cached_field(name, demos, job.seed, options, progress=progress,
                                                   verbose=not job.quiet)
        models[name] = {"path": str(path), "trained_now": trained, "options": options,
                        "train_time_s": fields[name].history.get("train_time_s"),
                        "load_or_train_s": time.perf_counter() - t0}
        if not job.quiet:
            print(f"{name}: {'trained' if trained else 'cached'} model {path}", file=sys.stderr)
    return fields, models, main


def _wrapped(name: str, f: Field, job: ArmJob, demos: DemoSet, exp: Experiment, motion: GoalMotion | None,
             avoided: list[Obstacle], vias: list[tuple[np.ndarray, float | None]]) -> Field:
    """``f`` toward the job's goal, through the via-points, checked against the task's space,
    re-centred on the moving goal, avoiding the obstacles, at the job's speed."""
    if job.goal is not None:   # the learned motion, toward the job's goal
        f = f.toward(np.asarray(job.goal, dtype=np.float64))
    if vias:
        f = through(f, [p for p, _ in vias], [s for _, s in vias], start=exp.start,
                    duration=float(exp.setup.demo_t[-1]))
    mismatch = space_mismatch(f, exp.placement.chart)
    if mismatch is not None:
        raise ConfigError(f"the {name} model does not fit the demos {demos.name}: {mismatch}")
    if f.dim != exp.placement.dim:
        raise ConfigError(f"the {name} model is {f.dim}-D but the demos {demos.name} are {demos.dim}-D")
    if motion is not None:
        f = moving(f, motion)
    return at_speed(lfd.avoid(f, avoided) if avoided else f, job.speed)


def _runs(job: ArmJob, main: list[str], pose: bool) -> list[PlannedRun]:
    """Every run of the job, in order: each main learner under each scenario, the side-by-side panels,
    the grid's pushes."""
    runs = [PlannedRun(learner, name, job.perturbations(name, job.seed, pose), job.seed)
            for learner in main for name in job.scenarios]
    if job.side_by_side:
        runs += [PlannedRun(learner, job.side_by_side, job.perturbations(job.side_by_side, job.seed, pose),
                            job.seed, "side", " (side by side)") for learner in SIDE_BY_SIDE_LEARNERS]
    runs += [PlannedRun(main[0], "push", job.perturbations("push", job.seed + i), job.seed + i, "grid",
                        f", seed {job.seed + i} (grid)") for i in range(job.grid or 0)]
    return runs


def iters_option(learner: str, iters: int) -> dict[str, int]:
    """``{'iters': n}`` or ``{'iterations': n}``, as the learner's Config names it (empty if neither)."""
    names = {f.name for f in dataclasses.fields(get_learner(learner).Config)}
    key = next((k for k in ("iters", "iterations") if k in names), None)
    return {} if key is None else {key: iters}


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
