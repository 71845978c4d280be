"""A placement with a real object: a bottle held in the hand, released when the motion ends, and a
shelf to stand it on; the placement's success read from the physics state (``sim.scene.pour`` is the
pour's; dm_control's ``ball_in_cup`` is the pattern: a scene and a predicate).

The scene (``build``) adds to the robot's MuJoCo scene (MjSpec), sizes in ``PlaceScene``:

* a bottle (a body and a neck, its mass and friction real), a free body held at the tool by a weld
  equality (``GRIP``): its axis along the tool-frame direction ``axis`` (``bottle_axis``: the one
  that points straight up at the demos' mean end, where the bottle stands), the tool point ``grasp``
  above its bottom.
  ``hold_bottle`` puts it in the hand at every episode's start and switches the weld on; the run's
  ``Release`` switches it off when the motion ends (the gripper opening);
* a shelf, a board on a post, its top ``drop`` below the bottle's bottom at the goal.

Where the shelf goes (``nominal_spot``): under the bottle at the demos' mean end pose: the spot is the
bottle's bottom centre there. ``--target`` moves the spot, and the goal with it.

Success (``outcome``): ``SETTLE_AFTER_S`` after the release the bottle stands within ``UPRIGHT_DEG``
of upright on the shelf (its bottom within ``REST_M`` of the shelf's top), its bottom within ``SPOT_M``
of the spot. A failure is named in one word: ``collision`` (before the release the bottle was pushed
out of the hand by more than ``SLIP_M``: it struck the shelf), ``not released`` (still where the hand
holds it, off the shelf), ``toppled`` (tilted past ``UPRIGHT_DEG`` or fell off the shelf), ``missed
the spot``; ``sim.run.tasks`` adds ``stopped short`` (the tool ended away from its goal). ``PlaceCheck``
checks the same conditions online, at every step, for a dm_env task's reward.
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

#: success: the bottle's axis within this of upright, deg, its bottom within this of the spot, m
UPRIGHT_DEG = 10.0
SPOT_M = 0.02
#: when after the release the bottle is judged, s
SETTLE_AFTER_S = 1.0
#: a bottle moved this far in the hand before its release struck something, m
SLIP_M = 0.01
#: a bottle stands on the shelf when its bottom is this close to the shelf's top, m (it hangs in the
#: hand ``PlaceScene.drop`` above it)
REST_M = 0.002
#: a bottle at rest moves slower than this, m/s (``PlaceCheck``)
REST_SPEED_M_S = 0.02
#: the weld equality that holds the bottle in the hand
GRIP = "place_grip"
_BOTTLE, _SHELF = "place_bottle", "place_shelf"


@dataclass(frozen=True)
class PlaceScene:
    """Sizes (m, kg) of the placement's objects: a bottle of radius ``radius`` and body height
    ``body_height``, a neck of ``neck_radius`` and ``neck_height``, mass ``mass`` (a filled 0.33 l
    glass bottle), held ``grasp`` above its bottom; a shelf board ``shelf_half`` (x, y half extents)
    and ``board`` thick, its top ``drop`` below the bottle's bottom at the goal; sliding ``friction``."""

    radius: float = 0.033
    body_height: float = 0.16
    neck_radius: float = 0.013
    neck_height: float = 0.06
    mass: float = 0.45
    grasp: float = 0.12
    shelf_half: tuple[float, float] = (0.15, 0.15)
    board: float = 0.02
    drop: float = 0.005
    friction: float = 0.8


def bottle_axis(end_rotation: np.ndarray) -> np.ndarray:
    """The bottle's axis in the tool frame, shape (3,), a unit vector: the direction that points
    straight up (world +z) at the demos' mean end rotation ``end_rotation`` (3, 3), so the bottle
    stands upright where the demos end (the demonstrator put it down upright)."""
    return np.asarray(end_rotation, dtype=np.float64).T @ np.array([0.0, 0.0, 1.0])


def nominal_spot(end_position: np.ndarray, end_rotation: np.ndarray, axis: np.ndarray,
                 scene: PlaceScene = PlaceScene()) -> np.ndarray:
    """The spot, shape (3,), world: the bottle's bottom centre when the tool is at ``end_position``
    (3,), ``end_rotation`` (3, 3) (module docstring)."""
    return np.asarray(end_position, dtype=np.float64) - scene.grasp * (end_rotation @ axis)


def _in_tool(axis: np.ndarray, site_pos: np.ndarray, site_quat: np.ndarray, scene: PlaceScene
             ) -> tuple[np.ndarray, np.ndarray]:
    """The bottle's frame (origin on its bottom centre, z along its axis) in the tool body's frame:
    position (3,) and rotation (3, 3)."""
    rot = objects.frame_along(axis, site_quat)
    return np.asarray(site_pos, dtype=np.float64) - rot[:, 2] * scene.grasp, rot


def build(robot: RobotModel, axis: np.ndarray, spot: np.ndarray, scene: PlaceScene = PlaceScene()) -> RobotModel:
    """``robot`` with the placement's bottle (welded to its tool body) and shelf added (module docstring).

    Parameters
    ----------
    robot : RobotModel
        The arm, loaded with a table (``load_robot(..., table=True)``).
    axis : ndarray, shape (3,)
        The bottle's axis in the tool frame (``bottle_axis``).
    spot : ndarray, shape (3,)
        Where the bottle's bottom should stand, world, m; the shelf's top is ``scene.drop`` below it.

    Returns
    -------
    RobotModel
        The same arm in the scene with the objects (its joint and actuator indices unchanged).
    """
    root = ET.fromstring(robot.mjcf_xml)
    tool_el, site = objects.tool_body(root, robot)
    world = root.find("worldbody")
    assert world is not None   # a compiled robot's scene
    r, hb, hn, m = scene.radius, scene.body_height, scene.neck_height, scene.mass
    height = hb + hn
    bottle = objects.body(world, _BOTTLE, [0.0, 0.0, 1.0], m,
                          [m * (3 * r ** 2 + height ** 2) / 12] * 2 + [m * r ** 2 / 2], com=[0.0, 0.0, hb / 2])
    ET.SubElement(bottle, "freejoint", {"name": _BOTTLE})
    green = "0.2 0.55 0.3 0.9"
    objects.geom(bottle, scene.friction, name=f"{_BOTTLE}_body", type="cylinder", size=[r, hb / 2],
                 pos=[0, 0, hb / 2], rgba=green, condim="4")
    objects.geom(bottle, scene.friction, name=f"{_BOTTLE}_neck", type="cylinder", size=[scene.neck_radius, hn / 2],
                 pos=[0, 0, hb + hn / 2], rgba=green)
    pos, rot = _in_tool(axis, site.pos, site.quat, scene)
    # the weld's relpose: the tool body's pose in the bottle's frame
    equality = root.find("equality")
    if equality is None:
        equality = ET.SubElement(root, "equality")
    ET.SubElement(equality, "weld", {"name": GRIP, "body1": _BOTTLE, "body2": tool_el.get("name", ""),
                                     "relpose": objects.fmt([*(-rot.T @ pos), *objects.quaternion(rot.T)]),
                                     "solref": "0.01 1"})
    top = float(spot[2]) - scene.drop
    objects.grow_table(root, spot, max(scene.shelf_half) + 0.05)
    objects.object_table(world, "place_table", scene.friction)
    shelf = ET.SubElement(world, "body", {"name": _SHELF, "pos": objects.fmt([spot[0], spot[1], 0.0])})
    wood = "0.6 0.45 0.3 1"
    hx, hy = scene.shelf_half
    objects.geom(shelf, scene.friction, name=f"{_SHELF}_board", type="box", size=[hx, hy, scene.board / 2],
                 pos=[0, 0, top - scene.board / 2], rgba=wood)
    if top - scene.board > 1e-3:
        objects.geom(shelf, scene.friction, name=f"{_SHELF}_post", type="box",
                     size=[0.03, 0.03, (top - scene.board) / 2], pos=[0, 0, (top - scene.board) / 2], rgba=wood)
    return objects.compiled(robot, root, "place")


def hold_bottle(robot: RobotModel, axis: np.ndarray, model: mujoco.MjModel, data: mujoco.MjData,
                scene: PlaceScene = PlaceScene()) -> None:
    """Put the bottle in the hand at rest, where the tool is in ``data`` (its kinematics computed
    here), and switch the grip on."""
    mujoco.mj_kinematics(model, data)
    site = model.site(robot.mj_ee_site)
    tool = int(site.bodyid[0])
    pos, rot = _in_tool(axis, site.pos, site.quat, scene)
    body_rot = data.xmat[tool].reshape(3, 3)
    j = model.joint(_BOTTLE)
    a, v = int(j.qposadr[0]), int(j.dofadr[0])
    data.qpos[a:a + 3] = data.xpos[tool] + body_rot @ pos
    data.qpos[a + 3:a + 7] = objects.quaternion(body_rot @ rot)
    data.qvel[v:v + 6] = 0.0
    data.eq_active[model.equality(GRIP).id] = 1


class PlaceCheck:
    """The placement's success, online, on a simulation's current state (what a dm_env task's reward
    reads): the conditions of ``outcome`` checked at every step, not once after the release: true when
    the grip is open, the bottle never moved more than ``SLIP_M`` in the hand while held, and it rests
    (slower than ``REST_SPEED_M_S``) on the shelf within ``UPRIGHT_DEG`` of upright and ``SPOT_M`` of
    ``spot`` (3,), world. ``reset`` at each episode's start; the call after each step (poses computed)."""

    def __init__(self, model: mujoco.MjModel, robot: RobotModel, axis: np.ndarray, spot: np.ndarray,
                 scene: PlaceScene = PlaceScene()) -> None:
        self.spot, self.scene = np.asarray(spot, dtype=np.float64), scene
        self._grip = model.equality(GRIP).id
        site = model.site(robot.mj_ee_site)
        self._tool = int(site.bodyid[0])
        self._held, _ = _in_tool(axis, site.pos, site.quat, scene)
        j = model.joint(_BOTTLE)
        self._a, self._v = int(j.qposadr[0]), int(j.dofadr[0])
        self._rot = np.zeros(9)
        self.slipped = False

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """A new episode: nothing slipped yet."""
        self.slipped = False

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> bool:
        a = self._a
        if data.eq_active[self._grip]:
            held = data.xpos[self._tool] + data.xmat[self._tool].reshape(3, 3) @ self._held
            self.slipped = self.slipped or float(np.linalg.norm(data.qpos[a:a + 3] - held)) > SLIP_M
            return False
        mujoco.mju_quat2Mat(self._rot, data.qpos[a + 3:a + 7])
        return bool(not self.slipped and _standing(data.qpos[a:a + 3], self._rot[8], self.spot, self.scene)
                    and np.linalg.norm(data.qvel[self._v:self._v + 3]) < REST_SPEED_M_S)


def _standing(bottom: np.ndarray, cos_tilt: float, spot: np.ndarray, scene: PlaceScene) -> bool:
    """Whether a bottle with its bottom centre at ``bottom`` (3,), world, its axis ``cos_tilt`` from the
    vertical (its cosine), stands on the shelf within the tolerances of its ``spot`` (3,)."""
    hx, hy = scene.shelf_half
    on_shelf = abs(bottom[2] - (spot[2] - scene.drop)) < REST_M and abs(bottom[0] - spot[0]) < hx \
        and abs(bottom[1] - spot[1]) < hy
    return bool(on_shelf and cos_tilt >= math.cos(math.radians(UPRIGHT_DEG))
                and math.hypot(bottom[0] - spot[0], bottom[1] - spot[1]) <= SPOT_M)


def outcome(model: mujoco.MjModel, robot: RobotModel, frame_t: np.ndarray, frame_qpos: np.ndarray,
            release_s: float, axis: np.ndarray, spot: np.ndarray, scene: PlaceScene = PlaceScene()
            ) -> dict[str, Any]:
    """The placement's success from the recorded physics states (module docstring).

    Parameters
    ----------
    model : mujoco.MjModel
        The scene of ``build``.
    robot : RobotModel
        The arm (its tool site).
    frame_t, frame_qpos : ndarray, shape (F,) and (F, nq)
        The run's recorded times and full joint states (a ``RunTrace``'s video frames).
    release_s : float
        When the grip opened, s; the bottle is judged ``SETTLE_AFTER_S`` later.
    axis : ndarray, shape (3,)
        The bottle's axis in the tool frame.
    spot : ndarray, shape (3,)
        Where its bottom should stand, world, m.

    Returns
    -------
    dict
        ``tilt_deg`` and ``off_spot_m`` (the bottle's when judged), ``on_shelf``, ``slip_m`` (the
        most it moved in the hand before the release), ``success`` and ``cause`` (None, ``collision``,
        ``not released``, ``toppled`` or ``missed the spot``).
    """
    data = mujoco.MjData(model)
    site = model.site(robot.mj_ee_site)
    tool = int(site.bodyid[0])
    pos, _ = _in_tool(axis, site.pos, site.quat, scene)
    a = int(model.joint(_BOTTLE).qposadr[0])
    rot = np.zeros(9)
    k_judge = int(np.argmin(np.abs(frame_t - (release_s + SETTLE_AFTER_S))))
    slip, bottom, tilt, in_hand = 0.0, np.zeros(3), 0.0, 0.0
    for k, (t, qpos) in enumerate(zip(frame_t, frame_qpos)):
        if t < release_s or k == k_judge:
            data.qpos[:] = qpos
            mujoco.mj_kinematics(model, data)
            in_hand = float(np.linalg.norm(qpos[a:a + 3] - data.xpos[tool] - data.xmat[tool].reshape(3, 3) @ pos))
            if t < release_s:
                slip = max(slip, in_hand)
        if k == k_judge:
            bottom = np.array(qpos[a:a + 3])
            mujoco.mju_quat2Mat(rot, qpos[a + 3:a + 7])
            tilt = float(np.degrees(np.arccos(np.clip(rot[8], -1.0, 1.0))))   # the axis's world z
            break
    off = float(np.hypot(*(bottom[:2] - spot[:2])))
    hx, hy = scene.shelf_half
    top = spot[2] - scene.drop
    on_shelf = bool(abs(bottom[2] - top) < REST_M and abs(bottom[0] - spot[0]) < hx and abs(bottom[1] - spot[1]) < hy)
    not_released = not on_shelf and in_hand < 1e-3
    success = slip <= SLIP_M and _standing(bottom, float(np.cos(np.radians(tilt))), spot, scene)
    cause = None if success else "collision" if slip > SLIP_M else "not released" if not_released else "toppled" \
        if not on_shelf or tilt > UPRIGHT_DEG else "missed the spot"
    return {"tilt_deg": tilt, "off_spot_m": off, "on_shelf": on_shelf, "slip_m": slip,
            "judged_at_s": float(frame_t[k_judge]), "success": bool(success), "cause": cause}
