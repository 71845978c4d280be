"""An arm job's options: what the ``lfd-demo-arm`` flags set, checked before any work.

``ArmJob`` is what ``sim.run_job`` runs (``sim.run.pipeline``); ``PushSpec`` the force of its ``push``
scenario.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

from lfd.errors import ConfigError
from lfd.retime import check_speed
from sim.media.camera import CameraSpec
from sim.run.experiment import SCENARIOS, scenario
from sim.run.tasks import TASK_DEMOS, TASKS
from sim.scene.perturbations import Perturbation, Push

#: the learners a job runs when it names none (and the panels of a side-by-side video)
DEFAULT_LEARNERS = ("node", "stable_node", "contracting_node", "contraction")
SIDE_BY_SIDE_LEARNERS = ("node", "contraction", "tracking")
#: baselines a job runs beside the learners: the DMP (``lfd.bench.dmp_field``), fitted at every job
BASELINES = ("dmp",)


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
    """Everything one arm job does; the fields mirror the ``lfd-demo-arm`` flags (``sim.run.cli``).

    ``learners`` None runs ``DEFAULT_LEARNERS``, or the learner of ``model``; ``out`` None is a fresh
    ``out/demo_arm_<time>``; ``placement`` is ``auto`` (``origin``, ``scale`` or ``size_m`` adjust
    it) or ``recorded`` (3-D demos where they were recorded, metres in the robot's base frame).
    ``goal`` (task units; for poses the position, or the pose x, y, z, qw, qx, qy, qz, in the demos'
    frame) runs every field toward it instead of the demos' mean end (``Field.toward``).
    ``clean`` is the clean-up of a recorded ``demos`` (``lfd.load_demos``: True all steps, or the steps'
    names). ``speed`` S runs every learned motion S times faster (``lfd.retime.at_speed``), the run
    1/S as long before its settling time. ``via`` (``lfd.via.parse_via`` texts, task units) makes the
    tracking learner's motion pass through those points (``lfd.via.through``). ``limiter`` controls
    through ``robots.controller.ArmController`` (the controller a real arm runs) with its jerk-limited
    limiter of the joint-velocity stream (``robots.limiter``); ``limits`` is a JSON file of the arm's
    limits (``robots.limits.load_limits``; default the robot's own). ``task`` runs a task with objects
    (``sim.run.tasks``: ``pour``, ``place``, ``lid``) and ``target`` puts its object (the bowl, the
    shelf's spot) there, m, robot base frame. ``demos`` None runs the task's RoboTasks9 demos
    (``sim.run.tasks.TASK_DEMOS``), or the spiral without a task (``demo_spec``).
    ``held_out`` K trains every learner on every demo but demo K and runs from demo K's start.
    ``obstacles`` are
    ``lfd.obstacles.parse_obstacle`` texts, in task units; with
    ``arm_clearance`` (the default) the fields keep the tool point the hand's size
    (``sim.scene.collision.hand_margin_m``) more than each obstacle's margin away, and collision dampers in
    the IK keep the rest of the arm clear of the obstacles, the table and itself (``sim.scene.collision``).
    """

    robot: str = "panda"
    ee_frame: str | None = None
    learners: tuple[str, ...] | None = None
    model: str | None = None
    demos: str | None = None
    clean: bool | frozenset[str] = True
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
    goal: tuple[float, ...] | None = None
    goal_shift: str | None = None
    goal_path: str | None = None
    speed: float = 1.0
    via: tuple[str, ...] = ()
    control_hz: float = 500.0
    limiter: bool = False
    limits: str | None = None
    task: str | None = None
    target: tuple[float, ...] | None = None
    held_out: int | None = None
    iters: int | None = None
    quiet: bool = False
    command: tuple[str, ...] = field(default_factory=lambda: tuple(sys.argv))

    @property
    def demo_spec(self) -> str:
        """The demos the job runs: ``demos``, or the task's RoboTasks9 demos, or ``spiral``."""
        return self.demos or TASK_DEMOS.get(self.task or "", "spiral")

    def check(self) -> None:
        """Raise ``ConfigError`` for options that contradict each other or are out of range."""
        from lfd.learners import LEARNERS, MAX_SEED

        if isinstance(self.seed, bool) or not 0 <= self.seed <= MAX_SEED:
            raise ConfigError(f"--seed must be between 0 and 2^63 - 1, got {self.seed}")
        if self.model and self.learners is not None and len(self.learners) != 1:
            raise ConfigError("--model holds one learner; leave out --learner or name that learner")
        for name in self.learners or ():
            if name not in (*LEARNERS, *BASELINES):
                raise ConfigError(f"unknown learner '{name}'; known: {', '.join((*LEARNERS, *BASELINES))}")
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
        if self.goal is not None and (len(self.goal) not in (2, 3, 7) or not all(math.isfinite(v) for v in self.goal)):
            raise ConfigError(f"--goal must be 2 or 3 finite task coordinates or a pose of 7, got {list(self.goal)}")
        check_speed(self.speed)
        if self.task is not None and self.task not in TASKS:
            raise ConfigError(f"unknown task '{self.task}'; known: {', '.join(TASKS)}")
        if self.target is not None and self.task is None:
            raise ConfigError("--target places a task's object: give --task")
        if self.iters is not None and self.iters < 1:
            raise ConfigError(f"--iters must be a positive integer, got {self.iters}")
        self.push.check()

    def perturbations(self, name: str, seed: int, pose: bool = False) -> tuple[Perturbation, ...]:
        """The perturbations of scenario ``name`` with ``seed`` (of a pose task if ``pose``), the push
        taking ``push``."""
        return (self.push.perturbation(seed),) if name == "push" else scenario(name, seed, pose)
