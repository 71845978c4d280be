"""Placement: where the task space (the demos' 2-D or 3-D user coordinates) lies on the robot.

A task point x, shape (d,), maps to the world point

    p = o + s A x,          A = R[:, :d]  (the first d task axes in world coordinates)

and back by x = A^T (p - o) / s (exact on the task plane; the normal component is dropped).
A task velocity v maps to the world velocity s A v. For d = 2 the plane normal is n = R[:, 2].

Default plane for a 2-D path on the Panda: horizontal, through the tool point at ``q_home``
(tool pointing down, held constant).

A pose task (a field on poses, ``lfd.pose``) has d = 6: x = (position, l log(R_g^T R)), the chart
point of Eq. (P1) at the field's ``PoseChart``. Its positions map as above (A = R, 3 x 3) and its
orientations by R_world = R R_task; ``Placement.recorded`` is the identity: poses run where they were
recorded, in the robot's base frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from lfd.pose import PoseChart
from robots import Kinematics, RobotModel, solve_pose_ik
from robots.task_frame import TaskFrame
from sim.errors import PlacementError

PLANES: tuple[str, ...] = ("auto", "horizontal", "vertical")
SIZE_FRACTION = 0.15     # default path size: this fraction of the robot's reach
REACH_MARGIN_M = 0.04    # reachability is checked this far around the path (offsets, pushes)
JOINT_MARGIN = 0.05      # ... with every joint this fraction of its range away from its limits
IK_TOLERANCE_M = 1e-3    # ... and a position error below this
IK_TOLERANCE_RAD = 1e-3  # ... and, for a pose, a rotation error below this
POSE_POSTURE_GAIN = 0.2  # a pose path's IK pulls the redundant joints toward q_home (``solve_pose_ik``)


@dataclass(frozen=True)
class Placement:
    """Affine map from task space onto the robot's workspace.

    origin : array, shape (3,)     -- world position (m) of the task origin
    rotation : array, shape (3, 3) -- columns: task x, y, z axes in world coordinates
    scale : float                  -- metres per user unit
    dim : int                      -- task dimension d (2 or 3; 6 for a pose task)
    chart : PoseChart or None      -- a pose task's orientation chart (then d = 6)
    """

    origin: np.ndarray
    rotation: np.ndarray
    scale: float
    dim: int
    chart: PoseChart | None = None

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation, dtype=np.float64)
        if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
            raise PlacementError("placement rotation must be a proper 3x3 rotation matrix")
        if not self.scale > 0:
            raise PlacementError(f"placement scale must be positive, got {self.scale}")
        if (self.dim == 6) != (self.chart is not None) or self.dim not in (2, 3, 6):
            raise PlacementError(f"placement dimension must be 2 or 3, or 6 with a pose chart, got {self.dim}")
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=np.float64).reshape(3))
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "scale", float(self.scale))

    @classmethod
    def recorded(cls, chart: PoseChart, robot: RobotModel | None = None) -> Placement:
        """The identity placement of a pose task: poses where they were recorded (base frame, metres);
        PlacementError for a planar ``robot`` (it cannot turn its tool freely)."""
        if robot is not None and robot.planar:
            raise PlacementError(f"robot '{robot.name}' moves in a plane; it cannot follow poses")
        return cls(np.zeros(3), np.eye(3), 1.0, 6, chart)

    @property
    def pose(self) -> bool:
        """Whether this places a pose task (d = 6, module docstring)."""
        return self.chart is not None

    @property
    def position_dim(self) -> int:
        """The task's position coordinates: d, or 3 for a pose task."""
        return 3 if self.chart is not None else self.dim

    @property
    def axes(self) -> np.ndarray:
        """A = R[:, :d], shape (3, d) (3 x 3 for a pose task): task axes in world coordinates."""
        return self.rotation[:, :self.position_dim]

    @property
    def normal(self) -> np.ndarray:
        """n = R[:, 2], shape (3,): the plane normal (d = 2) or the task z axis (d = 3)."""
        return self.rotation[:, 2]

    def to_world(self, x: np.ndarray) -> np.ndarray:
        """p = o + s A x; x : array, shape (..., d) -> shape (..., 3) (a pose's position part)."""
        x = np.asarray(x, dtype=np.float64)
        if self.chart is not None:
            x = x[..., :3]
        return self.origin + self.scale * x @ self.axes.T

    def to_task(self, p: np.ndarray, rot: np.ndarray | None = None) -> np.ndarray:
        """x = A^T (p - o) / s; p : array, shape (..., 3) -> shape (..., d). A pose task also needs
        the tool rotations rot, shape (..., 3, 3), world: x = (A^T (p - o) / s, l log(R_g^T R^T rot))."""
        pos = (np.asarray(p, dtype=np.float64) - self.origin) @ self.axes / self.scale
        if self.chart is None:
            return pos
        if rot is None:
            raise PlacementError("a pose task's points need the tool rotations as well as positions")
        rel = np.einsum("ji,...jk->...ik", self.rotation, np.asarray(rot, dtype=np.float64))
        return np.concatenate([pos, self.chart.rotation_coordinates(rel)], axis=-1)

    def rotation_to_world(self, x: np.ndarray) -> np.ndarray:
        """The world tool rotations R R_task, shape (..., 3, 3), of pose task points x (..., 6)."""
        if self.chart is None:
            raise PlacementError("only a pose task has orientations")
        return np.einsum("ij,...jk->...ik", self.rotation, self.chart.rotations(x))

    def tool_rotation(self, x: np.ndarray, held: np.ndarray | None = None) -> np.ndarray | None:
        """The world tool rotation that task points x, shape (..., d), ask for: R R_task(x), shape
        (..., 3, 3), for a pose task; ``held`` (the rotation a position task holds, or None) otherwise."""
        return self.rotation_to_world(x) if self.chart is not None else held

    def turned(self, x: np.ndarray, turn: np.ndarray) -> np.ndarray:
        """Task point x, shape (d,), with its tool orientation turned by exp(turn), turn a world rotation
        vector (3,) [rad]: a pose task's new chart point; a position task's x as it is (its orientation
        is not part of the task)."""
        if self.chart is None or not np.any(turn != 0):
            return x
        return self.to_task(self.to_world(x), pin.exp3(np.asarray(turn, dtype=np.float64)) @ self.rotation_to_world(x))

    def task_frame(self, planar: bool, rotation_ref: np.ndarray | None = None, plane_gain: float = 20.0,
                   rotation_gain: float = 10.0) -> TaskFrame:
        """This placement as a ``robots.task_frame.TaskFrame``, for ``robots.controller.ArmController``:
        on a spatial arm (``planar`` False) a 2-D task's pull onto its plane (``plane_gain``) and a
        position task's held tool orientation ``rotation_ref`` (``rotation_gain``); neither on a planar arm."""
        spatial = not planar
        return TaskFrame(origin=self.origin.copy(), axes=self.axes.copy(), scale=self.scale,
                         rotation=self.rotation.copy(), chart=self.chart,
                         rotation_ref=rotation_ref if spatial and self.chart is None else None,
                         plane_gain=plane_gain if spatial else 0.0, rotation_gain=rotation_gain)

    def solve_ik(self, robot: RobotModel, x: np.ndarray, held: np.ndarray | None = None,
                 q0: np.ndarray | None = None) -> tuple[np.ndarray, float, float, bool]:
        """Joints with the tool on task point x, shape (d,) (``solve_pose_ik``): a pose task's in its
        pose, its redundant joints pulled toward q_home; a position task's holding ``held``. Returns
        (q (n,), position miss [m], rotation miss [rad], reached: within ``IK_TOLERANCE_M`` and, for a
        pose task, ``IK_TOLERANCE_RAD``)."""
        pose = self.chart is not None
        q, err, rot_err = solve_pose_ik(robot, self.to_world(x), self.tool_rotation(x, held),
                                        q0=robot.q_home if q0 is None else q0,
                                        posture=POSE_POSTURE_GAIN if pose else 0.0)
        return q, err, rot_err, bool(err <= IK_TOLERANCE_M and (rot_err <= IK_TOLERANCE_RAD or not pose))

    def velocity_to_world(self, v: np.ndarray) -> np.ndarray:
        """s A v; v : array, shape (..., d) -> shape (..., 3) (a pose's linear part)."""
        v = np.asarray(v, dtype=np.float64)
        if self.chart is not None:
            v = v[..., :3]
        return self.scale * v @ self.axes.T

    def offset_to_task(self, offset_m: np.ndarray) -> np.ndarray:
        """A^T dp / s: a world displacement dp (m), shape (..., 3), as a task displacement (..., d)
        (no turn for a pose task)."""
        pos = np.asarray(offset_m, dtype=np.float64) @ self.axes / self.scale
        if self.chart is None:
            return pos
        return np.concatenate([pos, np.zeros(pos.shape[:-1] + (3,))], axis=-1)

    def to_dict(self) -> dict:
        out = {"origin": self.origin.tolist(), "rotation": self.rotation.tolist(),
               "scale_m_per_unit": self.scale, "dim": self.dim}
        if self.chart is not None:
            out["pose_chart"] = self.chart.to_dict()
        return out

    # ------------------------------------------------------------------ defaults
    @classmethod
    def auto(cls, robot: RobotModel, points: np.ndarray, plane: str = "auto",
             size_m: float | None = None, chart: PoseChart | None = None) -> Placement:
        """The default placement of task points, shape (..., d), on ``robot``.

        The bounding box of the points is centred on the tool position at ``q_home`` (a
        well-conditioned posture well inside the workspace) and scaled so its larger side is
        ``size_m`` (default ``SIZE_FRACTION`` of the robot's reach). A planar robot gets its own
        plane (world x, y). A 2-D path on a spatial robot goes on a horizontal plane (task x, y ->
        world x, y; ``plane="auto"``) or on a vertical plane facing the robot (task x -> sideways,
        task y -> up). A 3-D path keeps the world axes, and so does a pose path (``chart`` given,
        points of shape (..., 6): its positions are placed, its orientations kept).
        """
        if plane not in PLANES:
            raise PlacementError(f"unknown plane '{plane}'; known: {', '.join(PLANES)}")
        pts = np.asarray(points, dtype=np.float64)
        d = int(pts.shape[-1])
        pts = pts.reshape(-1, d)
        if robot.planar and d != 2:
            raise PlacementError(f"robot '{robot.name}' moves in a plane; it cannot follow a {d}-D field")
        if chart is None and d not in (2, 3):
            raise PlacementError(f"the arm follows 2-D or 3-D paths, or poses; these demos are {d}-D")
        if chart is not None:
            pts, d = pts[:, :3], 3
        lo, hi = pts.min(0), pts.max(0)
        extent = float(np.max(hi - lo))
        if not np.isfinite(extent) or extent <= 0:
            raise PlacementError("cannot place a path with zero extent")
        kin = Kinematics(robot)
        kin.update(robot.q_home)
        home = kin.ee_position().copy()
        base = base_position(robot)
        if size_m is None:
            size_m = SIZE_FRACTION * reach(robot)
        rotation = np.eye(3)
        if d == 2 and not robot.planar and plane == "vertical":
            n = home - base
            n[2] = 0.0
            if np.linalg.norm(n) < 1e-6:
                n = np.array([1.0, 0.0, 0.0])
            n /= np.linalg.norm(n)
            ey = np.array([0.0, 0.0, 1.0])
            rotation = np.column_stack([np.cross(ey, n), ey, n])
        scale = float(size_m) / extent
        center = (lo + hi) / 2
        origin = home - scale * rotation[:, :d] @ center
        if chart is not None:
            return cls(origin, rotation, scale, 6, chart)
        return cls(origin, rotation, scale, d)

    # ------------------------------------------------------------------ reachability
    def check_reachable(self, robot: RobotModel, points: np.ndarray, rotation: np.ndarray | None = None,
                        margin_m: float = REACH_MARGIN_M, n_path: int = 48) -> None:
        """Raise PlacementError unless the path and a margin around it are reachable.

        Checked points: ``n_path`` samples of the task points, shape (..., d) (in order, warm
        started one from the next, as the controller would move), and the corners and edge
        midpoints of their bounding box grown by ``margin_m``; for a pose path instead, eight of the
        sampled path points moved by ``margin_m`` along each world axis, in their own orientation.
        Each must be reached by ``solve_pose_ik`` (with the tool ``rotation`` held, if given, or the
        path's own for a pose path, then also to ``IK_TOLERANCE_RAD``) to ``IK_TOLERANCE_M``, with
        every joint within its limits: a path point ``JOINT_MARGIN`` of its range inside them (the arm
        follows the path with room to spare), a margin point anywhere inside (where a push or an
        offset start may take the arm for a moment).
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, self.dim)
        if not np.isfinite(pts).all():
            raise PlacementError("path has NaN or inf points")
        idx = np.unique(np.linspace(0, len(pts) - 1, min(n_path, len(pts))).round().astype(int))
        pd = self.position_dim
        lo, hi = pts[:, :pd].min(0), pts[:, :pd].max(0)
        grow = margin_m / self.scale
        hint = ("poses run where recorded: try --shift DX,DY,DZ" if self.chart is not None
                else "try a smaller --size-m or another --plane")
        rots, source = None, np.zeros(0, dtype=int)
        if self.chart is None:
            ring = _box_probe_points(lo - grow, hi + grow)
        else:
            # a pose path: the margin around each sampled path point along the world axes, in that
            # point's orientation (the box's corners are far from a winding 3-D path, and the arm need
            # not reach them with any one orientation)
            steps = np.concatenate([np.eye(3), -np.eye(3)]) * grow                     # (6, 3)
            source = np.repeat(np.arange(0, len(idx), max(1, len(idx) // 8)), len(steps))
            near = pts[idx][source]
            ring = np.concatenate([near[:, :pd] + np.tile(steps, (len(source) // len(steps), 1)), near[:, pd:]],
                                  axis=1)
            rots = self.rotation_to_world(np.concatenate([pts[idx], ring]))
        q = robot.q_home.copy()
        solved: list[np.ndarray] = []   # the path points' joints: a pose path's margin points start there
        span = robot.q_max - robot.q_min
        qlo, qhi = robot.q_min + JOINT_MARGIN * span, robot.q_max - JOINT_MARGIN * span
        for k, x in enumerate(np.concatenate([pts[idx], ring])):
            on_path = k < len(idx)
            p = self.to_world(x)
            q0 = q if on_path else (solved[source[k - len(idx)]] if rots is not None else robot.q_home)
            qs, err, rot_err = solve_pose_ik(robot, p, rotation if rots is None else rots[k], q0=q0,
                                             posture=0.0 if rots is None else POSE_POSTURE_GAIN)
            where = "path point" if on_path else f"point {margin_m * 100:.0f} cm around the path"
            if rots is not None and err <= IK_TOLERANCE_M and not rot_err <= IK_TOLERANCE_RAD:
                raise PlacementError(
                    f"placement unreachable on '{robot.name}': the tool orientation at {where} {_fmt(p)} m is "
                    f"missed by {np.degrees(rot_err):.1f} deg")
            if not err <= IK_TOLERANCE_M:
                raise PlacementError(
                    f"placement unreachable on '{robot.name}': {where} {_fmt(p)} m is missed by "
                    f"{err * 1e3:.1f} mm ({hint})")
            bad = np.flatnonzero((qs < qlo) | (qs > qhi)) if on_path else \
                np.flatnonzero((qs < robot.q_min) | (qs > robot.q_max))
            if bad.size:
                j = int(bad[0])
                within = f"within {JOINT_MARGIN:.0%} of" if on_path else "beyond"
                raise PlacementError(
                    f"placement unreachable on '{robot.name}': {where} {_fmt(p)} m needs joint "
                    f"'{robot.arm_joints[j]}' at {qs[j]:.2f} rad, {within} its limits "
                    f"[{robot.q_min[j]:.2f}, {robot.q_max[j]:.2f}]")
            if on_path:
                q = qs
                solved.append(qs)


def reach(robot: RobotModel, samples: int = 256, seed: int = 0) -> float:
    """The robot's reach (m): the largest distance from the first joint to the tool over
    ``samples`` joint configurations drawn uniformly within the limits (seeded)."""
    rng = np.random.default_rng(seed)
    kin = Kinematics(robot)
    base = base_position(robot)
    best = 0.0
    for q in rng.uniform(robot.q_min, robot.q_max, (samples, len(robot.q_min))):
        kin.update(q)
        best = max(best, float(np.linalg.norm(kin.ee_position() - base)))
    return best


def base_position(robot: RobotModel) -> np.ndarray:
    """World position, shape (3,), of the first arm joint at ``q_home``."""
    import pinocchio as pin

    data = robot.pin_model.createData()
    pin.forwardKinematics(robot.pin_model, data, robot.q_home)
    return data.oMi[1].translation.copy()


def _box_probe_points(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Corners and edge midpoints of the box [lo, hi], shape (K, d)."""
    d = len(lo)
    levels = np.stack([lo, (lo + hi) / 2, hi])           # (3, d)
    grid = np.stack(np.meshgrid(*[levels[:, j] for j in range(d)], indexing="ij"), -1).reshape(-1, d)
    center = (lo + hi) / 2
    on_surface = np.any(np.isclose(grid, lo) | np.isclose(grid, hi), axis=1)
    keep = on_surface & (np.sum(np.isclose(grid, center), axis=1) <= 1)
    return grid[keep]


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in p) + ")"
