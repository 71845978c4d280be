"""A pour with real objects: a cup held at the tool with balls in it, a bowl on the table, and the
pour's success read from the physics state (dm_control's ``ball_in_cup`` is the pattern: a scene and a
predicate).

The scene (``build``) adds to the robot's MuJoCo scene (MjSpec), sizes in ``PourScene``:

* a cup, a thin-walled cylinder (a disc and ``segments`` wall slabs) welded to the tool body, its
  centre on the tool point and its opening along the tool-frame axis ``axis`` (``cup_axis``: the one
  that points up at the demos' start, where a pour holds its cup upright);
* ``n_balls`` balls, each a free body with its mass, friction and contact, placed in the cup at every
  episode's start (``place_balls``, from the arm's start configuration);
* a bowl on the table (a disc and a wall of slabs) at ``bowl``, its bottom on the table top (z = 0);
  the table's top is grown to stand it on where it lies beyond it.

The objects collide with each other and their table top, not with the arm (``sim.scene.objects``).

Where the bowl goes (``nominal_bowl``): under the cup's mouth at the demos' mean end pose (the pour's
most tilted pose in a recorded pour), moved along the mouth's horizontal direction by the cup's radius
(the balls leave over the lip), on the table. ``--target`` moves it, and the goal with it.

Success (``outcome``): every ball stays in the cup until its tilt first passes ``POUR_TILT_DEG``, and at
least ``SUCCESS_BALLS`` rest inside the bowl ``SETTLE_AFTER_S`` after the motion ends. A failure is named
in one word: ``spilled early``, ``missed the bowl``, ``not poured`` (the cup never tilted far enough);
``sim.run.tasks`` adds ``stopped short`` (the tool ended away from its pouring pose). ``PourCheck``:
the same conditions checked online, at every step, for a dm_env task's reward.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from robots import RobotModel
from sim.scene import objects

#: the tilt of the cup's axis from the vertical, deg, from which on balls may leave it
POUR_TILT_DEG = 60.0
#: balls in the bowl for a success, and how long after the motion ends they are counted, s
SUCCESS_BALLS = 10
SETTLE_AFTER_S = 1.0
#: a ball at rest moves slower than this, m/s (``PourCheck``)
REST_SPEED_M_S = 0.05
_CUP, _BOWL, _BALL = "pour_cup", "pour_bowl", "pour_ball"


@dataclass(frozen=True)
class PourScene:
    """Sizes (m, kg) of the pour's objects: a cup of inner radius ``cup_radius`` and height
    ``cup_height``, walls ``wall`` thick; ``n_balls`` balls of radius ``ball_radius`` and mass
    ``ball_mass``; a bowl of inner radius ``bowl_radius`` and wall height ``bowl_height``. Contacts:
    sliding ``friction``, the balls' ``rolling`` friction (m) and the damping ratio of their contacts
    (``damping`` > 1: a ball that lands does not bounce: wooden or rubber balls, not steel)."""

    cup_radius: float = 0.035
    cup_height: float = 0.09
    cup_mass: float = 0.1
    wall: float = 0.004
    n_balls: int = 12
    ball_radius: float = 0.01
    ball_mass: float = 0.01
    bowl_radius: float = 0.07
    bowl_height: float = 0.05
    segments: int = 16
    friction: float = 0.6
    rolling: float = 0.002
    damping: float = 2.0


def cup_axis(start_rotations: np.ndarray) -> np.ndarray:
    """The tool-frame axis, shape (3,), a signed unit vector, that points most nearly up (world +z)
    on average over ``start_rotations`` (N, 3, 3), the demos' start tool rotations."""
    up = np.mean([r[2, :] for r in start_rotations], axis=0)   # world z of each tool axis
    i = int(np.argmax(np.abs(up)))
    axis = np.zeros(3)
    axis[i] = math.copysign(1.0, up[i])
    return axis


def tilt_deg(rotation: np.ndarray, axis: np.ndarray) -> float:
    """The angle between the cup's opening (``rotation`` (3, 3) @ ``axis``) and world +z, deg."""
    return float(np.degrees(np.arccos(np.clip((rotation @ axis)[2], -1.0, 1.0))))


def nominal_bowl(end_position: np.ndarray, end_rotation: np.ndarray, axis: np.ndarray,
                 scene: PourScene = PourScene()) -> np.ndarray:
    """The bowl's centre on the table, shape (3,) (z = 0), for a pour ending at the tool pose
    ``end_position`` (3,), ``end_rotation`` (3, 3) (module docstring)."""
    opening = end_rotation @ axis
    mouth = end_position + opening * scene.cup_height / 2
    horizontal = np.array([opening[0], opening[1], 0.0])
    n = float(np.linalg.norm(horizontal))
    shift = horizontal / n * scene.cup_radius if n > 1e-9 else np.zeros(3)
    return np.array([mouth[0] + shift[0], mouth[1] + shift[1], 0.0])


def _ring(body: ET.Element, name: str, radius: float, height: float, z: float, scene: PourScene, rgba: str) -> None:
    """A wall of ``segments`` slabs around the body's z axis, inner radius ``radius``, centred at height ``z``."""
    n = scene.segments
    half_w = (radius + scene.wall) * math.tan(math.pi / n) + 1e-4
    for k in range(n):
        a = 2 * math.pi * k / n
        objects.geom(body, scene.friction, name=f"{name}_wall{k}", type="box",
                     size=[scene.wall / 2, half_w, height / 2],
                     pos=[(radius + scene.wall / 2) * math.cos(a), (radius + scene.wall / 2) * math.sin(a), z],
                     quat=[math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)], rgba=rgba)


def build(robot: RobotModel, axis: np.ndarray, bowl: np.ndarray, scene: PourScene = PourScene()) -> RobotModel:
    """``robot`` with the pour's cup (on its tool body), balls and bowl added (module docstring).

    Parameters
    ----------
    robot : RobotModel
        The arm, loaded with a table (``load_robot(..., table=True)``).
    axis : ndarray, shape (3,)
        The cup's opening in the tool frame (``cup_axis``).
    bowl : ndarray, shape (3,)
        The bowl's centre on the table, world, m.
    scene : PourScene

    Returns
    -------
    RobotModel
        The same arm in the scene with the objects (its joint and actuator indices unchanged).
    """
    root = ET.fromstring(robot.mjcf_xml)
    tool_el, site = objects.tool_body(root, robot)
    world = root.find("worldbody")
    assert world is not None   # a compiled robot's scene
    # the cup's frame: origin on the tool point, z along ``axis`` (tool frame)
    quat = objects.quaternion(objects.frame_along(axis, site.quat))
    h, r_cup = scene.cup_height, scene.cup_radius + scene.wall
    cup = objects.body(tool_el, _CUP, site.pos, scene.cup_mass,
                       [scene.cup_mass * (r_cup ** 2 / 2 + h ** 2 / 12)] * 2 + [scene.cup_mass * r_cup ** 2], quat)
    glass = "0.85 0.85 0.9 0.55"
    objects.geom(cup, scene.friction, name=f"{_CUP}_bottom", type="cylinder", size=[r_cup, scene.wall / 2],
                 pos=[0, 0, -h / 2 + scene.wall / 2], rgba=glass)
    _ring(cup, _CUP, scene.cup_radius, h, 0.0, scene, glass)
    objects.grow_table(root, bowl, scene.bowl_radius + 0.1)   # the table grown to stand the bowl on
    objects.object_table(world, "pour_table", scene.friction)
    bowl_el = ET.SubElement(world, "body", {"name": _BOWL, "pos": objects.fmt([bowl[0], bowl[1], 0.0])})
    clay = "0.55 0.35 0.2 1"
    objects.geom(bowl_el, scene.friction, name=f"{_BOWL}_bottom", type="cylinder",
                 size=[scene.bowl_radius + scene.wall, scene.wall / 2], pos=[0, 0, scene.wall / 2], rgba=clay)
    _ring(bowl_el, _BOWL, scene.bowl_radius, scene.bowl_height, scene.wall + scene.bowl_height / 2, scene, clay)
    for i in range(scene.n_balls):
        ball = objects.body(world, f"{_BALL}{i}", [0.0, 0.0, 1.0 + 0.05 * i], scene.ball_mass,
                            [0.4 * scene.ball_mass * scene.ball_radius ** 2] * 3)
        ET.SubElement(ball, "freejoint", {"name": f"{_BALL}{i}"})
        g = objects.geom(ball, scene.friction, type="sphere", size=[scene.ball_radius], rgba="0.9 0.3 0.1 1",
                         condim="6", solref=[0.01, scene.damping])
        g.set("friction", objects.fmt([scene.friction, 0.005, scene.rolling]))
    return objects.compiled(robot, root, "pour")


def ball_offsets(scene: PourScene = PourScene()) -> np.ndarray:
    """The balls' start positions in the cup's frame, shape (n_balls, 3), m: rings of six on the
    bottom, each ring a ball's diameter above the last."""
    r, out = scene.ball_radius, []
    ring = scene.cup_radius - r - 0.002
    for i in range(scene.n_balls):
        layer, k = divmod(i, 6)
        a = 2 * math.pi * k / 6 + layer * math.pi / 6
        out.append([ring * math.cos(a), ring * math.sin(a), -scene.cup_height / 2 + scene.wall + r + 0.001
                    + layer * (2 * r + 0.002)])
    return np.array(out)


def place_balls(model: mujoco.MjModel, data: mujoco.MjData, scene: PourScene = PourScene()) -> None:
    """Put the balls in the cup at rest, where the cup is in ``data`` (its kinematics computed here)."""
    mujoco.mj_kinematics(model, data)
    cup = model.body(_CUP).id
    pos, rot = data.xpos[cup], data.xmat[cup].reshape(3, 3)
    for i, offset in enumerate(ball_offsets(scene)):
        j = model.joint(f"{_BALL}{i}")
        a, v = int(j.qposadr[0]), int(j.dofadr[0])
        data.qpos[a:a + 3] = pos + rot @ offset
        data.qpos[a + 3:a + 7] = (1.0, 0.0, 0.0, 0.0)
        data.qvel[v:v + 6] = 0.0


def _in_cup(balls: np.ndarray, cup_pos: np.ndarray, cup_rot: np.ndarray, scene: PourScene) -> np.ndarray:
    """Which balls (positions (B, 3), world) are inside the cup at ``cup_pos`` (3,), ``cup_rot`` (3, 3), (B,) bool."""
    local = (balls - cup_pos) @ cup_rot
    return (np.hypot(local[:, 0], local[:, 1]) < scene.cup_radius + scene.wall) & \
        (np.abs(local[:, 2]) < scene.cup_height / 2 + scene.ball_radius)


def _in_bowl(balls: np.ndarray, bowl_pos: np.ndarray, scene: PourScene) -> np.ndarray:
    """Which balls (positions (B, 3), world) are inside the bowl standing at ``bowl_pos`` (3,), (B,) bool."""
    rel = balls - bowl_pos
    return (np.hypot(rel[:, 0], rel[:, 1]) < scene.bowl_radius) & (rel[:, 2] > 0.0) & \
        (rel[:, 2] < scene.wall + scene.bowl_height)


class PourCheck:
    """The pour's success, online, on a simulation's current state (what a dm_env task's reward reads):
    true once no ball left the cup before its tilt first passed ``POUR_TILT_DEG`` and at least
    ``SUCCESS_BALLS`` balls rest (slower than ``REST_SPEED_M_S``) inside the bowl. ``reset`` at each
    episode's start; the call after each step (the bodies' poses computed)."""

    def __init__(self, model: mujoco.MjModel, scene: PourScene = PourScene()) -> None:
        self.scene = scene
        self._cup, self._bowl = model.body(_CUP).id, model.body(_BOWL).id
        joints = [model.joint(f"{_BALL}{i}") for i in range(scene.n_balls)]
        self._pos = np.array([int(j.qposadr[0]) + k for j in joints for k in range(3)])
        self._vel = np.array([int(j.dofadr[0]) + k for j in joints for k in range(3)])
        self.poured = self.spilled = False

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """A new episode: nothing poured, nothing spilled."""
        self.poured = self.spilled = False

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> bool:
        balls = data.qpos[self._pos].reshape(-1, 3)
        if not self.poured:
            rot = data.xmat[self._cup].reshape(3, 3)
            self.spilled = self.spilled or not _in_cup(balls, data.xpos[self._cup], rot, self.scene).all()
            self.poured = tilt_deg(rot, np.array([0.0, 0.0, 1.0])) >= POUR_TILT_DEG
        if self.spilled or not self.poured:
            return False
        still = np.linalg.norm(data.qvel[self._vel].reshape(-1, 3), axis=1) < REST_SPEED_M_S
        return int(np.count_nonzero(_in_bowl(balls, data.xpos[self._bowl], self.scene) & still)) >= SUCCESS_BALLS


def outcome(model: mujoco.MjModel, frame_t: np.ndarray, frame_qpos: np.ndarray, motion_end_s: float,
            axis: np.ndarray, scene: PourScene = PourScene()) -> dict[str, Any]:
    """The pour's success from the recorded physics states (module docstring).

    Parameters
    ----------
    model : mujoco.MjModel
        The scene of ``build``.
    frame_t, frame_qpos : ndarray, shape (F,) and (F, nq)
        The run's recorded times and full joint states (a ``RunTrace``'s video frames).
    motion_end_s : float
        When the motion ends (the demos' duration), s; balls are counted ``SETTLE_AFTER_S`` later.
    axis : ndarray, shape (3,)
        The cup's opening in the tool frame.

    Returns
    -------
    dict
        ``in_bowl``, ``in_cup_before_pour`` (balls still in the cup when its tilt first passed
        ``POUR_TILT_DEG``, or at the end if it never did), ``max_tilt_deg``, ``poured_at_s``,
        ``success`` and ``cause`` (None, ``spilled early``, ``missed the bowl`` or ``not poured``).
    """
    data = mujoco.MjData(model)
    cup, bowl = model.body(_CUP).id, model.body(_BOWL).id
    adr = [int(model.joint(f"{_BALL}{i}").qposadr[0]) for i in range(scene.n_balls)]
    cup_z = np.array([0.0, 0.0, 1.0])   # the opening, in the cup body's frame
    poured_at, in_cup_before, max_tilt = None, scene.n_balls, 0.0
    count_at = motion_end_s + SETTLE_AFTER_S
    k_count = int(np.argmin(np.abs(frame_t - count_at)))
    in_bowl = 0
    for k, (t, qpos) in enumerate(zip(frame_t, frame_qpos)):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        rot = data.xmat[cup].reshape(3, 3)
        tilt = tilt_deg(rot, cup_z)
        max_tilt = max(max_tilt, tilt)
        balls = np.array([qpos[a:a + 3] for a in adr])
        if poured_at is None:
            in_cup_before = int(np.count_nonzero(_in_cup(balls, data.xpos[cup], rot, scene)))
            if tilt >= POUR_TILT_DEG:
                poured_at = float(t)
        if k == k_count:
            in_bowl = int(np.count_nonzero(_in_bowl(balls, data.xpos[bowl], scene)))
    spilled = in_cup_before < scene.n_balls
    success = not spilled and poured_at is not None and in_bowl >= SUCCESS_BALLS
    cause = None if success else "spilled early" if spilled else "not poured" if poured_at is None \
        else "missed the bowl"
    return {"in_bowl": in_bowl, "in_cup_before_pour": in_cup_before, "max_tilt_deg": max_tilt,
            "poured_at_s": poured_at, "counted_at_s": float(frame_t[k_count]), "success": bool(success),
            "cause": cause}
