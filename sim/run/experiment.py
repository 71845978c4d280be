"""An experiment: one run setup (``sim.scene.setup.RunSetup``: robot, demos, placement, start, goal,
obstacles), run under named perturbation scenarios with any learned field, scored
(``sim.metrics``) and optionally filmed (``sim.media.render``).

The run starts at the start of demo ``demo_index`` and lasts ``time_factor`` times that demo's
duration plus ``settle_s``. Push metrics compare with the same run without the push, which is run
(once per field) when needed. A field with a phase (``lfd.learners.tracking``) carries it through
its runner (``lfd.runner``); such runs also report, from the phase trace, ``path_error_m``
(|p(t) - r(s(t))| in world at the end), ``path_recovery_time_s`` (after a push or a hold, until
|p - r(s)| stays <= 5 mm), ``phase_lag_s`` (T max_t (s_u(t) - s(t)), s_u the run without the push or
hold) and, with a hold, ``phase_advance_hold`` beside ``phase_advance_free``. Pose runs add
``sim.metrics.orientation_metrics``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lfd.demos import DemoSet
from lfd.field import Field, goal_at, space_mismatch
from lfd.obstacles import Obstacle
from lfd.runner import Runner
from robots import RobotModel
from robots.limits import Limits, limits_of
from sim.control.controller import Gains
from sim.control.env import FieldEnvironment, make_environment
from sim.control.loop import FPS, RunTrace, execute
from sim.control.task import ArmPhysics
from sim.errors import SimError
from sim.media.camera import CameraSpec
from sim.media.render import HEIGHT, WIDTH, Panel, render_panels
from sim.metrics import (
    RECOVERY_TOLERANCE_M,
    clearance_metrics,
    command_metrics,
    orientation_metrics,
    recovery_time,
    run_metrics,
)
from sim.scene.collision import TABLE_GEOM, Clearance
from sim.scene.obstacles import mocap_path
from sim.scene.perturbations import GoalShift, Hold, JointVelocityNoise, Perturbation, Push, StartOffset
from sim.scene.placement import Placement, base_position
from sim.scene.setup import SETTLE_S, RunSetup

SCENARIOS: tuple[str, ...] = ("none", "offset", "push", "goal", "noise", "hold")


def scenario(name: str, seed: int = 0, pose: bool = False) -> tuple[Perturbation, ...]:
    """The perturbations of a named scenario: ``none``; ``offset`` (start 2 cm off the demo's
    start; a pose task's 5 cm and turned 30 degrees); ``push`` (20 N for 0.2 s on the tool's body at
    t = 1 s); ``goal`` (goal moved 2 cm; a pose task's also turned 15 degrees); ``noise``
    (joint-velocity noise 0.01 rad/s per control step); ``hold`` (the arm held still from t = 1 s for
    1 s, ``sim.scene.perturbations.Hold``). Directions and axes are drawn from seed."""
    table: dict[str, tuple[Perturbation, ...]] = {
        "none": (),
        "offset": (StartOffset(distance_m=0.05, angle_deg=30.0, seed=seed) if pose else
                   StartOffset(distance_m=0.02, seed=seed),),
        "push": (Push(force_n=20.0, duration_s=0.2, start_s=1.0, seed=seed),),
        "goal": (GoalShift(distance_m=0.02, angle_deg=15.0, seed=seed) if pose else
                 GoalShift(distance_m=0.02, seed=seed),),
        "noise": (JointVelocityNoise(std_rad_s=0.01, seed=seed),),
        "hold": (Hold(start_s=1.0, duration_s=1.0),),
    }
    if name not in table:
        raise ValueError(f"unknown scenario '{name}'; known: {', '.join(SCENARIOS)}")
    return table[name]


@dataclass
class RunResult:
    """A scored run.

    Attributes
    ----------
    learner, scenario : str
        The field's learner and the scenario's name (``SCENARIOS``, or a caller's own label).
    trace : RunTrace
        The measured run (``sim.control.loop.RunTrace``).
    reference : ndarray, shape (K+1, 3)
        The unperturbed field rollout mapped to world, m.
    metrics : dict
        The run's scores (``sim.metrics.run_metrics`` and more, see ``Experiment.run``).
    unperturbed : ndarray, shape (K+1, 3), or None
        The measured tool path of the same run without its push or hold (None when it had neither).
    command : ndarray, shape (K+1, d), or None
        The field's command v = f(x - dg) at each measured position, task units per second.
    goal_path : ndarray, shape (K+1, 3), or None
        Where the goal was at each control step, world m, for a goal that moves during the run
        (``lfd.goal``); None for a fixed goal (``RunTrace.goal_world``).
    perturbations : tuple of Perturbation
        The perturbation objects the run was made with, exactly as given to ``Experiment.run``
        (or those of the named scenario): ``p.describe()`` for the metrics JSON.
    """

    learner: str
    scenario: str
    trace: RunTrace
    reference: np.ndarray
    metrics: dict[str, Any]
    unperturbed: np.ndarray | None = None
    command: np.ndarray | None = None
    perturbations: tuple[Perturbation, ...] = ()
    goal_path: np.ndarray | None = None


class Experiment:
    """Runs fields on one run setup (see module docstring).

    Parameters
    ----------
    robot : RobotModel or RunSetup
        The arm (its actuation is the robot's, ``robots.load_robot(..., actuation=...)``), whose
        setup is resolved here from ``demos`` and the setup options (``RunSetup.resolve``), or a
        resolved ``RunSetup`` (then the setup options must be left out).
    demos : DemoSet, optional
        The demonstrations (positions or poses); needed with a robot.
    placement, plane, size_m, demo_index, obstacles, time_factor, settle_s :
        The setup options of ``RunSetup.resolve``.
    control_hz, ik, gains, feedforward, limiter : as ``sim.make_environment``.
    on_reset : callable, optional
        Places the scene's objects at each episode's start (``sim.make_environment``).
    events : sequence of Perturbation
        The scene's events, added to every run's perturbations (a task's ``Release``: the hand lets go).
    limits : Limits, optional
        The arm's limits (default ``robots.limits.limits_of(robot)``): the limiter's, and every run's
        report against them.
    fps : float
        Rate at which the rollouts keep the full qpos for video, frames per simulated second.
    clearance : Clearance, None or "auto"
        Whole-arm collision dampers in the IK (``sim.scene.collision``); ``"auto"`` (default): the
        default ``Clearance`` when the scene has obstacles or a table, else none.
    """

    def __init__(self, robot: RobotModel | RunSetup, demos: DemoSet | None = None, *,
                 placement: Placement | None = None, plane: str = "auto", size_m: float | None = None,
                 demo_index: int = 0, control_hz: float = 500.0, ik: str = "dls", settle_s: float = SETTLE_S,
                 gains: Gains = Gains(), feedforward: bool = True, fps: float = FPS,
                 obstacles: Sequence[Obstacle] = (), clearance: Clearance | str | None = "auto",
                 time_factor: float = 1.0, limiter: bool = False, limits: Limits | None = None,
                 on_reset: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None,
                 events: Sequence[Perturbation] = ()) -> None:
        if isinstance(robot, RunSetup):
            self.setup = robot
        else:
            if demos is None:
                raise SimError("an Experiment needs demos with a robot, or a resolved RunSetup")
            self.setup = RunSetup.resolve(robot, demos, placement=placement, plane=plane, size_m=size_m,
                                          demo_index=demo_index, obstacles=obstacles, time_factor=time_factor,
                                          settle_s=settle_s)
        setup = self.setup
        # the setup's parts, by name (``sim.scene.setup.RunSetup``): the scene's robot, the demos as given and
        # as task points, the placement, the run's start and length, the obstacles
        self.robot, self.demos, self.task_demos, self.placement = setup.robot, setup.demos, setup.task_demos, \
            setup.placement
        self.start, self.duration_s, self.obstacles = setup.start, setup.duration_s, setup.obstacles
        #: the arm's motion limits (``robots.limits``): every run reports its peaks against them
        self.limits = limits_of(setup.robot) if limits is None else limits
        if isinstance(clearance, str):
            if clearance != "auto":
                raise SimError(f"clearance must be a Clearance, None or 'auto', not '{clearance}'")
            table = mujoco.mj_name2id(setup.robot.mj_model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM) >= 0
            clearance = Clearance() if (setup.obstacles or table) else None
        self.options: dict[str, Any] = dict(control_hz=control_hz, ik=ik, gains=gains, feedforward=feedforward,
                                            clearance=clearance, limiter=limiter, limits=self.limits,
                                            on_reset=on_reset)
        #: the scene's events of every run (``Release``)
        self.events: tuple[Perturbation, ...] = tuple(events)
        self.physics = ArmPhysics.from_robot(setup.robot)
        self.base = base_position(setup.robot)
        self.fps = float(fps)   # the rollouts record the full qpos at this video frame rate
        self._unperturbed: dict[tuple, tuple[Field, np.ndarray, np.ndarray | None]] = {}

    def environment(self, perturbations: Sequence[Perturbation] = (), goal: np.ndarray | None = None
                    ) -> FieldEnvironment:
        """The dm_env environment of a run with ``perturbations`` (``sim.make_environment`` on this
        setup and physics), toward ``goal``, shape (d,), task units (default the setup's)."""
        setup = self.setup if goal is None else self.setup.moved(goal=goal)
        return make_environment(setup, perturbations=(*perturbations, *self.events), physics=self.physics,
                                **self.options)

    def simulate(self, field: Field, perturbations: tuple[Perturbation, ...] = (),
                 progress: bool = False, desc: str = "run") -> RunTrace:
        """One closed-loop run of ``field`` with ``perturbations`` (``sim.control.loop.execute``)."""
        return self._simulate(field, perturbations, progress, desc)[0]

    def _simulate(self, field: Field, perturbations: tuple[Perturbation, ...], progress: bool,
                  desc: str) -> tuple[RunTrace, Runner]:
        self._check_space(field)
        # the goal the run must reach: where a moving goal is at the end of the run
        env = self.environment(perturbations, goal_at(field, self.duration_s))
        task = env.task
        path = mocap_path(self.robot.mj_model, self.obstacles, self.placement,
                          np.arange(task.n_steps + 1) * task.control_dt)
        if path is not None:
            task.set_mocap_path(path)
        runner = field.runner(task.start_task - task.schedule.goal_offset_task, task.control_dt)
        return execute(env, runner, fps=self.fps, progress=progress, desc=desc), runner

    def check_start(self, perturbations: tuple[Perturbation, ...]) -> None:
        """``PlacementError`` if a run with ``perturbations`` would start out of the arm's reach
        (an offset or turned start), before any field exists."""
        self.environment(perturbations)

    def _check_space(self, field: Field) -> None:
        """SimError unless the field lives where the task does (a pose field on this task's chart)."""
        reason = space_mismatch(field, self.placement.chart)
        if reason is not None:
            raise SimError(f"{reason} ({self.demos.name}): train it on these demos")

    def task_points(self, trace: RunTrace) -> np.ndarray:
        """The run's measured tool poses as task points, shape (K+1, d) (chart points for poses)."""
        return self.placement.to_task(trace.ee, trace.ee_rot)

    def reference_task(self, field: Field, trace: RunTrace) -> np.ndarray:
        """x_ref(t_k), shape (K+1, d): the task-space rollout of the (goal-shifted) field from the
        run's measured start, x_ref = dg + Phi_t(x0 - dg) (``Field.trajectory``: RK4 of the field's
        own state, x and its phase or the time, from t = 0)."""
        shift = self._shift(field, trace)
        x0 = self.task_points(trace)[0]
        return field.trajectory(x0 - shift, trace.t)[0] + shift

    def reference(self, field: Field, trace: RunTrace) -> np.ndarray:
        """p_ref(t_k), shape (K+1, 3): ``reference_task`` mapped to world."""
        return self.placement.to_world(self.reference_task(field, trace))

    def _shift(self, field: Field, ro: RunTrace) -> np.ndarray:
        """The run's constant goal shift dg (``sim.scene.perturbations.GoalShift``), shape (d,), task units:
        its goal minus the field's own goal at the run's end."""
        return ro.goal_task - goal_at(field, self.duration_s)

    def run(self, field: Field, name: str, perturbations: tuple[Perturbation, ...] | None = None,
            seed: int = 0, progress: bool = False) -> RunResult:
        """Run and score scenario ``name`` (its perturbations, or the ones given)."""
        perts = scenario(name, seed, self.placement.pose) if perturbations is None else perturbations
        ro, runner = self._simulate(field, perts, progress, desc=f"{field.learner}/{name}")
        unperturbed = None
        window = ro.push_window_s or ro.hold_window_s
        cached = None
        if window is not None:
            rest = tuple(p for p in perts if not isinstance(p, (Push, Hold)))
            key = (id(field), rest)
            cached = self._unperturbed.get(key)
            if cached is None or cached[0] is not field:
                free = self.simulate(field, rest, progress, desc=f"{field.learner}/unpushed")
                cached = (field, free.ee, free.phase)
                self._unperturbed[key] = cached
            unperturbed = cached[1]
        ref_task = self.reference_task(field, ro)
        ref = self.placement.to_world(ref_task)
        metrics: dict[str, Any] = run_metrics(ro.t, ro.ee, ref, ro.goal_world, self.setup.demo_t, self.setup.demo_world,
                                              unperturbed, ro.push_window_s)
        if ro.ee_rot is not None and self.setup.demo_rotations is not None:     # a pose task
            metrics.update(orientation_metrics(ro.t, ro.ee_rot, self.placement.rotation_to_world(ref_task),
                                               self.placement.rotation_to_world(ro.goal_task), self.setup.demo_t,
                                               self.setup.demo_rotations))
        metrics.update(joint_limit_violations=ro.joint_limit_violations, ik_limit_hits=ro.ik_limit_hits,
                       realtime_factor=ro.realtime_factor, control_step_us=ro.control_step_us,
                       motion_limits=self.limits.check(ro.t, ro.q, ro.qdot, ro.ee, ro.ee_rot))
        if ro.joint_command is not None:
            assert ro.ik_command is not None
            metrics.update(command_metrics(self.limits, ro.t, ro.q, ro.joint_command, ro.ik_command))
        if ro.phase is not None:
            free_phase = None if cached is None else cached[2]
            metrics.update(self.phase_metrics(field, runner, ro, window, free_phase))
        if ro.arm_clearance_m is not None and ro.guard_active is not None:
            metrics.update(clearance_metrics(ro.t, ro.arm_clearance_m, ro.guard_active,
                                             metrics["final_goal_error_m"]))
        return RunResult(field.learner, name, ro, ref, metrics, unperturbed, ro.command, tuple(perts),
                         self.goal_path(field, ro))

    def goal_path(self, field: Field, ro: RunTrace) -> np.ndarray | None:
        """Where the goal of ``field`` was at each step of ``ro``, shape (K+1, 3), world m (with the
        run's goal shift dg); None unless the goal moves during the run (``lfd.goal``)."""
        shift = self._shift(field, ro)
        path = np.array([goal_at(field, float(t)) for t in ro.t]) + shift
        return None if np.ptp(path, axis=0).max() == 0 else self.placement.to_world(path)

    def command(self, field: Field, ro: RunTrace) -> np.ndarray:
        """The field's command at every control step, shape (K+1, d), task units per second:
        v_k = f(x_k - dg) at the measured x_k (and time t_k, and the recorded phase s_k of a field
        with one), recomputed from the recorded states: a check of ``RunTrace.command``, which the
        loop records as it feeds the controller (before IK)."""
        shift = self._shift(field, ro)
        x = self.task_points(ro) - shift
        runner = field.runner(ro.start_task - shift, float(ro.t[1] - ro.t[0]))
        phase = [None] * len(x) if ro.phase is None else ro.phase
        return np.array([runner.command_at(xk, float(tk), sk) for xk, tk, sk in zip(x, ro.t, phase)])

    def phase_metrics(self, field: Field, runner: Runner, ro: RunTrace, window: tuple[float, float] | None,
                      free_phase: np.ndarray | None) -> dict[str, Any]:
        """The phase metrics of a run whose field carries a phase (module docstring)."""
        assert ro.phase is not None and runner.duration is not None
        shift = self._shift(field, ro)
        x0 = self.task_points(ro)[0] - shift
        ref = field.runner(x0, runner.dt).path(ro.phase)
        assert ref is not None
        path = self.placement.to_world(ref + shift)      # (K+1, 3)
        err = np.linalg.norm(ro.ee - path, axis=1)
        duration = runner.duration
        out: dict[str, Any] = {"path_error_m": float(err[-1]), "path_error_max_after_1s_m":
                               float(err[ro.t >= 1.0].max()) if np.any(ro.t >= 1.0) else None,
                               "final_phase": float(ro.phase[-1])}
        if window is not None:
            out["path_recovery_time_s"] = recovery_time(ro.t, err, window, RECOVERY_TOLERANCE_M)
            if free_phase is not None:
                out["phase_lag_s"] = float(np.max(free_phase - ro.phase) * duration)
                out["phase_lag_end_s"] = float((free_phase[-1] - ro.phase[-1]) * duration)
        if ro.hold_window_s is not None:
            k0, k1 = (int(round(v / (ro.t[1] - ro.t[0]))) for v in ro.hold_window_s)
            out["phase_advance_hold"] = float(ro.phase[k1] - ro.phase[k0])
            out["phase_advance_free"] = float((ro.hold_window_s[1] - ro.hold_window_s[0]) / duration)
        return out

    def render(self, result: RunResult | list[RunResult], path: str | os.PathLike, width: int = WIDTH,
               height: int = HEIGHT, fps: float = FPS, progress: bool = False,
               camera: CameraSpec = CameraSpec(), titles: list[str] | None = None) -> int:
        """Write the MP4 of one run, or of several runs side by side (one labelled panel each,
        ``sim.media.render.render_panels``, ``width`` x ``height`` in all); returns the frame count."""
        results = result if isinstance(result, list) else [result]
        normal = None if self.placement.dim != 2 else self.placement.normal
        names = titles or [f"{r.learner} / {r.scenario}" for r in results]
        panels = [Panel(r.trace, r.reference, name, r.goal_path) for r, name in zip(results, names)]
        return render_panels(self.physics.model.ptr, panels, self.setup.demo_world, path, self.base,
                             self.robot.mj_qpos_adr, normal, width, height, fps, camera, progress=progress,
                             demo_rotations=self.setup.demo_rotations)

    def describe(self) -> dict[str, Any]:
        """The experiment's settings, for the metrics JSON."""
        clearance = self.options["clearance"]
        opts = dict(self.options, gains=dataclasses.asdict(self.options["gains"]),
                    clearance=None if clearance is None else dataclasses.asdict(clearance), limits=self.limits.name,
                    on_reset=None if self.options["on_reset"] is None else getattr(self.options["on_reset"], "__name__",
                                                                                      "objects placed"))
        return {"robot": self.robot.name, "ee_frame": self.robot.ee_frame, "demos": self.demos.name,
                "demo_index": self.setup.demo_index, "duration_s": self.duration_s,
                "placement": self.placement.to_dict(), "actuation": self.robot.actuation, **opts}
