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
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import lfd
from lfd.errors import ConfigError
from lfd.field import Field, is_phased
from lfd.obstacles import MIN_GOAL_GAMMA, Obstacle, parse_obstacle
from robots import RobotError, RobotModel, load_robot
from sim.camera import CameraSpec
from sim.collision import hand_margin_m
from sim.controller import Gains
from sim.errors import PlacementError
from sim.experiment import SCENARIOS, Experiment, RunResult, scenario
from sim.gl import require_backend
from sim.obstacles import obstacle_contacts
from sim.perturbations import Perturbation, Push
from sim.placement import Placement

__all__ = ["ArmJob", "JobReport", "PushSpec", "run_job"]

#: the learners a job runs when it names none (and the panels of a side-by-side video)
DEFAULT_LEARNERS = ("node", "contraction")
SIDE_BY_SIDE_LEARNERS = ("node", "contraction", "tracking")
#: the controller's phase lead with obstacles (``sim.controller.Gains.lead_s``), s
OBSTACLE_LEAD_S = 0.01
#: with obstacles a run lasts this many times the demo's duration (then the settling time): the
#: horizon at which the field-level benchmark asks every start to have arrived (``lfd.bench.obstacles``
#: HORIZON; a literal here, since importing ``lfd.bench`` would load torch with the job)
OBSTACLE_TIME_FACTOR = 3.0


@dataclass(frozen=True)
class PushSpec:
    """The ``push`` scenario's force: ``force_n`` N for ``duration_s`` s from ``start_s`` s along the
    world ``direction`` (normalised; None: drawn from the run's seed)."""

    force_n: float = 20.0
    start_s: float = 1.0
    duration_s: float = 0.2
    direction: tuple[float, float, float] | None = None

    def check(self) -> None:
        """Raise ``ConfigError`` for a force outside [0, 1000] N, a negative start, a duration
        outside (0, 60] s or a zero direction."""
        if not (math.isfinite(self.force_n) and 0 <= self.force_n <= 1000):
            raise ConfigError(f"--push-force must be between 0 and 1000 N, got {self.force_n:g}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise ConfigError(f"--push-start must be a time >= 0 s, got {self.start_s:g}")
        if not (math.isfinite(self.duration_s) and 0 < self.duration_s <= 60):
            raise ConfigError(f"--push-duration must be in (0, 60] s, got {self.duration_s:g}")
        if self.direction is not None and not any(self.direction):
            raise ConfigError("--push-direction must not be zero")

    def perturbation(self, seed: int) -> Push:
        """The ``sim.Push`` of this spec, its direction drawn from ``seed`` unless given."""
        return Push(force_n=self.force_n, duration_s=self.duration_s, start_s=self.start_s,
                    direction=self.direction, seed=seed)


@dataclass(frozen=True)
class ArmJob:
    """Everything one arm job does; the fields mirror ``scripts/demo_arm.py``'s flags.

    ``learners`` None runs ``DEFAULT_LEARNERS``, or the learner of ``model``; ``out`` None is a fresh
    ``out/demo_arm_<time>``; ``placement`` is ``auto`` (``origin``, ``scale`` or ``size_m`` adjust
    it) or ``recorded`` (3-D demos where they were recorded, metres in the robot's base frame).
    ``obstacles`` are ``lfd.obstacles.parse_obstacle`` texts, in task units; with
    ``arm_clearance`` (the default) the fields keep the tool point the hand's size
    (``sim.collision.hand_margin_m``) more than each obstacle's margin away, and collision dampers in
    the IK keep the rest of the arm clear of the obstacles, the table and itself (``sim.collision``).
    """

    robot: str = "panda"
    ee_frame: str | None = None
    learners: tuple[str, ...] | None = None
    model: str | None = None
    demos: str = "spiral"
    scenarios: tuple[str, ...] = ("none", "offset", "push")
    seed: int = 0
    out: str | None = None
    overwrite: bool = False
    json: str | None = None
    video: str | None = None
    videos: bool = True
    plots: bool = True
    camera: CameraSpec | None = None
    size: tuple[int, int] | None = None
    fps: float = 30.0
    side_by_side: str | None = None
    grid: int | None = None
    table: bool = False
    ik: str = "dls"
    actuation: str = "torque"
    plane: str = "auto"
    size_m: float | None = None
    placement: str = "auto"
    origin: tuple[float, float, float] | None = None
    shift: tuple[float, float, float] | None = None
    scale: float | None = None
    push: PushSpec = PushSpec()
    obstacles: tuple[str, ...] = ()
    arm_clearance: bool = True
    goal_shift: str | None = None
    goal_path: str | None = None
    control_hz: float = 500.0
    iters: int | None = None
    quiet: bool = False
    command: tuple[str, ...] = field(default_factory=lambda: tuple(sys.argv))

    def check(self) -> None:
        """Raise ``ConfigError`` for options that contradict each other or are out of range."""
        from lfd.learners import LEARNERS, MAX_SEED

        if isinstance(self.seed, bool) or not 0 <= self.seed <= MAX_SEED:
            raise ConfigError(f"--seed must be between 0 and 2^63 - 1, got {self.seed}")
        if self.model and self.learners is not None and len(self.learners) != 1:
            raise ConfigError("--model holds one learner; leave out --learner or name that learner")
        for name in self.learners or ():
            if name not in LEARNERS:
                raise ConfigError(f"unknown learner '{name}'; known: {', '.join(LEARNERS)}")
        for name in (*self.scenarios, *([self.side_by_side] if self.side_by_side else [])):
            if name not in SCENARIOS:
                raise ConfigError(f"unknown scenario '{name}'; use one of {', '.join(SCENARIOS)}")
        if not self.scenarios:
            raise ConfigError("a job needs at least one scenario")
        if not (math.isfinite(self.control_hz) and self.control_hz > 0) or (
                self.size_m is not None and not (math.isfinite(self.size_m) and self.size_m > 0)):
            raise ConfigError("--control-hz and --size-m must be positive")
        if self.scale is not None and not (math.isfinite(self.scale) and self.scale > 0):
            raise ConfigError(f"--scale must be a positive number, got {self.scale:g}")
        if self.placement == "recorded" and (self.origin, self.scale, self.size_m) != (None, None, None):
            raise ConfigError("--placement recorded takes no --origin, --scale or --size-m")
        if self.shift is not None and (self.origin, self.scale, self.size_m) != (None, None, None):
            raise ConfigError("--shift moves recorded poses; it takes no --origin, --scale or --size-m")
        if self.iters is not None and self.iters < 1:
            raise ConfigError(f"--iters must be a positive integer, got {self.iters}")
        self.push.check()

    def perturbations(self, name: str, seed: int, pose: bool = False) -> tuple[Perturbation, ...]:
        """The perturbations of scenario ``name`` with ``seed`` (of a pose task if ``pose``), the push
        taking ``push``."""
        return (self.push.perturbation(seed),) if name == "push" else scenario(name, seed, pose)


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
    from lfd.learners import get_learner

    names = {f.name for f in dataclasses.fields(get_learner(learner).Config)}
    key = next((k for k in ("iters", "iterations") if k in names), None)
    return {} if key is None else {key: iters}


def grown(obstacles: list[Obstacle], margin: float) -> list[Obstacle]:
    """The obstacles with ``margin`` (task units) added to each one's own."""
    return [dataclasses.replace(o, margin=o.margin + margin) if margin > 0 else o for o in obstacles]


def placement_of(job: ArmJob, robot: RobotModel, demos: lfd.DemoSet) -> Placement | None:
    """The placement the job asks for, or None for the Experiment's default (``Placement.auto``;
    for poses ``Placement.recorded``, or ``Placement.auto`` with ``--size-m``)."""
    chart = None
    if demos.has_orientation:
        from lfd.pose import PoseChart

        chart = PoseChart.of(demos)
        if job.shift is not None:   # the recorded poses, translated
            return Placement(np.asarray(job.shift, dtype=np.float64), np.eye(3), 1.0, 6, chart)
        if job.placement == "recorded" or (job.origin is None and job.scale is None):
            return None
    else:
        if job.shift is not None:
            raise ConfigError("--shift is for demos of poses (run where recorded); use --origin for positions")
        if job.placement == "recorded":
            if demos.dim != 3:
                raise ConfigError(f"--placement recorded needs 3-D demos, {demos.name} are {demos.dim}-D")
            return Placement(np.zeros(3), np.eye(3), 1.0, 3)
    if job.origin is None and job.scale is None:
        return None
    auto = Placement.auto(robot, demos.x, plane=job.plane, size_m=job.size_m)
    lo, hi = demos.bounds()
    center = (lo + hi) / 2
    scale = auto.scale if job.scale is None else float(job.scale)
    target = auto.to_world(center) if job.origin is None else np.asarray(job.origin, dtype=np.float64)
    if chart is not None:
        return Placement(target - scale * auto.axes @ center, auto.rotation, scale, 6, chart)
    return Placement(target - scale * auto.axes @ center, auto.rotation, scale, auto.dim)


GoalMotion = tuple[str, Any]


def goal_motion_of(job: ArmJob, dim: int) -> GoalMotion | None:
    """The goal's motion, ``("shift", (t, dx))`` or ``("path", (times, goals))``, read and checked, or None."""
    from lfd import goal as moving_goal

    if job.goal_shift:
        return "shift", moving_goal.parse_goal_shift(job.goal_shift, dim)
    if job.goal_path:
        times, goals = moving_goal.load_goal_path(job.goal_path)
        if goals.ndim != 2 or goals.shape[1] != dim:
            raise ConfigError(f"--goal-path {job.goal_path}: {goals.shape[-1]}-D goals for {dim}-D demos")
        return "path", (times, goals)
    return None


def check_goal_motion(motion: GoalMotion, exp: Experiment, demos: lfd.DemoSet, obstacles: list[Obstacle]) -> None:
    """Every goal the runs visit must be reachable and clear of the obstacles, as the demos' goal
    is, and a shift must come before the run ends."""
    kind, spec = motion
    if kind == "shift":
        t, dx = spec
        if t >= exp.duration_s:
            raise ConfigError(f"--goal-shift at t = {t:g} s comes after the run ends ({exp.duration_s:g} s)")
        goals = np.stack([demos.goal, demos.goal + dx])
    else:
        goals = spec[1]
    flag = "--goal-shift" if kind == "shift" else "--goal-path"
    for o in obstacles:
        if float(np.min(o.gamma(goals))) < MIN_GOAL_GAMMA:
            raise ConfigError(f"{flag}: the moving goal comes inside or too close to the {o.describe()}")
    try:
        exp.placement.check_reachable(exp.robot, goals, rotation=exp.rotation_ref)
    except PlacementError as e:
        raise ConfigError(f"{flag}: the moving goal leaves the arm's reach ({e})") from None


def moving(field_: Field, motion: GoalMotion) -> Field:
    """``field_`` re-centred on the moving goal (``lfd.goal.shift_goal`` / ``follow_goal_path``)."""
    from lfd import goal as moving_goal

    kind, spec = motion
    return moving_goal.shift_goal(field_, *spec) if kind == "shift" else moving_goal.follow_goal_path(field_, *spec)


def describe_goal_motion(job: ArmJob) -> dict[str, Any] | None:
    """The moving goal's options, for metrics.json."""
    from lfd.goal import BLEND_S

    if job.goal_shift:
        return {"shift": job.goal_shift, "blend_s": BLEND_S}
    if job.goal_path:
        return {"path": str(job.goal_path), "blend_s": BLEND_S}
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
    from lfd.cache import cached_field
    from sim.job_files import JobFiles

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
    for o in obstacles:
        if float(o.gamma(demos.goal)) < MIN_GOAL_GAMMA:
            raise ConfigError(f"the demos' goal lies inside or too close to the {o.describe()}")
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
    exp = Experiment(robot, demos, placement=placement_of(job, robot, demos), plane=job.plane, size_m=job.size_m,
                     control_hz=job.control_hz, ik=job.ik, fps=job.fps, obstacles=obstacles,
                     gains=Gains(lead_s=OBSTACLE_LEAD_S) if obstacles else Gains(),
                     clearance="auto" if job.arm_clearance else None,
                     time_factor=OBSTACLE_TIME_FACTOR if obstacles else 1.0)
    hand = hand_margin_m(robot) if job.arm_clearance else 0.0
    avoided = grown(obstacles, hand / exp.placement.scale)
    for o, g in zip(obstacles, avoided):
        if float(g.gamma(demos.goal)) < MIN_GOAL_GAMMA:
            raise ConfigError(f"the demos' goal lies within the hand's size ({hand * 1e3:.0f} mm) "
                              f"of the {o.describe()}: move the obstacle, or give --no-arm-clearance")
    if goal_motion is not None:
        check_goal_motion(goal_motion, exp, demos, avoided)
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
        if (f.chart is not None) != demos.has_orientation:
            raise ConfigError(f"the {name} model is trained on {'poses' if f.chart is not None else 'positions'} "
                              f"but the demos {demos.name} are {'poses' if demos.has_orientation else 'positions'}")
        if f.dim != exp.placement.dim:
            raise ConfigError(f"the {name} model is {f.dim}-D but the demos {demos.name} are {demos.dim}-D")
        if goal_motion is not None and is_phased(f):
            raise ConfigError(f"--goal-shift/--goal-path does not apply to the {name} learner yet (its phase state)")
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
                         settings={"seed": job.seed, "goal_motion": describe_goal_motion(job)})
    return JobReport(results, side, grid, models, files.out, files.json_path, files.n_videos, report)
