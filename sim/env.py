"""The dm_env environment of ``sim.make_environment``: dm_control's ``control.Environment`` with a
lean ``step`` for a ``sim.task.FieldTrackingTask``.

``FieldEnvironment.step`` keeps the dm_env API of ``control.Environment`` exactly (the same
``TimeStep``: step type, reward, discount, and the observation ``OrderedDict`` with the keys,
dtypes and shapes of ``observation_spec()``; the same time limit, reset-after-LAST and
``PhysicsError`` on a new MuJoCo warning) and runs the control step of ``sim.loop.execute``:
``mj_step1`` (with ``FieldController.split``), the tool pose, the controller's command and
the step's perturbations (``FieldTrackingTask.apply``), ``mj_step2`` (or ``mj_step`` without the
split), all on the raw ``physics.model.ptr`` / ``physics.data.ptr``; then ``mj_kinematics`` so the
observation (and ``physics.data``) describes the new joints, and the reward and observation from
``FieldTrackingTask.outputs`` (for a position task one compiled pass that writes every observed
value into one fresh array, whose slices are the observation's arrays). Each observation holds
fresh arrays: a later step does not change an observation kept from an earlier one.

Warnings: dm_control raises ``PhysicsError`` for a warning counter that grew during
``Physics.step``; this step compares the counters once a step, with those at the end of the last
step (or the reset), so a warning raised by hand between two steps (a direct ``mj_forward`` in a
bad state) is reported by the next step.

What dm_control's generic step adds and this one leaves out: the second ``mj_step1`` inside
``mj_step`` (the task's ``before_step`` has already run it), ``Physics.step``'s context manager and
its wrapped-array accesses, ``rewards.tolerance`` on numpy scalars and a reduction per action check.

A task whose class overrides one of the hooks the lean step inlines (``before_step``,
``after_step``, ``get_observation``, ``get_reward``, ``get_termination`` is honoured), a physics
class that overrides ``step``, a flat observation or ``legacy_step=True`` fall back to
``control.Environment.step`` unchanged. ``isinstance(env, control.Environment)`` holds, which is
what ``shimmy.DmControlCompatibilityV0`` checks.
"""

from __future__ import annotations

import logging
from typing import Any

import dm_env
import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.rl import control

from sim.task import ArmPhysics, FieldTrackingTask

# the Task hooks the lean step inlines: a subclass that overrides one gets dm_control's generic step
_INLINED = ("before_step", "after_step", "get_observation", "get_reward")
_MID, _LAST = dm_env.StepType.MID, dm_env.StepType.LAST
_step1, _step2, _mj_step, _kinematics = mujoco.mj_step1, mujoco.mj_step2, mujoco.mj_step, mujoco.mj_kinematics
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
        self._qadr: Any = None
        self._q_arm: Any = None
        self._check: Any = None
        self._apply: Any = None
        self._outputs: Any = None

    @property
    def lean(self) -> bool:
        """Whether ``step`` runs the lean path (module docstring), not ``control.Environment.step``."""
        return self._lean

    def _bind(self) -> None:
        """Keep the raw model and data, views of the arrays the step reads, and the step's flags."""
        physics, task = self._physics, self._task
        self._data_wrapper = physics.data
        self._model, self._data = physics.model.ptr, physics.data.ptr
        d = self._data
        self._warnings = d.warning.number   # a view of MuJoCo's warning counters, shape (mjNWARNING,)
        self._warned = self._warnings.tobytes()
        self._warnings_now = self._warnings.tobytes
        self._qpos, self._qadr = d.qpos, task._qadr
        task.bind(d)
        # the arm's q as a view of qpos when contiguous (as sim.loop; read before mj_step2 changes it)
        self._q_arm = task._qpos_arm
        ctl = task.controller
        ctl.bind(d)
        self._split = ctl.split
        # as sim.loop: after mj_step1 the tool pose is MuJoCo's site, else Pinocchio's FK
        self._measure = ctl.measure_site if self._split else ctl.measure
        self._to_task = ctl.to_task if task.placement.pose else None   # a pose twist needs the chart point
        # the task's methods the step calls, bound once (a subclass's overrides included)
        self._check, self._apply, self._outputs = task.check_action, task.apply, task.outputs

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
        m, d = self._model, self._data
        split = self._split
        if split:   # as sim.loop: M(q) and the bias forces at this state
            _step1(m, d)
        q = self._q_arm if self._q_arm is not None else self._qpos[self._qadr]
        p = self._measure(q)
        if self._to_task is not None:
            self._to_task(p)
        self._apply(d, q, None, v, m)
        n_sub = self._n_sub_steps
        if split:
            _step2(m, d)
            if n_sub > 1:
                _mj_step(m, d, n_sub - 1)
        else:
            _mj_step(m, d, n_sub)
        warned = self._warnings_now()
        if warned != self._warned:   # counters only grow between resets: a new warning since the last check
            self._invalid_state(warned)
        _kinematics(m, d)   # the observed tool pose of the new joints (``after_step``)
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
