"""A run's setup, resolved once: the robot's scene, the demos as task points, the placement, the
tool orientation to hold, the start, the goal, the obstacles and the run's length.

``RunSetup.resolve`` is the one place that works these out from the raw inputs (a robot, demos,
placement options); the experiment, the task, the environment and the loop receive the
``RunSetup`` and never derive them again (as dm_control hands a ``Physics`` to its ``Task``).
Demos of poses make a pose task: its task points are the chart points of ``lfd.pose`` (Eq. (P1)
at the goal orientation) and it runs where it was recorded unless a placement is asked for.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.obstacles import Obstacle
from lfd.pose import UNIT_TOLERANCE, PoseChart, chart_demos
from robots import Kinematics, RobotModel
from sim.errors import PlacementError, SimError
from sim.scene.obstacles import with_obstacles
from sim.scene.placement import Placement

#: run time after the demo's duration (times ``time_factor``), s
SETTLE_S = 1.5


@dataclass(frozen=True)
class RunSetup:
    """Everything a run is set up with (module docstring).

    Attributes
    ----------
    robot : RobotModel
        The scene: the arm, with the obstacles as MuJoCo geoms (``sim.scene.obstacles.with_obstacles``).
    demos : DemoSet
        The demonstrations as given (positions, or poses).
    task_demos : DemoSet
        The demos as task points, x of shape (N, T, d) (chart points, d = 6, for poses).
    placement : Placement
        Task space -> world.
    rotation_ref : ndarray, shape (3, 3), or None
        The tool orientation a spatial arm holds on a position task (its orientation at
        ``q_home``); None for a planar arm and for a pose task (the field gives the orientation).
    demo_index : int
        The demo whose start and duration the runs take.
    start, goal : ndarray, shape (d,)
        The run's start (that demo's first sample) and goal (the demos' mean end), task units.
    duration_s : float
        The run's length: ``time_factor`` times the demo's duration plus the settling time, s.
    obstacles : tuple of Obstacle
        Task-space obstacles, in the scene (the field avoids them only if built to: ``lfd.avoid``).
    speed : float
        The runs' speed factor S (``lfd.retime``): the demo the runs are scored against takes 1/S of
        its recorded time (``demo_t``).
    """

    robot: RobotModel
    demos: DemoSet
    task_demos: DemoSet
    placement: Placement
    rotation_ref: np.ndarray | None
    demo_index: int
    start: np.ndarray
    goal: np.ndarray
    duration_s: float
    obstacles: tuple[Obstacle, ...] = ()
    speed: float = 1.0

    @classmethod
    def resolve(cls, robot: RobotModel, demos: DemoSet, *, placement: Placement | None = None,
                plane: str = "auto", size_m: float | None = None, origin: Sequence[float] | None = None,
                scale: float | None = None, shift: Sequence[float] | None = None, recorded: bool = False,
                demo_index: int = 0, obstacles: Sequence[Obstacle] = (), time_factor: float = 1.0,
                settle_s: float = SETTLE_S, goal: Sequence[float] | np.ndarray | None = None) -> RunSetup:
        """Resolve a run's setup (module docstring) and check that the arm reaches the demos.

        Parameters
        ----------
        robot : RobotModel
            The bare arm (the obstacles are added to its scene here).
        demos : DemoSet
            Positions (2-D or 3-D) or poses.
        placement : Placement, optional
            Task space -> world, as given; else from the options below.
        plane, size_m : str and float, optional
            ``Placement.auto``'s plane and path size (m). For poses, ``size_m`` places them
            automatically instead of where they were recorded.
        origin, scale : optional
            The world point (m) the demos' box centre goes to, and metres per task unit (each
            defaults to ``Placement.auto``'s).
        shift : (3,), optional
            Poses where they were recorded, translated by this (m).
        recorded : bool
            3-D positions (or poses) where they were recorded: metres in the robot's base frame.
        demo_index : int
            The demo whose start and duration the runs take.
        obstacles : sequence of Obstacle
            Put into the scene before the reach check.
        time_factor : float
            The run lasts this many times the demo's duration, then ``settle_s``; in [1, 100].
        settle_s : float
            Run time after that, s.
        goal : array, optional
            Run toward this goal instead of the demos' mean end, in the demos' frame: shape (d,) task
            units for positions; for poses the position (3,) or the pose (7,) x, y, z, qw, qx, qy, qz
            (metres, the robot's base frame): the task's chart is then the one at the goal orientation
            (Eq. (P1)), as the fields' run toward it (``Field.toward``). Checked reachable.

        Raises
        ------
        ConfigError, SimError, sim.errors.PlacementError
            Contradicting options, a demo index out of range, or a path out of the arm's reach.
        """
        if not (isinstance(time_factor, (int, float)) and math.isfinite(time_factor) and 1.0 <= time_factor <= 100.0):
            raise SimError(f"time_factor must be in [1, 100], got {time_factor!r}")
        chart = None
        goal_v = None if goal is None else np.asarray(goal, dtype=np.float64).reshape(-1)
        if demos.has_orientation:   # poses run as chart points (lfd.pose)
            chart = placement.chart if placement is not None and placement.chart is not None else PoseChart.of(demos)
            if goal_v is not None and goal_v.shape == (7,):   # the chart at the goal's orientation
                chart = PoseChart.at(_unit_quaternion(goal_v[3:]), chart.length)
            task_demos = chart_demos(demos, chart)
        else:
            task_demos = demos
        goal_task = task_demos.goal.copy() if goal_v is None else _goal_point(goal_v, task_demos, chart)
        if placement is None:
            placement = _placement(robot, task_demos, chart, plane, size_m, origin, scale, shift, recorded)
        if (placement.chart is None) != (chart is None):
            raise SimError(f"the placement is for {'poses' if placement.pose else 'positions'}, the demos "
                           f"{demos.name} are {'poses' if chart is not None else 'positions'}")
        if obstacles:   # the scene holds them; the placement above is the bare robot's
            robot = with_obstacles(robot, obstacles, placement)
        rotation_ref = None
        if not robot.planar and chart is None:
            kin = Kinematics(robot)
            kin.update(robot.q_home)
            rotation_ref = kin.ee_rotation().copy()
        placement.check_reachable(robot, task_demos.x, rotation=rotation_ref)
        if goal_v is not None:
            try:
                placement.check_reachable(robot, goal_task[None], rotation=rotation_ref)
            except PlacementError as e:
                raise PlacementError(f"the goal is out of the arm's reach: {e}") from None
        if not 0 <= demo_index < demos.n_demos:
            raise SimError(f"demo index {demo_index} out of range: {demos.name} has {demos.n_demos} demos")
        t = task_demos.t[demo_index]
        return cls(robot, demos, task_demos, placement, rotation_ref, int(demo_index),
                   task_demos.x[demo_index, 0].copy(), goal_task,
                   float(time_factor) * float(t[-1] - t[0]) + float(settle_s), tuple(obstacles))

    def moved(self, start: np.ndarray | None = None, goal: np.ndarray | None = None,
              duration_s: float | None = None) -> RunSetup:
        """This setup with another start or goal, shape (d,), task units, or run length, s."""
        changes: dict[str, object] = {}
        for name, value in (("start", start), ("goal", goal)):
            if value is not None:
                v = np.asarray(value, dtype=np.float64).reshape(-1)
                if v.shape != (self.dim,) or not np.isfinite(v).all():
                    raise SimError(f"the {name} must be {self.dim} finite task coordinates, got {v.tolist()}")
                changes[name] = v.copy()
        if duration_s is not None:
            if not (math.isfinite(duration_s) and duration_s > 0):
                raise SimError(f"the run length must be positive, got {duration_s}")
            changes["duration_s"] = float(duration_s)
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    def retimed(self, speed: float, settle_s: float = SETTLE_S) -> RunSetup:
        """This setup for a motion run ``speed`` times faster (``lfd.retime``): the part of the run before
        the settling time ``settle_s`` lasts 1/speed as long, and the demo is scored at its re-timed
        times (``demo_t``)."""
        if not (math.isfinite(speed) and speed > 0):
            raise SimError(f"the speed must be a positive factor, got {speed}")
        motion = (self.duration_s - settle_s) * self.speed / speed
        return dataclasses.replace(self, speed=float(speed), duration_s=motion + settle_s)

    @property
    def dim(self) -> int:
        """The task dimension d (6 for a pose task)."""
        return self.placement.dim

    @property
    def pose(self) -> bool:
        """Whether this is a pose task."""
        return self.placement.pose

    @property
    def chart(self) -> PoseChart | None:
        """A pose task's orientation chart (None for positions)."""
        return self.placement.chart

    @property
    def demo_t(self) -> np.ndarray:
        """The run's demo's times from 0 at the runs' speed, shape (T,), s."""
        t = self.task_demos.t[self.demo_index]
        return (t - t[0]) / self.speed

    @property
    def demo_world(self) -> np.ndarray:
        """The run's demo in world, shape (T, 3), m."""
        return self.placement.to_world(self.task_demos.x[self.demo_index])

    @property
    def demo_rotations(self) -> np.ndarray | None:
        """A pose task's demo orientations in world, shape (T, 3, 3); None for positions."""
        return self.placement.tool_rotation(self.task_demos.x[self.demo_index])


def _unit_quaternion(q: np.ndarray) -> np.ndarray:
    """q, shape (4,), (w, x, y, z), normalised; ``ConfigError`` unless it is a rotation."""
    norm = float(np.linalg.norm(q))
    if not (np.isfinite(q).all() and abs(norm - 1.0) <= UNIT_TOLERANCE):
        raise ConfigError(f"the goal's quaternion (w, x, y, z) must have norm 1, got {np.round(q, 4).tolist()}")
    return q / norm


def _goal_point(goal: np.ndarray, task_demos: DemoSet, chart: PoseChart | None) -> np.ndarray:
    """The task point, shape (d,), of a goal given in the demos' frame (``RunSetup.resolve``)."""
    if not np.isfinite(goal).all():
        raise ConfigError(f"the goal must be finite, got {goal.tolist()}")
    if chart is None:
        if goal.shape != (task_demos.dim,):
            raise ConfigError(f"the goal must have {task_demos.dim} coordinates for {task_demos.dim}-D demos, "
                              f"got {goal.shape[0]}")
        return goal.copy()
    if goal.shape not in ((3,), (7,)):
        raise ConfigError(f"a pose goal is X,Y,Z or X,Y,Z,QW,QX,QY,QZ, got {goal.shape[0]} values")
    point = task_demos.goal.copy()   # the demos' goal orientation in the chart (0 at the chart's own)
    point[:3] = goal[:3]
    if goal.shape == (7,):
        point[3:] = 0.0
    return point


def _placement(robot: RobotModel, task_demos: DemoSet, chart: PoseChart | None, plane: str, size_m: float | None,
               origin: Sequence[float] | None, scale: float | None, shift: Sequence[float] | None,
               recorded: bool) -> Placement:
    """The placement the options ask for (``RunSetup.resolve``)."""
    if chart is not None:
        if shift is not None:   # the recorded poses, translated
            return Placement(np.asarray(shift, dtype=np.float64), np.eye(3), 1.0, 6, chart)
        if recorded or (origin is None and scale is None and size_m is None):
            return Placement.recorded(chart, robot)
    else:
        if shift is not None:
            raise ConfigError("--shift is for demos of poses (run where recorded); use --origin for positions")
        if recorded:
            if task_demos.dim != 3:
                raise ConfigError(f"--placement recorded needs 3-D demos, {task_demos.name} are {task_demos.dim}-D")
            return Placement(np.zeros(3), np.eye(3), 1.0, 3)
    auto = Placement.auto(robot, task_demos.x, plane=plane, size_m=size_m, chart=chart)
    if origin is None and scale is None:
        return auto
    lo, hi = task_demos.bounds()
    pd = auto.position_dim
    center = (lo[:pd] + hi[:pd]) / 2
    s = auto.scale if scale is None else float(scale)
    target = auto.to_world(center) if origin is None else np.asarray(origin, dtype=np.float64)
    return Placement(target - s * auto.axes @ center, auto.rotation, s, auto.dim, chart)
