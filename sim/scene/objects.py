"""MJCF parts shared by the scenes with objects (``sim.scene.pour``, ``sim.scene.place``): bodies with
explicit inertials, geoms on the objects' collision bit, the table grown under an object, the objects'
own table top, and the compiled scene.

The objects collide with each other and with their table top (collision bit 2), not with the arm (bit 0):
the hand holds what it carries through its fingers, and nothing is caught between them.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from typing import Any

import mujoco
import numpy as np

from robots import RobotModel
from sim.errors import SimError

#: the objects' collision bit (contype and conaffinity)
OBJECT_BIT = "2"


def fmt(values: Any) -> str:
    """Numbers as an MJCF attribute, space-separated, at full precision."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


def geom(parent: ET.Element, friction: float, **attrs: Any) -> ET.Element:
    """A geom of ``parent`` on the objects' collision bit with sliding ``friction``; ``attrs`` are its
    MJCF attributes (numbers or arrays formatted by ``fmt``)."""
    base = {"contype": OBJECT_BIT, "conaffinity": OBJECT_BIT, "friction": fmt([friction, 0.005, 0.0001])}
    return ET.SubElement(parent, "geom", {**base, **{k: v if isinstance(v, str) else fmt(v) for k, v in attrs.items()}})


def body(parent: ET.Element, name: str, pos: Any, mass: float, inertia: Any, quat: Any = (1.0, 0.0, 0.0, 0.0),
         com: Any = (0.0, 0.0, 0.0)) -> ET.Element:
    """A body with an explicit inertial at ``com`` (the robot's scene does not infer inertia from geoms)."""
    el = ET.SubElement(parent, "body", {"name": name, "pos": fmt(pos), "quat": fmt(quat)})
    ET.SubElement(el, "inertial", {"pos": fmt(com), "mass": fmt(mass), "diaginertia": fmt(inertia)})
    return el


def frame_along(axis: np.ndarray, site_quat: np.ndarray) -> np.ndarray:
    """The rotation, shape (3, 3), in the tool body's frame, of an object frame whose z is ``axis`` (3,),
    given in the tool site's frame (its orientation ``site_quat`` (4,) in the body); x is the site's
    y (or x, for an axis near y) crossed with z."""
    z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    site_rot = np.zeros(9)
    mujoco.mju_quat2Mat(site_rot, np.asarray(site_quat, dtype=np.float64))
    return site_rot.reshape(3, 3) @ np.column_stack([x, np.cross(z, x), z])


def quaternion(rot: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z), shape (4,), of a rotation matrix (3, 3) (MuJoCo's convention)."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot, dtype=np.float64).ravel())
    return q


def tool_body(root: ET.Element, robot: RobotModel) -> tuple[ET.Element, Any]:
    """The MJCF element of the body that carries the robot's tool site, and the site (``MjModel`` view)."""
    site = robot.mj_model.site(robot.mj_ee_site)
    name = robot.mj_model.body(int(site.bodyid[0])).name
    el = next((b for b in root.iter("body") if b.get("name") == name), None)
    if el is None:
        raise SimError(f"a scene with objects needs the tool body '{name}' in the robot's scene")
    return el, site


def grow_table(root: ET.Element, centre: np.ndarray, margin: float) -> None:
    """Grow the robot's table top (geom ``table_top``, if any) to reach ``margin`` m around ``centre``
    (x, y), so that an object stands on it."""
    top = next((g for g in root.iter("geom") if g.get("name") == "table_top"), None)
    if top is None:
        return
    c = np.array([float(v) for v in top.get("pos", "0 0 0").split()])
    half = np.array([float(v) for v in top.get("size", "0 0 0").split()])
    lo = np.minimum(c[:2] - half[:2], np.asarray(centre[:2]) - margin)
    hi = np.maximum(c[:2] + half[:2], np.asarray(centre[:2]) + margin)
    top.set("pos", fmt([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, c[2]]))
    top.set("size", fmt([(hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2, half[2]]))


def object_table(world: ET.Element, name: str, friction: float) -> None:
    """The table top for the objects, a plane at z = 0 (the robot's own top collides with the arm's bit only)."""
    geom(world, friction, name=name, type="plane", size=[0, 0, 1], pos=[0, 0, 0], rgba="0 0 0 0")


def compiled(robot: RobotModel, root: ET.Element, what: str) -> RobotModel:
    """``robot`` with its scene replaced by ``root``, compiled; ``SimError`` of one line if it does not."""
    xml = ET.tostring(root, encoding="unicode")
    try:
        model = mujoco.MjModel.from_xml_string(xml, dict(robot.mj_assets or {}))
    except ValueError as exc:
        raise SimError(f"the {what} scene does not compile: {str(exc).splitlines()[0]}") from None
    return dataclasses.replace(robot, mjcf_xml=xml, mj_model=model)
