"""Opening a box's hinged lid: the hand holds the lid's handle and swings it open about its hinge; the
success read from the physics state (``sim.scene.pour`` and ``sim.scene.place`` are the other tasks).

Where the box is (``fit_hinge``): a recorded opening swings the tool on a circle about the hinge, so
the hinge is fitted to the demos' mean path, its axis the normal of the path's best plane (SVD), its
point the centre of the best circle in that plane (algebraic least squares), the lid's length the
circle's radius; the closed lid points from the hinge to the path's start.

The scene (``build``), sizes in ``LidScene``:

* a box under the lid, and the lid, a board on a hinge joint (damped, with friction) that rotates
  about the fitted axis, closed at the start;
* a handle on the lid's free edge, on two slide joints (along the lid and along the hinge), held at
  the tool point through a connect equality of the two sites (``GRIP``): the fingers hold it and may
  slide along it, so the hand drives the lid's angle and nothing else. ``hold_lid`` puts the lid and
  the handle where the hand is at each episode's start (the lid about closed).

Success (``outcome``): the lid opened past ``OPEN_DEG`` ``SETTLE_AFTER_S`` after the motion ends. A
failure is named in one word: ``lost the lid`` (the handle reached the end of its slide, or the grip
was stretched more than ``STRETCH_M``), ``not opened``; ``sim.run.tasks`` adds ``stopped short``.
``LidCheck``: the same conditions checked online, at every step, for a dm_env task's reward.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from robots import RobotModel
from sim.scene import objects

#: success: the lid opened past this, deg, this long after the motion ends, s
OPEN_DEG = 60.0
SETTLE_AFTER_S = 1.0
#: a grip stretched this far has let go of the handle, m
STRETCH_M = 0.02
#: the connect equality by which the hand holds the handle
GRIP = "lid_grip"
_BOX, _LID, _HANDLE = "lid_box", "lid_board", "lid_handle"


@dataclass(frozen=True)
class LidScene:
    """Sizes (m, kg) and joints of the box: a lid ``width`` across (along the hinge) and ``thickness``
    thick, of ``mass``, on a box down to the table; the hinge's ``damping`` (N m s/rad) and
    ``friction`` (N m); the handle's ``slide`` (its range each way along the lid and the hinge, m)."""

    width: float = 0.30
    thickness: float = 0.012
    mass: float = 0.4
    damping: float = 0.2
    friction: float = 0.05
    slide: float = 0.06
    handle_mass: float = 0.02


def fit_hinge(path: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The hinge of an opening whose tool path is ``path`` (T, 3), world, m (module docstring): its point
    (3,), its unit axis (3,) (the path turns positively about it) and the lid's length, m."""
    p = np.asarray(path, dtype=np.float64)
    mean = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - mean)
    u, v, axis = vt[0], vt[1], vt[2]
    flat = np.stack([(p - mean) @ u, (p - mean) @ v], axis=1)
    a = np.column_stack([2 * flat, np.ones(len(flat))])
    sol = np.linalg.lstsq(a, (flat ** 2).sum(axis=1), rcond=None)[0]
    centre, radius = sol[:2], float(np.sqrt(sol[2] + sol[:2] @ sol[:2]))
    hinge = mean + centre[0] * u + centre[1] * v
    if np.cross(p[0] - hinge, p[-1] - hinge) @ axis < 0:
        axis = -axis
    return hinge, axis / np.linalg.norm(axis), radius


def _frame(hinge: np.ndarray, axis: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The closed lid's frame (3, 3): x from the hinge to the start (across the axis), z = axis cross x
    (where the lid's edge goes as it opens, turning positively about ``axis``), y = -axis."""
    x = np.asarray(start, dtype=np.float64) - hinge
    x -= (x @ axis) * axis
    x /= np.linalg.norm(x)
    return np.column_stack([x, -axis, np.cross(axis, x)])


def build(robot: RobotModel, hinge: np.ndarray, axis: np.ndarray, length: float, start: np.ndarray,
          scene: LidScene = LidScene()) -> RobotModel:
    """``robot`` with the box, its lid on the hinge (``hinge`` (3,), unit ``axis`` (3,), world) of
    ``length`` m, closed toward the path's ``start`` (3,), and the handle the hand holds (module docstring).

    Returns
    -------
    RobotModel
        The same arm in the scene with the objects (its joint and actuator indices unchanged).
    """
    root = ET.fromstring(robot.mjcf_xml)
    tool_el, _ = objects.tool_body(root, robot)
    world = root.find("worldbody")
    assert world is not None   # a compiled robot's scene
    rot = _frame(hinge, axis, start)
    quat = objects.quaternion(rot)
    wood = "0.6 0.45 0.3 1"
    box = ET.SubElement(world, "body", {"name": _BOX, "pos": objects.fmt(hinge), "quat": objects.fmt(quat)})
    depth = max(float(hinge[2]) - scene.thickness, 0.02)   # down to the table (the hinge near level)
    objects.geom(box, 0.6, name=f"{_BOX}_shell", type="box", rgba="0.45 0.33 0.2 1",
                 size=[length / 2, scene.width / 2, depth / 2], pos=[length / 2, 0.0, -depth / 2 - scene.thickness])
    m, t, w = scene.mass, scene.thickness, scene.width
    lid = objects.body(box, _LID, [0.0, 0.0, 0.0], m,
                       [m * (w ** 2 + t ** 2) / 12, m * (length ** 2 + t ** 2) / 12, m * (length ** 2 + w ** 2) / 12],
                       com=[length / 2, 0.0, -t / 2])
    ET.SubElement(lid, "joint", {"name": _LID, "type": "hinge", "axis": "0 -1 0", "pos": "0 0 0",
                                 "damping": objects.fmt(scene.damping), "frictionloss": objects.fmt(scene.friction),
                                 "range": objects.fmt(np.radians([-5.0, 175.0])), "limited": "true"})
    objects.geom(lid, 0.6, name=f"{_LID}_plate", type="box", size=[length / 2, w / 2, t / 2],
                 pos=[length / 2, 0.0, -t / 2], rgba=wood)
    hm = scene.handle_mass
    handle = objects.body(lid, _HANDLE, [length, 0.0, 0.0], hm, [hm * 1e-4] * 3)
    for name, direction in (("along", "1 0 0"), ("across", "0 1 0")):
        ET.SubElement(handle, "joint", {"name": f"{_HANDLE}_{name}", "type": "slide", "axis": direction,
                                        "range": objects.fmt([-scene.slide, scene.slide]), "limited": "true",
                                        "damping": "1"})
    objects.geom(handle, 0.6, name=f"{_HANDLE}_bar", type="capsule", size=[0.008, 0.02],
                 quat=[0.7071067811865476, 0.7071067811865476, 0.0, 0.0], rgba="0.2 0.2 0.2 1",
                 contype="0", conaffinity="0")
    ET.SubElement(handle, "site", {"name": _HANDLE, "pos": "0 0 0"})
    equality = root.find("equality")
    if equality is None:
        equality = ET.SubElement(root, "equality")
    ET.SubElement(equality, "connect", {"name": GRIP, "site1": _HANDLE, "site2": robot.mj_ee_site,
                                        "solref": "0.01 1"})
    objects.grow_table(root, hinge, length + 0.1)
    return objects.compiled(robot, root, "lid")


def hold_lid(model: mujoco.MjModel, data: mujoco.MjData, scene: LidScene = LidScene()) -> None:
    """Open the lid (at rest) and slide its handle so that the handle is where the hand is in ``data``
    (the kinematics are computed here): the lid's angle takes the hand's height above the closed lid,
    the slides the rest; then switch the grip on."""
    names = (_LID, f"{_HANDLE}_along", f"{_HANDLE}_across")
    qadr = [int(model.joint(n).qposadr[0]) for n in names]
    data.qpos[qadr] = 0.0
    data.qvel[[int(model.joint(n).dofadr[0]) for n in names]] = 0.0
    mujoco.mj_kinematics(model, data)
    eq = model.equality(GRIP).id
    box = model.body(_BOX).id
    hand = data.site_xpos[int(model.eq_obj2id[eq])]
    x, y, z = data.xmat[box].reshape(3, 3).T @ (hand - data.xpos[box])   # the hand in the hinge's frame
    length = float(model.body(_HANDLE).pos[0])
    data.qpos[qadr[0]] = np.arctan2(z, x)           # its edge at (L cos a, 0, L sin a) at angle a
    data.qpos[qadr[1]] = np.clip(np.hypot(x, z) - length, -scene.slide, scene.slide)
    data.qpos[qadr[2]] = np.clip(y, -scene.slide, scene.slide)
    data.eq_active[eq] = 1


def lid_angle_deg(model: mujoco.MjModel, qpos: np.ndarray) -> float:
    """The lid's opening angle in the state ``qpos`` (nq,), deg (0: closed)."""
    return float(np.degrees(qpos[int(model.joint(_LID).qposadr[0])]))


class LidCheck:
    """The opening's success, online, on a simulation's current state (what a dm_env task's reward reads):
    the conditions of ``outcome`` checked at every step, not once after the motion: true when the lid is
    open past ``OPEN_DEG`` and the handle has stayed in the hand (never at the end of its slide, the grip
    never stretched past ``STRETCH_M``). ``reset`` at each episode's start."""

    def __init__(self, model: mujoco.MjModel, scene: LidScene = LidScene()) -> None:
        eq = model.equality(GRIP).id
        self._hinge = int(model.joint(_LID).qposadr[0])
        self._slides = [int(model.joint(f"{_HANDLE}_{n}").qposadr[0]) for n in ("along", "across")]
        self._handle, self._hand = int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])
        self._limit = scene.slide - 1e-3
        self.lost = False

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """A new episode: the handle in the hand."""
        self.lost = False

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> bool:
        self.lost = self.lost or bool(np.any(np.abs(data.qpos[self._slides]) >= self._limit)) or \
            float(np.linalg.norm(data.site_xpos[self._hand] - data.site_xpos[self._handle])) > STRETCH_M
        return not self.lost and bool(np.degrees(data.qpos[self._hinge]) >= OPEN_DEG)


def outcome(model: mujoco.MjModel, frame_t: np.ndarray, frame_qpos: np.ndarray, motion_end_s: float,
            scene: LidScene = LidScene()) -> dict[str, Any]:
    """The opening's success from the recorded physics states (module docstring).

    Parameters
    ----------
    model : mujoco.MjModel
        The scene of ``build``.
    frame_t, frame_qpos : ndarray, shape (F,) and (F, nq)
        The run's recorded times and full joint states (a ``RunTrace``'s video frames).
    motion_end_s : float
        When the motion ends, s; the lid is judged ``SETTLE_AFTER_S`` later.

    Returns
    -------
    dict
        ``angle_deg`` (when judged), ``max_angle_deg``, ``stretch_m`` (the grip's largest), ``slid_out``
        (the handle reached the end of its slide), ``success`` and ``cause`` (None, ``lost the lid`` or
        ``not opened``).
    """
    data = mujoco.MjData(model)
    eq = model.equality(GRIP).id
    handle, hand = int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])
    slides = [int(model.joint(f"{_HANDLE}_{n}").qposadr[0]) for n in ("along", "across")]
    k_judge = int(np.argmin(np.abs(frame_t - (motion_end_s + SETTLE_AFTER_S))))
    stretch, slid, angles = 0.0, False, []
    for qpos in frame_qpos[:k_judge + 1]:
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        stretch = max(stretch, float(np.linalg.norm(data.site_xpos[hand] - data.site_xpos[handle])))
        slid = slid or bool(np.any(np.abs(qpos[slides]) >= scene.slide - 1e-3))
        angles.append(lid_angle_deg(model, qpos))
    angle = angles[-1]
    lost = slid or stretch > STRETCH_M
    success = not lost and angle >= OPEN_DEG
    cause = None if success else "lost the lid" if lost else "not opened"
    return {"angle_deg": angle, "max_angle_deg": max(angles), "stretch_m": stretch, "slid_out": slid,
            "judged_at_s": float(frame_t[k_judge]), "success": bool(success), "cause": cause}
