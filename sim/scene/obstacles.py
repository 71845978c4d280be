"""Task-space obstacles (``lfd.obstacles``) as MuJoCo geoms, and the arm's contacts with them.

The field avoids an obstacle in task space (the tool point is kept out of it; ``sim.scene.collision``
keeps the rest of the arm out through the IK); this module puts
the same obstacle into the robot's scene, so it is drawn in videos, physically collides with the
arm, and can be checked: ``obstacle_contacts`` replays a run's joint trajectory through
MuJoCo's collision detection and reports every robot-obstacle contact and the smallest clearance
between any robot geom and any obstacle.

Task units map to the world by the placement, p = o + s A x (``sim.scene.placement.Placement``):

* a ``Sphere`` becomes a ball of radius s r centred at p(c), in 2-D and 3-D tasks;
* a ``Box`` becomes a box with half sizes s h, its axes along the task axes; in a 2-D task its
  half thickness along the plane normal is the smaller of its two half sizes;
* a ``Capsule`` becomes a capsule from p(a) to p(b) of radius s r.

The obstacle's ``margin`` is not drawn: it is clearance the field keeps, not geometry. A moving
obstacle's geom sits in a mocap body ``obstacle_<i>`` whose position is its world displacement
s A delta(t) (``lfd.obstacles.Obstacle.offset``); ``mocap_path`` gives those positions at the
control steps, which the control loop writes into ``MjData.mocap_pos`` before each step (so the arm
collides with the obstacle where it is), the run's trace records, the video draws and
``obstacle_contacts`` replays.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from lfd.errors import ConfigError
from lfd.obstacles import Box, Capsule, Obstacle, Sphere
from robots.model import RobotModel
from sim.scene.placement import Placement

PREFIX = "obstacle_"
RGBA = (0.85, 0.25, 0.2, 0.55)  # half-transparent red: the path behind it stays visible
DISTANCE_CUTOFF_M = 0.5         # clearances beyond this are reported as this


@dataclass(frozen=True)
class ContactReport:
    """Robot-obstacle contacts over a replayed trajectory.

    contacts : int       -- robot-obstacle contact pairs summed over all replayed states
    steps_in_contact : int -- states with at least one such contact
    first_contact_s : float | None -- time of the first state in contact
    min_clearance_m : float -- smallest signed distance between a robot geom and an obstacle (< 0: penetration)
    pairs : tuple[str, ...] -- "robot geom / obstacle geom" names that touched, sorted
    """

    contacts: int
    steps_in_contact: int
    first_contact_s: float | None
    min_clearance_m: float
    pairs: tuple[str, ...]

    def to_dict(self) -> dict:
        return dataclasses.asdict(self) | {"pairs": list(self.pairs)}


def _quat_from_axes(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), shape (4,), of a 3x3 rotation matrix."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=np.float64).ravel())
    return q


def _numbers(values: Sequence[float] | np.ndarray) -> str:
    """Space-separated numbers at full double precision (MuJoCo's own writer keeps 6 digits)."""
    return " ".join(repr(float(v)) for v in np.ravel(values))


def obstacle_geoms(obstacles: Sequence[Obstacle], placement: Placement,
                   rgba: Sequence[float] = RGBA) -> list[dict[str, str]]:
    """MJCF ``<geom>`` attributes, one dict per obstacle, named ``obstacle_<i>``, in world units.

    The geoms collide with everything (contype = conaffinity = 1) and are drawn in group 0.
    Raises ``ConfigError`` for an obstacle whose dimension is not the placement's.
    """
    geoms: list[dict[str, str]] = []
    s = placement.scale
    for i, ob in enumerate(obstacles):
        if ob.dim != placement.dim:
            raise ConfigError(f"obstacle {i + 1} ({ob.describe()}) is {ob.dim}-D but the task is {placement.dim}-D")
        g = {"name": f"{PREFIX}{i}", "rgba": _numbers(rgba), "contype": "1", "conaffinity": "1", "group": "0"}
        if isinstance(ob, Sphere):
            g |= {"type": "sphere", "size": _numbers([s * ob.radius]), "pos": _numbers(placement.to_world(ob.center))}
        elif isinstance(ob, Box):
            h = s * np.asarray(ob.half_sizes, dtype=np.float64)
            if placement.dim == 2:
                h = np.append(h, h.min())
            g |= {"type": "box", "size": _numbers(h), "pos": _numbers(placement.to_world(ob.center)),
                  "quat": _numbers(_quat_from_axes(placement.rotation))}
        elif isinstance(ob, Capsule):
            ends = np.concatenate([placement.to_world(ob.a), placement.to_world(ob.b)])
            g |= {"type": "capsule", "size": _numbers([s * ob.radius]), "fromto": _numbers(ends)}
        else:
            raise ConfigError(f"obstacle {i + 1}: no MuJoCo geom for a {type(ob).__name__}")
        geoms.append(g)
    return geoms


def with_obstacles(robot: RobotModel, obstacles: Sequence[Obstacle], placement: Placement) -> RobotModel:
    """A copy of ``robot`` whose scene (``mjcf_xml``, ``mj_model``) also holds the obstacles.

    The geoms are appended to the world body of the robot's exact XML (every other number is kept
    as it was), which adds no joint, actuator or site, so the arm's index arrays stay valid.
    """
    if not obstacles:
        return robot
    root = ET.fromstring(robot.mjcf_xml)
    world = root.find("worldbody")
    if world is None:
        raise ConfigError(f"robot '{robot.name}': its scene has no <worldbody>")
    for ob, attrs in zip(obstacles, obstacle_geoms(obstacles, placement)):
        if ob.moving:   # the geom keeps its t = 0 coordinates inside a body moved by the displacement
            body = ET.SubElement(world, "body", {"name": attrs["name"], "mocap": "true",
                                                 "pos": _numbers(placement.velocity_to_world(ob.offset(0.0)))})
            ET.SubElement(body, "geom", attrs)
        else:
            ET.SubElement(world, "geom", attrs)
    xml = ET.tostring(root, encoding="unicode")
    model = mujoco.MjModel.from_xml_string(xml, dict(robot.mj_assets))
    return dataclasses.replace(robot, mjcf_xml=xml, mj_model=model)


def mocap_path(model: mujoco.MjModel, obstacles: Sequence[Obstacle], placement: Placement,
               times: np.ndarray) -> np.ndarray | None:
    """Positions of every mocap body of ``model`` at ``times`` (shape (T,), s): shape (T, nmocap, 3),
    m, with the moving obstacles' bodies (``with_obstacles``) at their displacement and any other
    mocap body where the model puts it; None when no obstacle moves."""
    movers = [(i, ob) for i, ob in enumerate(obstacles) if ob.moving]
    if not movers:
        return None
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    out = np.broadcast_to(_model_mocap(model), (times.size, model.nmocap, 3)).copy()
    for i, ob in movers:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{PREFIX}{i}")
        if body < 0 or model.body_mocapid[body] < 0:
            raise ConfigError(f"obstacle {i + 1} ({ob.describe()}) moves but the scene has no mocap body "
                              f"'{PREFIX}{i}' (build it with sim.scene.obstacles.with_obstacles)")
        m = int(model.body_mocapid[body])
        out[:, m] = placement.velocity_to_world(np.array([ob.offset(float(t)) for t in times]))   # s A delta(t)
    return out


def _model_mocap(model: mujoco.MjModel) -> np.ndarray:
    """The mocap bodies' positions in the model, shape (nmocap, 3)."""
    ids = [b for b in range(model.nbody) if model.body_mocapid[b] >= 0]
    out = np.zeros((model.nmocap, 3))
    for b in ids:
        out[model.body_mocapid[b]] = model.body_pos[b]
    return out


def obstacle_geom_ids(model: mujoco.MjModel) -> np.ndarray:
    """Ids, shape (k,), of the geoms named ``obstacle_<i>`` in ``model``."""
    return np.array([g for g in range(model.ngeom)
                     if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith(PREFIX)], dtype=int)


def robot_geom_ids(model: mujoco.MjModel) -> np.ndarray:
    """Geoms that collide on the arm's bit (contype or conaffinity bit 0, the robot's and the table's)
    on bodies other than the world body and the moving obstacles' mocap bodies, shape (m,). Objects
    that collide only among themselves (``sim.scene.pour``: bit 1) are not the robot's."""
    return np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] != 0
                     and model.body_mocapid[model.geom_bodyid[g]] < 0
                     and (model.geom_contype[g] & 1 or model.geom_conaffinity[g] & 1)], dtype=int)


def obstacle_contacts(robot: RobotModel, q: np.ndarray, t: np.ndarray | None = None,
                      mocap_pos: np.ndarray | None = None) -> ContactReport:
    """Replay the arm joint trajectory ``q``, shape (T, n), through ``robot``'s scene (built by
    ``with_obstacles``) and report robot-obstacle contacts and the smallest clearance.

    ``t`` : array, shape (T,), the states' times (default: their indices). Collision detection runs
    on every state (``mj_kinematics`` + ``mj_collision``), so contacts are found at the states'
    spacing, not MuJoCo's internal step. ``mocap_pos`` : array, shape (T, nmocap, 3), optional: where
    the mocap bodies (moving obstacles) were at each state (``sim.RunTrace.mocap_pos``).
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != robot.n:
        raise ConfigError(f"joint trajectory must have shape (T, {robot.n}), got {q.shape}")
    if mocap_pos is not None and np.shape(mocap_pos) != (len(q), robot.mj_model.nmocap, 3):
        raise ConfigError(f"mocap positions must have shape ({len(q)}, {robot.mj_model.nmocap}, 3), "
                          f"got {np.shape(mocap_pos)}")
    times = np.arange(len(q), dtype=np.float64) if t is None else np.asarray(t, dtype=np.float64)
    model = robot.mj_model
    data = mujoco.MjData(model)
    obstacles = obstacle_geom_ids(model)
    robot_geoms = robot_geom_ids(model)
    if obstacles.size == 0:
        return ContactReport(0, 0, None, float("inf"), ())
    is_obstacle = np.zeros(model.ngeom, dtype=bool)
    is_obstacle[obstacles] = True
    is_robot = np.zeros(model.ngeom, dtype=bool)
    is_robot[robot_geoms] = True
    total = steps = 0
    first: float | None = None
    clearance = DISTANCE_CUTOFF_M
    pairs: set[str] = set()
    fromto = np.zeros(6)
    for k in range(len(q)):
        data.qpos[robot.mj_qpos_adr] = q[k]
        if mocap_pos is not None:
            data.mocap_pos[:] = mocap_pos[k]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        hits = 0
        for c in data.contact[:data.ncon]:
            g1, g2 = int(c.geom1), int(c.geom2)
            if (is_obstacle[g1] and is_robot[g2]) or (is_obstacle[g2] and is_robot[g1]):
                hits += 1
                r, o = (g2, g1) if is_obstacle[g1] else (g1, g2)
                pairs.add(f"{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, r) or f'geom {r}'} / "
                          f"{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, o)}")
                clearance = min(clearance, float(c.dist))
        if hits:
            total += hits
            steps += 1
            first = float(times[k]) if first is None else first
        else:
            for o in obstacles:
                for r in robot_geoms:
                    clearance = min(clearance, float(mujoco.mj_geomDistance(model, data, int(r), int(o),
                                                                            DISTANCE_CUTOFF_M, fromto)))
    return ContactReport(total, steps, first, clearance, tuple(sorted(pairs)))
