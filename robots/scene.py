"""The MuJoCo scene around an arm: floor, lights, camera "workspace", actuators, gravity compensation, and an exact XML.

Position actuation is a PD servo per arm joint, tau = kp (q_ref - q) - kv qdot, with kp = M_ii(q_home) w^2 and
kv = 2 zeta w M_ii (w = 60 rad/s, zeta = 1) unless the source file already had a position actuator on that joint;
gravity is compensated through the actuators (body gravcomp = 1, joint actuatorgravcomp), so it counts against the
force limits. Torque actuation is one motor per joint (ctrl = tau, no compensation).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from robots._mujoco import mujoco

SERVO_OMEGA = 60.0
SERVO_ZETA = 1.0
TIMESTEP = 0.002
FLOOR_HALF_M = 4.0   # the drawn floor is 8 m x 8 m


def source_servo_gains(model: mujoco.MjModel, joint: str) -> tuple[float, float, float] | None:
    """(kp, kv, force limit) of a position actuator already driving ``joint`` in the source, else None."""
    jid = model.joint(joint).id
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or model.actuator_trnid[a, 0] != jid:
            continue
        kp, bias = model.actuator_gainprm[a, 0], model.actuator_biasprm[a]
        if model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE and kp > 0 and np.isclose(bias[1], -kp):
            limit = float(model.actuator_forcerange[a, 1]) if model.actuator_forcelimited[a] else np.inf
            return float(kp), float(-bias[2]), limit
    return None


def add_actuators(spec: mujoco.MjSpec, joints: tuple[str, ...], actuation: str, q_min: np.ndarray,
                  q_max: np.ndarray, gains: list[tuple[float, float, float]]) -> None:
    """Replace the spec's actuators by one per arm joint, named act_<joint>; gains[i] = (kp, kv, force limit)."""
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for i, joint in enumerate(joints):
        kp, kv, limit = gains[i]
        act = spec.add_actuator(name=f"act_{joint}", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        if actuation == "position":
            act.set_to_position(kp=kp, kv=kv)
            act.ctrlrange = [q_min[i], q_max[i]]
            act.ctrllimited = True
            if np.isfinite(limit):
                act.forcerange = [-limit, limit]
                act.forcelimited = True
            spec.joint(joint).actgravcomp = True
        else:
            act.set_to_motor()
            if np.isfinite(limit):
                act.ctrlrange = [-limit, limit]
                act.ctrllimited = True
    if actuation == "position":
        for body in spec.bodies:
            if body.name != "world":
                body.gravcomp = 1.0


def _look_at_quat(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera quaternion looking from eye at target with world z up (MuJoCo cameras look along their -z)."""
    forward = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(forward, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(-forward, x)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([x, y, -forward]).ravel())
    return quat


def add_environment(spec: mujoco.MjSpec, eye: np.ndarray, target: np.ndarray, floor_z: float = 0.0) -> None:
    """Floor at height ``floor_z`` (unless the source has a geom 'floor': a colliding plane, hidden, and a
    thin box that draws it), sky, three lights (a key light
    from above the front, a fill light and a rim light from behind), the camera 'workspace' and render
    buffer size."""
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    spec.visual.headlight.specular = [0.1, 0.1, 0.1]
    world = spec.worldbody
    if spec.geom("floor") is None:
        spec.add_texture(name="floor_grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                         builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=512, height=512,
                         rgb1=[0.62, 0.65, 0.70], rgb2=[0.50, 0.53, 0.58],
                         mark=mujoco.mjtMark.mjMARK_EDGE, markrgb=[0.62, 0.64, 0.67])
        material = spec.add_material(name="floor_grid", texrepeat=[8, 8], texuniform=True, reflectance=0.05)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "floor_grid"
        # The plane collides and is hidden (group 3); a thin box draws the floor: a software renderer
        # (llvmpipe) is much slower on an infinite plane's many lit quads.
        world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05],
                       pos=[0.0, 0.0, floor_z], material="floor_grid", contype=1, conaffinity=1, group=3)
        world.add_geom(name="floor_visual", type=mujoco.mjtGeom.mjGEOM_BOX, size=[FLOOR_HALF_M, FLOOR_HALF_M, 0.005],
                       pos=[0.0, 0.0, floor_z - 0.005], material="floor_grid", contype=0, conaffinity=0)
    spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT, width=256, height=256,
                     rgb1=[0.55, 0.65, 0.8], rgb2=[0.95, 0.95, 0.97])
    world.add_light(name="key", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0.5, -1.0, 3.0],
                    dir=[-0.15, 0.3, -1.0], diffuse=[0.6, 0.6, 0.6], castshadow=True)
    world.add_light(name="fill", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[-1.0, 1.0, 2.0],
                    dir=[0.4, -0.4, -1.0], diffuse=[0.25, 0.25, 0.25], castshadow=False)
    world.add_light(name="rim", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[-1.5, 0.0, 1.5],
                    dir=[1.0, 0.0, -0.6], diffuse=[0.15, 0.15, 0.17], specular=[0.2, 0.2, 0.2],
                    castshadow=False)
    world.add_camera(name="workspace", pos=eye, quat=_look_at_quat(eye, target), fovy=45.0)


TABLE_HEIGHT = 0.75   # m: the table top is at z = 0 (the robot's base), the floor this far below


def add_table(spec: mujoco.MjSpec, lo: np.ndarray, hi: np.ndarray) -> None:
    """A wooden table whose top, 4 cm thick, covers the (x, y) rectangle [lo, hi] with its upper face
    at z = 0 (where the robot stands); the top collides like the floor did, the legs are drawn only."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    c, half = (lo + hi) / 2, (hi - lo) / 2
    spec.add_material(name="table_wood", rgba=[0.55, 0.38, 0.24, 1.0], specular=0.2, shininess=0.3)
    spec.add_material(name="table_leg", rgba=[0.25, 0.25, 0.27, 1.0], specular=0.4, shininess=0.5)
    world = spec.worldbody
    world.add_geom(name="table_top", type=mujoco.mjtGeom.mjGEOM_BOX, size=[half[0], half[1], 0.02],
                   pos=[c[0], c[1], -0.02], material="table_wood", contype=1, conaffinity=1)
    leg_h = (TABLE_HEIGHT - 0.04) / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            world.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.03, leg_h],
                           pos=[c[0] + sx * (half[0] - 0.06), c[1] + sy * (half[1] - 0.06), -0.04 - leg_h],
                           material="table_leg", contype=0, conaffinity=0)


def _fmt(values: np.ndarray) -> str:
    """Floats written so that they read back bit-exact."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


_ORIENTATION_ATTRS = ("quat", "euler", "axisangle", "xyaxes", "zaxis")


def _set_pose(elem: ET.Element, pos: np.ndarray, quat: np.ndarray) -> None:
    for key in _ORIENTATION_ATTRS:
        elem.attrib.pop(key, None)
    elem.set("pos", _fmt(pos))
    elem.set("quat", _fmt(quat))


def exact_xml(spec: mujoco.MjSpec, model: mujoco.MjModel) -> str:
    """The spec's MJCF with body/inertial/joint/site numbers from the compiled model at full double precision.

    MuJoCo's writer keeps 6 significant digits, which moves a URDF's rpy-derived frames by ~1e-6; the kinematic and
    inertial numbers are rewritten from ``model`` (same element order as the model's ids) so that the XML compiles back
    to the same model. Files using <frame> elements are returned as MuJoCo writes them.
    """
    root = ET.fromstring(spec.to_xml())
    if root.find(".//frame") is not None:
        return ET.tostring(root, encoding="unicode")
    world = root.find("worldbody")
    assert world is not None
    bodies = list(world.iter("body"))
    joints = [j for b in bodies for j in b.findall("joint")]
    sites = [s for b in [world, *bodies] for s in b.findall("site")]
    if len(bodies) != model.nbody - 1 or len(joints) != model.njnt or len(sites) != model.nsite:
        return ET.tostring(root, encoding="unicode")
    for bid, elem in enumerate(bodies, start=1):
        _set_pose(elem, model.body_pos[bid], model.body_quat[bid])
        inertial = elem.find("inertial")
        if inertial is None and model.body_mass[bid] > 0:
            inertial = ET.Element("inertial")
            elem.insert(0, inertial)
        if inertial is not None:
            inertial.attrib.pop("fullinertia", None)
            _set_pose(inertial, model.body_ipos[bid], model.body_iquat[bid])
            inertial.set("mass", _fmt(model.body_mass[bid]))
            inertial.set("diaginertia", _fmt(model.body_inertia[bid]))
    for jid, elem in enumerate(joints):
        elem.set("pos", _fmt(model.jnt_pos[jid]))
        elem.set("axis", _fmt(model.jnt_axis[jid]))
    for sid, elem in enumerate(sites):
        _set_pose(elem, model.site_pos[sid], model.site_quat[sid])
    return ET.tostring(root, encoding="unicode")
