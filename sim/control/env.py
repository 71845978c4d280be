"""The dm_env environment: ``make_environment`` and ``FieldEnvironment``, dm_control's
``control.Environment`` with a lean ``step`` for a ``sim.control.task.FieldTrackingTask``.

``FieldEnvironment.step`` keeps the dm_env API of ``control.Environment`` exactly (the same
``TimeStep``: step type, reward, discount, and the observation ``OrderedDict`` with the keys,
dtypes and shapes of ``observation_spec()``; the same time limit, reset-after-LAST and
``PhysicsError`` on a new MuJoCo warning) and runs the task's control step (``sim.control.step.ControlStep``,
the loop's own: ``begin``, ``command``, ``end``) on the raw MuJoCo model and data; then
``mj_kinematics`` so the observation describes the new joints, and the reward and observation
from ``FieldTrackingTask.outputs`` (for a position task one compiled pass into one fresh array).
Each observation holds fresh arrays: a later step does not change an observation kept earlier.

Warnings are compared once a step with those at the end of the last step (or the reset). A task
class that overrides a hook the lean step inlines (``before_step``, ``after_step``,
``get_observation``, ``get_reward``), a physics class that overrides ``step``, a flat observation
or ``legacy_step=True`` get ``control.Environment.step`` unchanged. ``isinstance(env,
control.Environment)`` holds, which is what ``shimmy.DmControlCompatibilityV0`` checks.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import dm_env
import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.rl import control

from lfd.demos import DemoSet, load_demos
from lfd.field import Field
from robots import RobotModel, load_robot
from robots.limits import Limits
from sim.control.controller import Gains
from sim.control.object_task import ObjectTask, SuccessCheck
from sim.control.task import ArmPhysics, FieldTrackingTask
from sim.errors import SimError
from sim.scene.collision import Clearance
from sim.scene.perturbations import Perturbation
from sim.scene.setup import SETTLE_S, RunSetup

# the Task hooks the lean step inlines: a subclass that overrides one gets dm_control's generic step
_INLINED = ("before_step", "after_step", "get_observation", "get_reward")
_MID, _LAST = dm_env.StepType.MID, dm_env.StepType.LAST
_kinematics = mujoco.mj_kinematics
# TimeStep(...) through its NamedTuple __new__ costs more than the tuple's own constructor
_new_tuple = tuple.__new__
_log = logging.getLogger(__name__)


class FieldEnvironment(control.Environment):
    """``control.Environment`` with the lean step of the module docstring.

    Parameters
    ----------
    physics : ArmPhysics
        The robot's MuJoCo physics.
    task : FieldTrackingTask
        The task (another ``control.Task`` gets the generic step).
    time_limit : float
        Episode length, s.
    control_timestep : float, optional
        The control period, s, an integer multiple of the physics timestep.
    n_sub_steps : int, optional
        Physics steps per control step, instead of ``control_timestep``.
    flat_observation : bool
        As ``control.Environment`` (then the generic step).
    legacy_step : bool
        As ``control.Environment``; the lean step needs ``False`` (a plain ``mj_step`` per physics
        step, ``make_environment``'s choice), else the generic step.
    """

    # control.Environment's own state, which the lean step reads and advances as its step does
    _reset_next_step: bool
    _step_count: int
    _step_limit: float
    _n_sub_steps: int

    def __init__(self, physics: ArmPhysics, task: control.Task, time_limit: float = float("inf"),
                 control_timestep: float | None = None, n_sub_steps: int | None = None,
                 flat_observation: bool = False, legacy_step: bool = False) -> None:
        super().__init__(physics, task, time_limit=time_limit, control_timestep=control_timestep,
                         n_sub_steps=n_sub_steps, flat_observation=flat_observation, legacy_step=legacy_step)
        cls = type(task)
        self._lean = (isinstance(task, FieldTrackingTask) and not flat_observation and not legacy_step
                      and all(getattr(cls, h) is getattr(FieldTrackingTask, h) for h in _INLINED)
                      and type(physics).step is dm_mujoco.Physics.step)
        self._terminates = cls.get_termination is not control.Task.get_termination
        self._data: Any = None
        self._data_wrapper: Any = None
        self._warned = b""
        self._warnings_now: Any = None
        self._check: Any = None
        self._step: Any = None
        self._outputs: Any = None

    @property
    def lean(self) -> bool:
        """Whether ``step`` runs the lean path (module docstring), not ``control.Environment.step``."""
        return self._lean

    def _bind(self) -> None:
        """Keep the raw model and data, the warning counters and the task's control step, bound."""
        physics, task = self._physics, self._task
        self._data_wrapper = physics.data
        self._model, self._data = physics.model.ptr, physics.data.ptr
        self._warnings = self._data.warning.number   # a view of MuJoCo's warning counters, (mjNWARNING,)
        self._warned = self._warnings.tobytes()
        self._warnings_now = self._warnings.tobytes
        task.bind(self._data)
        task.step.bind(self._model, self._data)
        # the task's methods the step calls, bound once (a subclass's overrides included)
        self._check, self._step, self._outputs = task.check_action, task.step, task.outputs

    def reset(self) -> dm_env.TimeStep:
        """Start a new episode (``control.Environment.reset``) and bind the raw MuJoCo arrays."""
        ts = super().reset()
        if self._lean:
            self._bind()
        return ts

    def step(self, action: Any) -> dm_env.TimeStep:
        """One control step with ``action``, the tool velocity, shape (d,), task units/s.

        Parameters
        ----------
        action : array_like, shape (d,)
            Checked and clipped as ``FieldTrackingTask.check_action``.

        Returns
        -------
        dm_env.TimeStep
            As ``control.Environment.step`` (the first step of an episode, and the step after a
            LAST one, reset the environment and return its FIRST time step).

        Raises
        ------
        dm_control.rl.control.PhysicsError
            A MuJoCo warning during the step (unless inside ``physics.suppress_physics_errors()``).
        SimError
            An action of the wrong shape, non-numeric or not finite.
        """
        if self._reset_next_step:
            return self.reset()
        if not self._lean:
            return super().step(action)
        if self._physics.data is not self._data_wrapper:   # the physics' data was replaced since the reset
            self._bind()
        v = self._check(action)
        step = self._step
        step.begin()
        step.command(v)
        step.end()
        warned = self._warnings_now()
        if warned != self._warned:   # counters only grow between resets: a new warning since the last check
            self._invalid_state(warned)
        _kinematics(self._model, self._data)   # the observed tool pose of the new joints (``after_step``)
        reward, observation = self._outputs()
        self._step_count += 1
        if self._step_count >= self._step_limit:
            discount = 1.0
        elif self._terminates:
            discount = self._task.get_termination(self._physics)
        else:
            return _new_tuple(dm_env.TimeStep, (_MID, reward, 1.0, observation))
        if discount is None:
            return _new_tuple(dm_env.TimeStep, (_MID, reward, 1.0, observation))
        self._reset_next_step = True
        return _new_tuple(dm_env.TimeStep, (_LAST, reward, discount, observation))

    def _invalid_state(self, warned: bytes) -> None:
        """``dm_control.mujoco.Physics.check_invalid_state`` for MuJoCo's warning counters, now
        ``warned`` (``tobytes``), against those of the last check: ``PhysicsError`` naming the new
        warnings, or a logged warning inside ``physics.suppress_physics_errors()``."""
        dtype = self._warnings.dtype
        new = np.greater(np.frombuffer(warned, dtype=dtype), np.frombuffer(self._warned, dtype=dtype))
        self._warned = warned
        if not new.any():   # counters reset by hand (mj_resetData) since the last check: nothing new
            return
        names = np.compress(new, list(mujoco.mjtWarning.__members__))
        message = f"Physics state is invalid. Warning(s) raised: {', '.join(names)}"
        if getattr(self._physics, "_warnings_cause_exception", True):
            raise control.PhysicsError(message)
        _log.warning(message)


def _control_dt(control_hz: float, timestep: float) -> float:
    """The control period, s: an integer number of physics steps (else ``SimError``)."""
    if not control_hz > 0:
        raise SimError(f"control rate must be positive, got {control_hz}")
    n_sub = (1.0 / control_hz) / timestep
    if n_sub < 1 - 1e-9 or abs(n_sub - round(n_sub)) > 1e-6:
        raise SimError(f"control rate {control_hz:g} Hz must divide the physics rate {1 / timestep:g} Hz")
    return round(n_sub) * timestep


def _robot(robot: str | RobotModel, actuation: str | None) -> RobotModel:
    """A robot name loaded with ``actuation`` (default ``torque``), or a loaded robot, whose own
    actuation ``actuation`` (if given) must be."""
    if isinstance(robot, str):
        return load_robot(robot, actuation=actuation or "torque")
    if actuation is not None and actuation != robot.actuation:
        raise SimError(f"robot '{robot.name}' was loaded with actuation='{robot.actuation}', not '{actuation}'")
    return robot


def make_environment(robot: str | RobotModel | RunSetup, demos: str | DemoSet | None = None, *,
                     learner_field: Field | None = None, seed: int | None = None, start_radius: float = 0.0,
                     demo_index: int = 0, control_hz: float = 500.0, duration_s: float | None = None,
                     settle_s: float = SETTLE_S, ik: str = "dls", actuation: str | None = None,
                     perturbations: Sequence[Perturbation] = (), gains: Gains = Gains(),
                     feedforward: bool = True, physics: ArmPhysics | None = None, dynamics: str = "mujoco",
                     clearance: Clearance | None = None, goal: np.ndarray | None = None,
                     limiter: bool = False, limits: Limits | None = None,
                     on_reset: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None,
                     success: SuccessCheck | None = None) -> FieldEnvironment:
    """A dm_control Environment of the arm following task velocities (``sim.control.task``), whose ``step``
    is the lean one of the module docstring.

    One call from names::

        env = sim.make_environment("panda", demos="spiral", learner_field=None, seed=0)

    Parameters
    ----------
    robot : str, RobotModel or RunSetup
        A built-in name (``planar``, ``panda``), loaded with ``actuation`` (default ``torque``), or
        a loaded robot (its own actuation; another ``actuation``: ``SimError``); both resolve the
        setup from ``demos`` (``RunSetup.resolve``: auto placement, demo ``demo_index``'s start,
        the demos' goal). Or a resolved ``RunSetup``, used as it is.
    demos : str or DemoSet, optional
        A demo SPEC (``spiral``, ``lasa:Angle``, a file; ``lfd.load_demos``) or a DemoSet; needed
        unless ``robot`` is a RunSetup.
    learner_field : Field, optional
        Adds the ``field_velocity`` observation (the action ``sim.control.loop.execute`` would take); the
        goal is then where the field's goal is at the run's end (a moving goal, ``lfd.goal``).
    seed, start_radius : random initial states: with ``start_radius`` > 0 (task units) each
        episode starts uniformly in that ball around the start, drawn from ``seed``.
    duration_s : float, optional
        Episode length, s (default: the setup's, the demo's duration plus ``settle_s``).
    control_hz : the control rate, an integer divisor of the physics rate (a rate above the physics
        rate sets the physics step of ``physics`` to the control step).
    physics : an ``ArmPhysics.from_robot(setup.robot)`` to reuse one compiled model.
    dynamics : computed torque from MuJoCo's M(q) and bias forces (``mujoco``) or Pinocchio's RNEA.
    clearance : whole-arm collision dampers in the IK (``sim.scene.collision``; default None: none).
    goal : array, optional
        Run toward this goal, in the demos' frame (``RunSetup.resolve``): the ``goal`` observation,
        and ``learner_field.toward(goal)`` for ``field_velocity``. A position task takes a new goal
        for each later episode from ``env.task.set_goal`` (read at the reset).
    on_reset : the scene's objects placed at each episode's start (``FieldTrackingTask``).
    success : a task's success predicate: the reward is it, and the episode ends where it holds
        (``sim.control.object_task.ObjectTask``).
    limiter, limits : control through ``robots.controller.ArmController`` and its jerk-limited limiter,
        within ``limits`` (default the robot's; ``FieldTrackingTask``).
    Others as ``sim.control.task.FieldTrackingTask`` and ``sim.control.controller.FieldController``.
    """
    if isinstance(robot, RunSetup):
        setup = robot
        if goal is not None:
            raise SimError("a resolved RunSetup brings its goal: give the goal to RunSetup.resolve")
        if actuation is not None and actuation != setup.robot.actuation:
            raise SimError(f"robot '{setup.robot.name}' was loaded with actuation='{setup.robot.actuation}', "
                           f"not '{actuation}'")
    else:
        if demos is None:
            raise SimError("make_environment needs demos (a spec or a DemoSet), or a resolved RunSetup")
        demo_set = load_demos(demos) if isinstance(demos, str) else demos
        setup = RunSetup.resolve(_robot(robot, actuation), demo_set, demo_index=demo_index, settle_s=settle_s,
                                 goal=goal)
    if duration_s is not None:
        setup = setup.moved(duration_s=duration_s)
    if learner_field is not None and learner_field.dim != setup.dim:
        raise SimError(f"the field is {learner_field.dim}-D but the placement is {setup.dim}-D")
    if goal is not None and learner_field is not None:
        learner_field = learner_field.toward(np.asarray(goal, dtype=np.float64))
    target = None if learner_field is None else learner_field.goal_at(setup.duration_s)
    physics = ArmPhysics.from_robot(setup.robot) if physics is None else physics
    if control_hz > 0 and 1.0 / control_hz < physics.model.opt.timestep - 1e-12:
        physics.model.opt.timestep = 1.0 / control_hz   # a control rate above the physics rate: physics at it
    control_dt = _control_dt(control_hz, physics.model.opt.timestep)
    options: dict[str, Any] = dict(
        goal=target, ik=ik, perturbations=perturbations, gains=gains, feedforward=feedforward,
        mj_model=physics.model.ptr, start_radius=start_radius, seed=seed, field=learner_field, dynamics=dynamics,
        clearance=clearance, limiter=limiter, limits=limits, on_reset=on_reset)
    task = FieldTrackingTask(setup, control_dt, **options) if success is None else \
        ObjectTask(setup, control_dt, success=success, **options)
    return FieldEnvironment(physics, task, time_limit=setup.duration_s, control_timestep=control_dt,
                            legacy_step=False)
