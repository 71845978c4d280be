"""A task with objects as a dm_env task: ``FieldTrackingTask`` whose reward is the scene's success
predicate and whose episode ends on success (dm_control's ``ball_in_cup`` is the pattern: a scene, a
predicate read from the physics state, a task whose reward is it).

The predicate (``SuccessCheck``: ``sim.scene.pour.PourCheck``, ``sim.scene.place.PlaceCheck``) is
evaluated on the state after each step: the reward is 1.0 where it holds and 0.0 elsewhere, and the
first step where it holds is the episode's last (discount 0: nothing follows a success; at the time
limit dm_control's discount 1 stands). The observation, the action and the control step (the lean one
of ``sim.control.env``) are the tracking task's.
"""

from __future__ import annotations

import collections
from typing import Any, Protocol

import mujoco

from sim.control.task import ArmPhysics, FieldTrackingTask


class SuccessCheck(Protocol):
    """A task's success predicate on a simulation's current state."""

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Forget the last episode (at each episode's start, the objects placed)."""

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> bool:
        """Whether the task is done in the state of ``data`` (its kinematics computed)."""


class ObjectTask(FieldTrackingTask):
    """``FieldTrackingTask`` rewarded by ``success`` (module docstring); the other arguments are the
    tracking task's."""

    def __init__(self, *args: Any, success: SuccessCheck, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.success = success
        self.done = False

    def initialize_episode(self, physics: ArmPhysics) -> None:
        super().initialize_episode(physics)
        self.success.reset(physics.model.ptr, physics.data.ptr)
        self.done = False

    def outputs(self) -> tuple[float, collections.OrderedDict]:
        """The predicate's reward (1.0 or 0.0) and the tracking task's observation."""
        _, obs = super().outputs()
        self.done = bool(self.success(self.step.model, self.step.data))
        return float(self.done), obs

    def reward_now(self) -> float:
        """1.0 where the predicate holds at the bound state (``bind``), else 0.0 (what ``get_reward`` returns)."""
        self.done = bool(self.success(self.step.model, self.step.data))
        return float(self.done)

    def get_termination(self, physics: ArmPhysics) -> float | None:
        """0.0 (the episode ends, nothing follows) once the task is done, else None."""
        return 0.0 if self.done else None
