"""A job's task with objects (``--task pour|place``): its scene built around the arm, its goal set by
where the user puts the object (``--target``), and each run's success scored from the physics state.

The pour (``sim.scene.pour``): the cup's opening is the tool axis that points up at the demos' mean
start; the demos must tilt it past ``sim.scene.pour.POUR_TILT_DEG`` by their mean end, or there is
no pour to run. The bowl's nominal place is where the demos' mean end pours (``nominal_bowl``).

The placement (``sim.scene.place``): the bottle's axis is the tool direction that is straight up at
the demos' mean end; its nominal spot is under the bottle there (``nominal_spot``), the shelf's top
just below it; the grip opens when the motion ends (the demos' duration, a ``Release``).

The lid (``sim.scene.lid``): the box's hinge is fitted to the demos' mean path (a circle about it);
the demos must swing through ``sim.scene.lid.OPEN_DEG`` on it. The box stays where it was recorded.

``--target X,Y[,Z]`` puts the object there instead (robot base frame, m): the bowl's centre on the
table (Z, if given, must be the table top, 0), or the bottle's spot on the shelf (Z, if given, the
shelf's top). The goal follows: the demos' mean end moved by the object's offset from its nominal
place, the orientation kept.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Self, cast

import mujoco
import numpy as np

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.rotations import quaternion_matrices
from robots import RobotModel
from sim.scene import lid, place, pour
from sim.scene.perturbations import Perturbation, Release

#: the tasks a job can run, and the demos each runs by default (RoboTasks9's recorded ones)
TASKS: tuple[str, ...] = ("pour", "place", "lid")
TASK_DEMOS: dict[str, str] = {"pour": "robottasks:pouring", "place": "robottasks:bottle2shelf",
                              "lid": "robottasks:openbox"}
#: a lid's fitted circle may miss the demos' mean path by this share of its radius (RMS)
LID_FIT = 0.1
#: where a task runs its default demos moved (``--shift``), m: openbox's recorded end lies just beyond the
#: Panda's reach in its tool frame (reports/robottasks_arm.md)
TASK_SHIFTS: dict[str, tuple[float, float, float]] = {"lid": (0.0, 0.02, -0.02)}
#: the base's radius on the table, m: an object nearer the base's axis would stand inside the arm
BASE_CLEARANCE_M = 0.2
#: a task whose tool ends further than this from its goal did not reach its pose, m
STOPPED_SHORT_M = 0.005
#: the highest shelf, m (the Panda reaches about 1.2 m above its base)
MAX_SHELF_M = 1.0


class _Timed:
    """What every planned task shares: the motion's end ``motion_end_s`` (s), re-timed for the run."""

    motion_end_s: float

    def timed(self, motion_end_s: float) -> Self:
        """The same task with the motion ending at ``motion_end_s`` (the run's demo at its speed)."""
        return dataclasses.replace(cast(Any, self), motion_end_s=float(motion_end_s))


@dataclass(frozen=True)
class PourTask(_Timed):
    """A planned pour: the cup's opening ``axis`` (tool frame, (3,)), the ``bowl`` (world, (3,)), its
    ``nominal`` place, the ``goal`` position of the tool (world, (3,)), the motion's end ``motion_end_s``
    (s) and the ``scene``'s sizes."""

    axis: np.ndarray
    bowl: np.ndarray
    nominal: np.ndarray
    goal: np.ndarray
    motion_end_s: float
    scene: pour.PourScene = pour.PourScene()
    name = "pour"



    def with_scene(self, robot: RobotModel) -> RobotModel:
        """``robot`` (loaded with a table) with the pour's objects (``sim.scene.pour.build``)."""
        return pour.build(robot, self.axis, self.bowl, self.scene)

    def on_reset(self, robot: RobotModel) -> Callable[[mujoco.MjModel, mujoco.MjData], None]:
        """The objects placed at each episode's start: the balls in the cup."""
        return functools.partial(pour.place_balls, scene=self.scene)

    def events(self) -> tuple[Perturbation, ...]:
        """The scene's events of every run: none."""
        return ()

    def check(self, model: mujoco.MjModel, robot: RobotModel) -> pour.PourCheck:
        """The online predicate on ``model`` (the scene of ``with_scene``): a dm_env task's reward."""
        return pour.PourCheck(model, self.scene)

    def score(self, model: Any, robot: RobotModel, frame_t: np.ndarray, frame_qpos: np.ndarray,
              goal_error_m: float = 0.0) -> dict[str, Any]:
        """``sim.scene.pour.outcome`` of a run's recorded states, with the bowl's place; a pour that
        missed the bowl while its tool ended more than ``STOPPED_SHORT_M`` from its goal ``stopped short``."""
        out = pour.outcome(model, frame_t, frame_qpos, self.motion_end_s, self.axis, self.scene)
        if out["cause"] == "missed the bowl" and goal_error_m > STOPPED_SHORT_M:
            out["cause"] = "stopped short"
        out.update(task=self.name, in_target=out["in_bowl"], total=self.scene.n_balls, bowl_m=self.bowl.tolist(),
                   summary=f"{out['in_bowl']} of {self.scene.n_balls} in the bowl")
        return out


@dataclass(frozen=True)
class PlaceTask(_Timed):
    """A planned placement: the bottle's ``axis`` (tool frame, (3,)), its ``spot`` (world, (3,)), the
    ``nominal`` spot, the tool's ``goal`` position (world, (3,)), the release ``motion_end_s`` (s) and
    the ``scene``'s sizes."""

    axis: np.ndarray
    spot: np.ndarray
    nominal: np.ndarray
    goal: np.ndarray
    motion_end_s: float
    scene: place.PlaceScene = place.PlaceScene()
    name = "place"



    def with_scene(self, robot: RobotModel) -> RobotModel:
        """``robot`` (loaded with a table) with the bottle and the shelf (``sim.scene.place.build``)."""
        return place.build(robot, self.axis, self.spot, self.scene)

    def on_reset(self, robot: RobotModel) -> Callable[[mujoco.MjModel, mujoco.MjData], None]:
        """The objects placed at each episode's start: the bottle in the hand, gripped."""
        return functools.partial(place.hold_bottle, robot, self.axis, scene=self.scene)

    def events(self) -> tuple[Perturbation, ...]:
        """The scene's events of every run: the grip opens when the motion ends."""
        return (Release(start_s=self.motion_end_s, equality=place.GRIP),)

    def check(self, model: mujoco.MjModel, robot: RobotModel) -> place.PlaceCheck:
        """The online predicate on ``model`` (the scene of ``with_scene``): a dm_env task's reward."""
        return place.PlaceCheck(model, robot, self.axis, self.spot, self.scene)

    def score(self, model: Any, robot: RobotModel, frame_t: np.ndarray, frame_qpos: np.ndarray,
              goal_error_m: float = 0.0) -> dict[str, Any]:
        """``sim.scene.place.outcome`` of a run's recorded states, with the spot; a placement that
        failed (not by a collision) while its tool ended more than ``STOPPED_SHORT_M`` from its goal
        ``stopped short``."""
        out = place.outcome(model, robot, frame_t, frame_qpos, self.motion_end_s, self.axis, self.spot, self.scene)
        if out["cause"] in ("missed the spot", "toppled") and goal_error_m > STOPPED_SHORT_M:
            out["cause"] = "stopped short"
        standing = out["on_shelf"] and out["tilt_deg"] <= place.UPRIGHT_DEG and out["off_spot_m"] <= place.SPOT_M
        out.update(task=self.name, in_target=int(standing), total=1, spot_m=self.spot.tolist(),
                   summary=f"the bottle {out['off_spot_m'] * 1e3:.0f} mm from its spot, tilted "
                   f"{out['tilt_deg']:.0f} deg" + ("" if out["on_shelf"] else ", off the shelf"))
        return out


@dataclass(frozen=True)
class LidTask(_Timed):
    """A planned opening: the fitted ``hinge`` (world, (3,)), its unit ``axis`` (3,), the lid's ``length``
    (m), the demos' mean ``start`` (3,) (where the closed lid points), the tool's ``goal`` position
    (world, (3,)), the motion's end ``motion_end_s`` (s) and the ``scene``'s sizes."""

    hinge: np.ndarray
    axis: np.ndarray
    length: float
    start: np.ndarray
    goal: np.ndarray
    motion_end_s: float
    scene: lid.LidScene = lid.LidScene()
    name = "lid"


    @property
    def nominal(self) -> np.ndarray:
        """The hinge: the box stays where it was recorded."""
        return self.hinge


    def with_scene(self, robot: RobotModel) -> RobotModel:
        """``robot`` (loaded with a table) with the box and its lid (``sim.scene.lid.build``)."""
        return lid.build(robot, self.hinge, self.axis, self.length, self.start, self.scene)

    def moved(self, offset: np.ndarray) -> LidTask:
        """The same task with its box moved by ``offset`` (3,), m (its demos run shifted, ``--shift``)."""
        return dataclasses.replace(self, hinge=self.hinge + offset, start=self.start + offset)

    def on_reset(self, robot: RobotModel) -> Callable[[mujoco.MjModel, mujoco.MjData], None]:
        """The objects placed at each episode's start: the lid and its handle where the hand is, gripped."""
        return functools.partial(lid.hold_lid, scene=self.scene)

    def events(self) -> tuple[Perturbation, ...]:
        """The scene's events of every run: none (the hand keeps the handle)."""
        return ()

    def check(self, model: mujoco.MjModel, robot: RobotModel) -> lid.LidCheck:
        """The online predicate on ``model`` (the scene of ``with_scene``): a dm_env task's reward."""
        return lid.LidCheck(model, self.scene)

    def score(self, model: Any, robot: RobotModel, frame_t: np.ndarray, frame_qpos: np.ndarray,
              goal_error_m: float = 0.0) -> dict[str, Any]:
        """``sim.scene.lid.outcome`` of a run's recorded states; a lid not opened while the tool ended
        more than ``STOPPED_SHORT_M`` from its goal ``stopped short``."""
        out = lid.outcome(model, frame_t, frame_qpos, self.motion_end_s, self.scene)
        if out["cause"] == "not opened" and goal_error_m > STOPPED_SHORT_M:
            out["cause"] = "stopped short"
        out.update(task=self.name, in_target=int(out["success"]), total=1, hinge_m=self.hinge.tolist(),
                   summary=f"the lid opened {out['angle_deg']:.0f} deg" + ("" if not out["slid_out"] else
                                                                          ", its handle slid out of the hand"))
        return out


Task = PourTask | PlaceTask | LidTask


def _target(target: tuple[float, ...], what: str) -> np.ndarray:
    """``--target`` as an array of 2 or 3 finite numbers, clear of the arm's base; ``ConfigError`` if not."""
    t = np.asarray(target, dtype=np.float64)
    if t.shape not in ((2,), (3,)) or not np.isfinite(t).all():
        raise ConfigError(f"--target must be X,Y[,Z], finite, metres in the robot's base frame, got {list(target)}")
    if np.hypot(t[0], t[1]) < BASE_CLEARANCE_M:
        raise ConfigError(f"--target ({t[0]:g}, {t[1]:g}) m puts the {what} inside the arm's base")
    return t


def _ends(demos: DemoSet, task: str) -> tuple[np.ndarray, np.ndarray]:
    """The demos' mean end position (3,) and rotation (3, 3); ``ConfigError`` for position demos."""
    if not demos.has_orientation:
        raise ConfigError(f"--task {task} needs demos of poses (an object to turn); {demos.name} are positions")
    assert demos.goal_q is not None   # demos with orientation
    return np.asarray(demos.goal, dtype=np.float64)[:3], quaternion_matrices(demos.goal_q)


def plan_pour(demos: DemoSet, target: tuple[float, ...] | None) -> PourTask:
    """The pour of ``demos`` with its bowl at ``target`` (module docstring); ``ConfigError`` of one line
    for demos without orientation or without a pouring tilt, or a target off the table or in the arm."""
    end, end_rot = _ends(demos, "pour")
    assert demos.q is not None
    axis = pour.cup_axis(quaternion_matrices(demos.q[:, 0]))
    tilt = pour.tilt_deg(end_rot, axis)
    if tilt < pour.POUR_TILT_DEG:
        raise ConfigError(f"--task pour: the demos {demos.name} tilt their cup by {tilt:.0f} deg at their end, "
                          f"not past {pour.POUR_TILT_DEG:g} deg: they do not pour")
    nominal = pour.nominal_bowl(end, end_rot, axis)
    bowl = nominal.copy()
    if target is not None:
        t = _target(target, "bowl")
        if t.shape == (3,) and abs(t[2]) > 1e-3:
            raise ConfigError(f"--target: the bowl stands on the table (Z = 0), got Z = {t[2]:g} m")
        bowl = np.array([t[0], t[1], 0.0])
    return PourTask(axis, bowl, nominal, end + (bowl - nominal), float(demos.t[0, -1] - demos.t[0, 0]))


def plan_place(demos: DemoSet, target: tuple[float, ...] | None) -> PlaceTask:
    """The placement of ``demos`` with its spot at ``target`` (module docstring); ``ConfigError`` of one
    line for demos without orientation, a spot in the arm, or a shelf under the table or out of reach."""
    end, end_rot = _ends(demos, "place")
    scene = place.PlaceScene()
    axis = place.bottle_axis(end_rot)
    nominal = place.nominal_spot(end, end_rot, axis, scene)
    spot = nominal.copy()
    if target is not None:
        t = _target(target, "shelf")
        spot = np.array([t[0], t[1], nominal[2] if t.shape == (2,) else t[2] + scene.drop])
    if not scene.board < spot[2] - scene.drop <= MAX_SHELF_M:
        raise ConfigError(f"the shelf's top at {spot[2] - scene.drop:.3f} m is not between the board's "
                          f"{scene.board:g} m above the table and {MAX_SHELF_M:g} m")
    return PlaceTask(axis, spot, nominal, end + (spot - nominal), float(demos.t[0, -1] - demos.t[0, 0]), scene)


def plan_lid(demos: DemoSet, target: tuple[float, ...] | None) -> LidTask:
    """The opening of ``demos`` (module docstring); ``ConfigError`` of one line for demos that are not
    poses, that do not swing on a circle through ``sim.scene.lid.OPEN_DEG``, or a ``target``."""
    if target is not None:
        raise ConfigError("--target: the lid's box stays where it was recorded (its hinge is fitted to the "
                          "demos); leave out --target")
    _ends(demos, "lid")   # poses, in the robot's base frame
    path = demos.x.mean(axis=0)
    hinge, axis, length = lid.fit_hinge(path)
    flat = path - hinge - np.outer((path - hinge) @ axis, axis)
    miss = float(np.sqrt(np.mean((np.linalg.norm(flat, axis=1) - length) ** 2)))
    a, b = flat[0] / np.linalg.norm(flat[0]), flat[-1] / np.linalg.norm(flat[-1])
    swing = float(np.degrees(np.arctan2(np.cross(a, b) @ axis, a @ b)))
    if not (np.isfinite([miss, swing, length]).all() and length > 0 and miss <= LID_FIT * length
            and swing >= lid.OPEN_DEG):
        raise ConfigError(f"--task lid: the demos {demos.name} do not swing a lid open: they turn {swing:.0f} deg "
                          f"on the best circle (radius {length:.3f} m, missed by {miss * 1e3:.0f} mm RMS), not past "
                          f"{lid.OPEN_DEG:g} deg on one")
    return LidTask(hinge, axis, length, path[0].copy(), np.asarray(demos.goal, dtype=np.float64)[:3],
                   float(demos.t[0, -1] - demos.t[0, 0]))


def shifted(task: Task, demos: str, shift: tuple[float, float, float] | None
            ) -> tuple[Task, tuple[float, float, float] | None]:
    """The task and the demos' shift (``--shift``) it runs with: a lid's box moves with its demos (by
    ``TASK_SHIFTS`` for its default demos unless a shift is given); a pour or a placement takes none."""
    if isinstance(task, LidTask):
        shift = shift or (TASK_SHIFTS["lid"] if demos == TASK_DEMOS["lid"] else None)
        return (task if shift is None else task.moved(np.asarray(shift, dtype=np.float64))), shift
    if shift is not None:
        raise ConfigError(f"--shift: the {task.name} puts its objects in the robot's base frame (--target); "
                          "leave out --shift")
    return task, None


def plan_task(name: str, demos: DemoSet, target: tuple[float, ...] | None) -> Task:
    """The task ``name`` (``TASKS``) of ``demos`` with its object at ``target``."""
    if name == "pour":
        return plan_pour(demos, target)
    if name == "place":
        return plan_place(demos, target)
    if name == "lid":
        return plan_lid(demos, target)
    raise ConfigError(f"unknown task '{name}'; known: {', '.join(TASKS)}")
