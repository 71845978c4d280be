"""An experiment: one robot, one demonstration set and its placement, run under named perturbation
scenarios with any learned field, scored (``sim.metrics``) and optionally filmed (``sim.render``).

The run starts at the start of demo ``demo_index`` and lasts ``time_factor`` times that demo's
duration plus ``settle_s``. Push metrics compare with the same run without the push, which is run (once per
field) when needed.

A ``FieldKind.PHASED`` field (``lfd.learners.tracking``) runs through ``sim.loop.PhaseLoop`` (the loop
carries s), its reference is the joint (x, s) rollout, and its runs also report, from the phase
trace: ``path_error_m`` (|p(t) - r(s(t))| in world at the end), ``path_recovery_time_s`` (after a
push or a hold: from its start until |p - r(s)| stays <= 5 mm), ``phase_lag_s`` (T max_t (s_u(t) -
s(t)), s_u the run without the push or hold) and, with a hold, ``phase_advance_hold`` (s at the
hold's end minus s at its start) beside ``phase_advance_free`` (the hold's duration / T).

Demos of poses (``DemoSet.has_orientation``) make a pose task: its task points are the chart points
of ``lfd.pose`` (``Experiment.task_demos``), it runs where it was recorded (``Placement.recorded``)
unless a placement is given, and its runs add ``sim.metrics.orientation_metrics``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lfd import DemoSet
from lfd.field import Field, goal_at, is_phased, is_time_varying
from lfd.integrate import rk4, rk4_phase
from lfd.obstacles import Obstacle
from robots import Kinematics, RobotModel
from sim.camera import CameraSpec
from sim.collision import TABLE_GEOM, Clearance
from sim.controller import Gains
from sim.errors import SimError
from sim.loop import FPS, Hold, PhaseLoop, RunTrace, execute
from sim.metrics import RECOVERY_TOLERANCE_M, clearance_metrics, orientation_metrics, recovery_time, run_metrics
from sim.obstacles import mocap_path, with_obstacles
from sim.perturbations import GoalShift, JointVelocityNoise, Perturbation, Push, StartOffset
from sim.placement import Placement, base_position
from sim.render import HEIGHT, WIDTH, Panel, render_panels
from sim.task import ArmPhysics, make_environment

SCENARIOS: tuple[str, ...] = ("none", "offset", "push", "goal", "noise", "hold")


def scenario(name: str, seed: int = 0, pose: bool = False) -> tuple[Perturbation, ...]:
    """The perturbations of a named scenario: ``none``; ``offset`` (start 2 cm off the demo's
    start; a pose task's 5 cm and turned 30 degrees); ``push`` (20 N for 0.2 s on the tool's body at
    t = 1 s); ``goal`` (goal moved 2 cm; a pose task's also turned 15 degrees); ``noise``
    (joint-velocity noise 0.01 rad/s per control step); ``hold`` (the arm held still from t = 1 s for
    1 s, ``sim.loop.Hold``). Directions and axes are drawn from seed."""
    table: dict[str, tuple[Perturbation, ...]] = {
        "none": (),
        "offset": (StartOffset(distance_m=0.05, angle_deg=30.0, seed=seed) if pose else
                   StartOffset(distance_m=0.02, seed=seed),),
        "push": (Push(force_n=20.0, duration_s=0.2, start_s=1.0, seed=seed),),
        "goal": (GoalShift(distance_m=0.02, angle_deg=15.0, seed=seed) if pose else
                 GoalShift(distance_m=0.02, seed=seed),),
        "noise": (JointVelocityNoise(std_rad_s=0.01, seed=seed),),
        "hold": (Hold(start_s=1.0, duration_s=1.0),),  # type: ignore[dict-item]
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
        The measured run (``sim.loop.RunTrace``).
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
    perturbations : tuple of Perturbation (and ``Hold``)
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
    perturbations: tuple[Perturbation | Hold, ...] = ()
    goal_path: np.ndarray | None = None


class Experiment:
    """Runs fields on ``robot`` for the demos ``demos`` (see module docstring).

    Parameters
    ----------
    robot : RobotModel
        The arm; the actuation is the robot's (``robots.load_robot(..., actuation=...)``,
        ``RobotModel.actuation``).
    demos : DemoSet
        The demonstrations, shape (N, T, d), or poses (module docstring).
    placement : Placement, optional
        Task space -> world (default ``Placement.auto`` with ``plane`` and ``size_m``; for poses
        ``Placement.recorded``, or ``Placement.auto`` when ``size_m`` is given).
    demo_index : int
        The demo whose start and duration the runs take.
    control_hz, ik, gains, feedforward : as ``sim.make_environment``.
    settle_s : float
        Run time after ``time_factor`` times the demo's duration, s.
    time_factor : float
        The run lasts this many times the demo's duration before ``settle_s`` (default 1; a detour
        around obstacles takes longer than the demo did).
    fps : float
        Rate at which the rollouts keep the full qpos for video, frames per simulated second.
    obstacles : sequence of ``lfd.obstacles.Obstacle``
        Task-space obstacles put into the robot's scene (``sim.obstacles.with_obstacles``); moving
        ones move with the run (mocap bodies, ``sim.obstacles.mocap_path``; ``RunTrace.mocap_pos``).
        The field avoids them only if it is built to (``lfd.avoid``).
    clearance : Clearance, None or "auto"
        Whole-arm collision dampers in the IK (``sim.collision``); ``"auto"`` (default): the
        default ``Clearance`` when the scene has obstacles or a table, else none.
    """

    def __init__(self, robot: RobotModel, demos: DemoSet, *, placement: Placement | None = None,
                 plane: str = "auto", size_m: float | None = None, demo_index: int = 0,
                 control_hz: float = 500.0, ik: str = "dls",
                 settle_s: float = 1.5, gains: Gains = Gains(), feedforward: bool = True,
                 fps: float = FPS, obstacles: Sequence[Obstacle] = (),
                 clearance: Clearance | str | None = "auto", time_factor: float = 1.0) -> None:
        if not (isinstance(time_factor, (int, float)) and math.isfinite(time_factor) and 1.0 <= time_factor <= 100.0):
            raise SimError(f"time_factor must be in [1, 100], got {time_factor!r}")
        self.robot, self.demos = robot, demos
        chart = None
        if demos.has_orientation:
            from lfd.pose import PoseChart, chart_demos

            chart = placement.chart if placement is not None and placement.chart is not None else PoseChart.of(demos)
            demos = chart_demos(demos, chart)
            if placement is None:
                placement = Placement.recorded(chart, robot) if size_m is None else \
                    Placement.auto(robot, demos.x, size_m=size_m, chart=chart)
        if placement is not None and (placement.chart is None) != (chart is None):
            raise SimError(f"the placement is for {'poses' if placement.pose else 'positions'}, the demos "
                           f"{demos.name} are {'poses' if chart is not None else 'positions'}")
        #: the demos as task points (chart points for poses), shape (N, T, d)
        self.task_demos = demos
        self.placement = placement or Placement.auto(robot, demos.x, plane=plane, size_m=size_m)
        self.obstacles = tuple(obstacles)
        if self.obstacles:   # the scene holds them; the placement above is the bare robot's
            self.robot = robot = with_obstacles(robot, self.obstacles, self.placement)
        self.rotation_ref = None
        if not robot.planar and chart is None:
            kin = Kinematics(robot)
            kin.update(robot.q_home)
            self.rotation_ref = kin.ee_rotation().copy()
        self.placement.check_reachable(robot, demos.x, rotation=self.rotation_ref)
        if not 0 <= demo_index < demos.n_demos:
            raise SimError(f"demo index {demo_index} out of range: {demos.name} has {demos.n_demos} demos")
        self.demo_index = demo_index
        self.demo_t = demos.t[demo_index] - demos.t[demo_index, 0]
        self.demo_world = self.placement.to_world(demos.x[demo_index])
        self.demo_rotations = self.placement.rotation_to_world(demos.x[demo_index]) if self.placement.pose else None
        self.start = demos.x[demo_index, 0].copy()
        self.duration_s = float(time_factor) * float(self.demo_t[-1]) + settle_s
        if isinstance(clearance, str):
            if clearance != "auto":
                raise SimError(f"clearance must be a Clearance, None or 'auto', not '{clearance}'")
            table = mujoco.mj_name2id(robot.mj_model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM) >= 0
            clearance = Clearance() if (self.obstacles or table) else None
        self.options: dict[str, Any] = dict(control_hz=control_hz, ik=ik, gains=gains, feedforward=feedforward,
                                            clearance=clearance)
        self.physics = ArmPhysics.from_robot(robot)
        self.base = base_position(robot)
        self.fps = float(fps)   # the rollouts record the full qpos at this video frame rate
        self._unperturbed: dict[tuple, tuple[Field, np.ndarray, np.ndarray | None]] = {}

    def simulate(self, field: Field, perturbations: tuple[Perturbation, ...] = (),
                 progress: bool = False, desc: str = "run") -> RunTrace:
        """One closed-loop run of ``field`` with ``perturbations`` (a ``Hold`` among them clamps the arm;
        a phase field runs through ``PhaseLoop``)."""
        holds = [p for p in perturbations if isinstance(p, Hold)]
        rest = tuple(p for p in perturbations if not isinstance(p, Hold))
        self._check_space(field)
        # the goal the run must reach: where a moving goal is at the end of the run
        env = make_environment(self.robot, self.placement, self.start, goal_at(field, self.duration_s),
                               duration_s=self.duration_s, perturbations=rest,
                               rotation_ref=self.rotation_ref, physics=self.physics, **self.options)
        task = env.task
        path = mocap_path(self.robot.mj_model, self.obstacles, self.placement,
                          np.arange(task.n_steps + 1) * task.control_dt)
        if path is not None:
            task.set_mocap_path(path)
        fn: Callable[..., np.ndarray] = field.single_point_evaluator()
        if is_phased(field):
            fn = PhaseLoop(field, task.control_dt, task.start_task - task.schedule.goal_offset_task)
        return execute(env, fn, fps=self.fps, progress=progress, desc=desc, hold=holds[0] if holds else None,
                       timed=is_time_varying(field))

    def check_start(self, perturbations: tuple[Perturbation, ...]) -> None:
        """``PlacementError`` if a run with ``perturbations`` would start out of the arm's reach
        (an offset or turned start), before any field exists."""
        rest = tuple(p for p in perturbations if not isinstance(p, Hold))
        make_environment(self.robot, self.placement, self.start, self.task_demos.goal, duration_s=self.duration_s,
                         perturbations=rest, rotation_ref=self.rotation_ref, physics=self.physics, **self.options)

    def _check_space(self, field: Field) -> None:
        """SimError unless the field lives where the task does (a pose field on this task's chart)."""
        chart, own = getattr(field, "chart", None), self.placement.chart
        if (chart is None) != (own is None):
            kind = "a pose field" if chart is not None else "a position field"
            raise SimError(f"{kind} cannot run on {'poses' if own is not None else 'positions'} "
                           f"({self.demos.name}): train it on these demos")
        if chart is not None and own is not None and not np.allclose(chart.goal_rotation, own.goal_rotation,
                                                                       atol=1e-9):
            raise SimError("the pose field's goal orientation is not this task's: train it on these demos")

    def task_points(self, trace: RunTrace) -> np.ndarray:
        """The run's measured tool poses as task points, shape (K+1, d) (chart points for poses)."""
        if self.placement.pose:
            return self.placement.to_task(trace.ee, trace.ee_rot)
        return self.placement.to_task(trace.ee)

    def reference_task(self, field: Field, trace: RunTrace) -> np.ndarray:
        """x_ref(t_k), shape (K+1, d): the task-space rollout of the (goal-shifted) field from the
        run's measured start, x_ref = dg + Phi_t(x0 - dg) (``lfd.integrate.rk4``; a time-varying
        field is integrated in time, from t = 0)."""
        shift = self._shift(field, trace)
        x0 = self.task_points(trace)[0]
        if is_phased(field):
            x, _ = rk4_phase(field.phase_point_fn(x0 - shift), x0 - shift, trace.t)
            return x + shift
        return rk4(field.single_point_evaluator(), x0 - shift, trace.t, timed=is_time_varying(field)) + shift

    def reference(self, field: Field, trace: RunTrace) -> np.ndarray:
        """p_ref(t_k), shape (K+1, 3): ``reference_task`` mapped to world."""
        return self.placement.to_world(self.reference_task(field, trace))

    def _shift(self, field: Field, ro: RunTrace) -> np.ndarray:
        """The run's constant goal shift dg (``sim.perturbations.GoalShift``), shape (d,), task units:
        its goal minus the field's own goal at the run's end."""
        return ro.goal_task - goal_at(field, self.duration_s)

    def run(self, field: Field, name: str, perturbations: tuple[Perturbation, ...] | None = None,
            seed: int = 0, progress: bool = False) -> RunResult:
        """Run and score scenario ``name`` (its perturbations, or the ones given)."""
        perts = scenario(name, seed, self.placement.pose) if perturbations is None else perturbations
        ro = self.simulate(field, perts, progress, desc=f"{field.learner}/{name}")
        unperturbed = None
        window = ro.push_window_s or ro.hold_window_s
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
        metrics: dict[str, Any] = run_metrics(ro.t, ro.ee, ref, ro.goal_world, self.demo_t, self.demo_world,
                                              unperturbed, ro.push_window_s)
        if self.placement.pose and ro.ee_rot is not None and self.demo_rotations is not None:
            metrics.update(orientation_metrics(ro.t, ro.ee_rot, self.placement.rotation_to_world(ref_task),
                                               self.placement.rotation_to_world(ro.goal_task), self.demo_t,
                                               self.demo_rotations))
        metrics.update(joint_limit_violations=ro.joint_limit_violations, ik_limit_hits=ro.ik_limit_hits,
                       realtime_factor=ro.realtime_factor, control_step_us=ro.control_step_us)
        if ro.phase is not None:
            free_phase = None if window is None or cached is None else cached[2]
            metrics.update(self.phase_metrics(field, ro, window, free_phase))
        if ro.arm_clearance_m is not None and ro.guard_active is not None:
            metrics.update(clearance_metrics(ro.t, ro.arm_clearance_m, ro.guard_active,
                                             metrics["final_goal_error_m"]))
        return RunResult(field.learner, name, ro, ref, metrics, unperturbed, ro.command, tuple(perts),
                         self.goal_path(field, ro))

    def goal_path(self, field: Field, ro: RunTrace) -> np.ndarray | None:
        """Where the goal of ``field`` was at each step of ``ro``, shape (K+1, 3), world m (with the
        run's goal shift dg); None unless the goal moves during the run (``lfd.goal``)."""
        if not is_time_varying(field):
            return None
        shift = self._shift(field, ro)
        path = np.array([goal_at(field, float(t)) for t in ro.t]) + shift
        return None if np.ptp(path, axis=0).max() == 0 else self.placement.to_world(path)

    def command(self, field: Field, ro: RunTrace) -> np.ndarray:
        """The field's command at every control step, shape (K+1, d), task units per second:
        v_k = f(x_k - dg) at the measured x_k (at the recorded phase s_k for a phase field),
        recomputed from the recorded states: a check of ``RunTrace.command``, which the loop records
        as it feeds the controller (before IK)."""
        shift = self._shift(field, ro)
        x = self.task_points(ro) - shift
        if is_phased(field) and ro.phase is not None:
            start = ro.start_task - shift
            phase_fn = field.phase_point_fn(start)
            return np.array([phase_fn(xk, float(sk))[0] for xk, sk in zip(x, ro.phase)])
        fn: Callable[..., np.ndarray] = field.single_point_evaluator()
        if is_time_varying(field):
            return np.array([fn(xk, float(tk)) for xk, tk in zip(x, ro.t)])
        return np.array([fn(xk) for xk in x])

    def phase_metrics(self, field: Field, ro: RunTrace, window: tuple[float, float] | None,
                      free_phase: np.ndarray | None) -> dict[str, Any]:
        """The phase metrics of a run of a phase field (module docstring)."""
        assert is_phased(field) and ro.phase is not None
        shift = self._shift(field, ro)
        x0 = self.task_points(ro)[0] - shift
        path = self.placement.to_world(field.reference(ro.phase, x0) + shift)      # (K+1, 3)
        err = np.linalg.norm(ro.ee - path, axis=1)
        out: dict[str, Any] = {"path_error_m": float(err[-1]), "path_error_max_after_1s_m":
                               float(err[ro.t >= 1.0].max()) if np.any(ro.t >= 1.0) else None,
                               "final_phase": float(ro.phase[-1])}
        if window is not None:
            out["path_recovery_time_s"] = recovery_time(ro.t, err, window, RECOVERY_TOLERANCE_M)
            if free_phase is not None:
                out["phase_lag_s"] = float(np.max(free_phase - ro.phase) * field.duration)
                out["phase_lag_end_s"] = float((free_phase[-1] - ro.phase[-1]) * field.duration)
        if ro.hold_window_s is not None:
            k0, k1 = (int(round(v / (ro.t[1] - ro.t[0]))) for v in ro.hold_window_s)
            out["phase_advance_hold"] = float(ro.phase[k1] - ro.phase[k0])
            out["phase_advance_free"] = float((ro.hold_window_s[1] - ro.hold_window_s[0]) / field.duration)
        return out

    def render(self, result: RunResult | list[RunResult], path: str | os.PathLike, width: int = WIDTH,
               height: int = HEIGHT, fps: float = FPS, progress: bool = False,
               camera: CameraSpec = CameraSpec(), titles: list[str] | None = None) -> int:
        """Write the MP4 of one run, or of several runs side by side (one labelled panel each,
        ``sim.render.render_panels``, ``width`` x ``height`` in all); returns the frame count."""
        results = result if isinstance(result, list) else [result]
        normal = None if self.placement.dim != 2 else self.placement.normal
        names = titles or [f"{r.learner} / {r.scenario}" for r in results]
        panels = [Panel(r.trace, r.reference, name, r.goal_path) for r, name in zip(results, names)]
        return render_panels(self.physics.model.ptr, panels, self.demo_world, path, self.base,
                             self.robot.mj_qpos_adr, normal, width, height, fps, camera, progress=progress,
                             demo_rotations=self.demo_rotations)

    def describe(self) -> dict[str, Any]:
        """The experiment's settings, for the metrics JSON."""
        clearance = self.options["clearance"]
        opts = dict(self.options, gains=dataclasses.asdict(self.options["gains"]),
                    clearance=None if clearance is None else dataclasses.asdict(clearance))
        return {"robot": self.robot.name, "ee_frame": self.robot.ee_frame, "demos": self.demos.name,
                "demo_index": self.demo_index, "duration_s": self.duration_s,
                "placement": self.placement.to_dict(), "actuation": self.robot.actuation, **opts}
