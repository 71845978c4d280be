"""A job's task with objects (``--task pour``): its scene built around the arm, its goal set by where the
user puts the object (``--target``), and each run's success scored from the physics state.

The pour (``sim.scene.pour``): the cup's opening is the tool axis that points up at the demos' mean
start; the demos must tilt it past ``sim.scene.pour.POUR_TILT_DEG`` by their mean end, or there is
no pour to run. The bowl's nominal place is where the demos' mean end pours (``nominal_bowl``).
``--target X,Y[,Z]`` puts the bowl there instead (robot base frame, m; Z, if given, must be the table
top, 0), and the goal follows: the demos' mean end moved by the bowl's offset from its nominal place,
the orientation kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.rotations import quaternion_matrices
from robots import RobotModel
from sim.scene import pour

#: the tasks a job can run
TASKS: tuple[str, ...] = ("pour",)
#: the base's radius on the table, m: a bowl nearer the base's axis would stand inside the arm
BASE_CLEARANCE_M = 0.2
#: a pour whose tool ends further than this from its goal did not reach its pouring pose, m
STOPPED_SHORT_M = 0.005


@dataclass(frozen=True)
class PourTask:
    """A planned pour: the cup's opening ``axis`` (tool frame, (3,)), the ``bowl`` (world, (3,)), its
    ``nominal`` place, the ``goal`` position of the tool (world, (3,)), the motion's end ``motion_end_s``
    (s) and the ``scene``'s sizes."""

    axis: np.ndarray
    bowl: np.ndarray
    nominal: np.ndarray
    goal: np.ndarray
    motion_end_s: float
    scene: pour.PourScene = pour.PourScene()

    def score(self, model: Any, frame_t: np.ndarray, frame_qpos: np.ndarray, goal_error_m: float = 0.0
              ) -> dict[str, Any]:
        """``sim.scene.pour.outcome`` of a run's recorded states, with the bowl's place; a pour that
        missed the bowl while its tool ended more than ``STOPPED_SHORT_M`` from its goal ``stopped short``."""
        out = pour.outcome(model, frame_t, frame_qpos, self.motion_end_s, self.axis, self.scene)
        if out["cause"] == "missed the bowl" and goal_error_m > STOPPED_SHORT_M:
            out["cause"] = "stopped short"
        out["bowl_m"] = self.bowl.tolist()
        return out


def plan_pour(demos: DemoSet, target: tuple[float, ...] | None) -> PourTask:
    """The pour of ``demos`` with its bowl at ``target`` (module docstring); ``ConfigError`` of one line
    for demos without orientation or without a pouring tilt, or a target off the table or in the arm."""
    if not demos.has_orientation:
        raise ConfigError(f"--task pour needs demos of poses (a cup to tilt); {demos.name} are positions")
    assert demos.q is not None and demos.goal_q is not None   # demos with orientation
    axis = pour.cup_axis(quaternion_matrices(demos.q[:, 0]))
    end_rot = quaternion_matrices(demos.goal_q)
    tilt = pour.tilt_deg(end_rot, axis)
    if tilt < pour.POUR_TILT_DEG:
        raise ConfigError(f"--task pour: the demos {demos.name} tilt their cup by {tilt:.0f} deg at their end, "
                          f"not past {pour.POUR_TILT_DEG:g} deg: they do not pour")
    end = np.asarray(demos.goal, dtype=np.float64)[:3]
    nominal = pour.nominal_bowl(end, end_rot, axis)
    bowl = nominal.copy()
    if target is not None:
        t = np.asarray(target, dtype=np.float64)
        if t.shape not in ((2,), (3,)) or not np.isfinite(t).all():
            raise ConfigError(f"--target must be X,Y[,Z], finite, metres in the robot's base frame, got {list(target)}")
        if t.shape == (3,) and abs(t[2]) > 1e-3:
            raise ConfigError(f"--target: the bowl stands on the table (Z = 0), got Z = {t[2]:g} m")
        if np.hypot(t[0], t[1]) < BASE_CLEARANCE_M:
            raise ConfigError(f"--target ({t[0]:g}, {t[1]:g}) m puts the bowl inside the arm's base")
        bowl = np.array([t[0], t[1], 0.0])
    goal = end + (bowl - nominal)
    return PourTask(axis, bowl, nominal, goal, float(demos.t[0, -1]))


def with_scene(robot: RobotModel, task: PourTask) -> RobotModel:
    """``robot`` (loaded with a table) with the pour's objects (``sim.scene.pour.build``)."""
    return pour.build(robot, task.axis, task.bowl, task.scene)
