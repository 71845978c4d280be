"""load_robot: a built-in arm ("planar", "panda") or any URDF/MJCF file, in MuJoCo and Pinocchio from the same source.

Every non-fixed 1-DoF joint left after locking is an arm joint. The MuJoCo site ``mj_ee_site`` is placed at the
Pinocchio frame ``ee_frame`` and checked against it; the scene (floor, lights, camera, actuators) is added with MjSpec.
"""

from __future__ import annotations

import importlib.metadata
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from robots import scene, sources, visual
from robots._mujoco import mujoco
from robots.errors import RobotError
from robots.model import RobotModel

BUILTIN_ROBOTS: tuple[str, ...] = ("planar", "panda")
ACTUATIONS: tuple[str, ...] = ("position", "torque")
# the built-in MJCF files: package data of ``robots`` (robots/assets links to the repository's assets/,
# where they live; an installed wheel holds a copy), else the repository's folder itself
ASSETS_DIR = next((d for d in (Path(__file__).resolve().parent / "assets",
                               Path(__file__).resolve().parent.parent / "assets") if d.is_dir()),
                  Path(__file__).resolve().parent / "assets")

DEFAULT_V_MAX_REVOLUTE = 2.0   # rad/s, when the file gives no velocity limit
DEFAULT_V_MAX_PRISMATIC = 0.5  # m/s
_FRAME_CHECK_TOL = 1e-9


@dataclass(frozen=True)
class _Source:
    """What is known about a robot before loading: file, tool frame, locked joints and per-robot settings."""

    name: str
    path: Path
    ee_frame: str
    locked: dict[str, float] = field(default_factory=dict)
    q_home: tuple[float, ...] | None = None
    armature: float | None = None   # None keeps the file's value
    damping: float | None = None


def _example_robot_data() -> Path:
    """The share folder of the example-robot-data package (installed through cmeel)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise RobotError("robot 'panda' needs the example-robot-data package") from None
    # ignore: typeshed types locate_file as SimplePath; it returns a pathlib.Path
    root = Path(dist.locate_file("cmeel.prefix/share/example-robot-data"))  # type: ignore[arg-type]
    if not root.is_dir():
        raise RobotError(f"example-robot-data files not found at {root}")
    return root


def _builtin(name: str) -> _Source:
    if name == "planar":
        return _Source("planar", ASSETS_DIR / "planar_arm.xml", "ee", q_home=(-1.0, 1.4, 1.2))
    # Franka Panda: fingers locked closed (they add 2 x 4.8 cm of width to the hand when open, which the
    # tool-point obstacle margin would have to cover; closed, the fingertip geoms lie within 2.3 cm of the TCP);
    # armature 0.1 kg m^2 and damping 1 N m s/rad per joint
    # (reflected rotor inertia and gear friction of the real arm's drives; they keep the 500 Hz servo loop stiff).
    urdf = _example_robot_data() / "robots" / "panda_description" / "urdf" / "panda.urdf"
    return _Source("panda", urdf, "panda_hand_tcp",
                   locked={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0},
                   q_home=(0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4),
                   armature=0.1, damping=1.0)


def _resolve(spec: str, ee_frame: str | None) -> _Source:
    if spec in BUILTIN_ROBOTS:
        source = _builtin(spec)
        return source if ee_frame is None else replace(source, ee_frame=ee_frame)
    path = Path(spec).expanduser()
    if path.suffix.lower() not in (".urdf", ".xml"):
        raise RobotError(f"unknown robot '{spec}'; built-in: {', '.join(BUILTIN_ROBOTS)}, or a path to .urdf/.xml")
    if not path.is_file():
        raise RobotError(f"robot file not found: {path}")
    if ee_frame is None:
        raise RobotError(f"robot file '{path}' needs an end-effector frame (ee_frame=...)")
    return _Source(path.stem, path.resolve(), ee_frame)


def _limits(model: pin.Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q_min, q_max, v_max), shape (n,): the file's limits; missing ones become +-pi / +-1 m and 2 rad/s / 0.5 m/s."""
    prismatic = np.array([model.joints[j].shortname().startswith("JointModelP") for j in range(1, model.njoints)])
    big = np.abs(model.lowerPositionLimit) > 1e6
    q_min = np.where(big, np.where(prismatic, -1.0, -np.pi), model.lowerPositionLimit)
    big = np.abs(model.upperPositionLimit) > 1e6
    q_max = np.where(big, np.where(prismatic, 1.0, np.pi), model.upperPositionLimit)
    v_default = np.where(prismatic, DEFAULT_V_MAX_PRISMATIC, DEFAULT_V_MAX_REVOLUTE)
    v = model.velocityLimit
    v_max = np.where(np.isfinite(v) & (v > 0) & (v < 1e6), v, v_default)
    return q_min.astype(float), q_max.astype(float), v_max.astype(float)


def _auto_home(model: pin.Model, frame_id: int, q_min: np.ndarray, q_max: np.ndarray, planar: bool) -> np.ndarray:
    """A well-conditioned posture: the candidate (mid-range, then 255 seeded ones in the middle half of the ranges)
    whose position Jacobian J_p (3, n) (rows x, y for a planar arm) has the largest smallest singular value,
    tool above z = 0.05 m if possible."""
    rows = 2 if planar else 3
    data = model.createData()
    rng = np.random.default_rng(0)
    mid, half = (q_min + q_max) / 2, (q_max - q_min) / 4
    candidates = np.vstack([mid, mid + rng.uniform(-1.0, 1.0, (255, model.nq)) * half])
    best, best_score = mid, -np.inf
    for q in candidates:
        jac = pin.computeFrameJacobian(model, data, q, frame_id, pin.LOCAL_WORLD_ALIGNED)[:rows]
        sv = np.linalg.svd(jac, compute_uv=False)
        score = sv[min(len(sv), model.nv) - 1] - (data.oMf[frame_id].translation[2] < 0.05)
        if score > best_score:
            best, best_score = q, score
    return best


def _frame_id(model: pin.Model, name: str) -> int:
    if not model.existFrame(name):
        names = ", ".join(f.name for f in model.frames)
        raise RobotError(f"unknown end-effector frame '{name}'; frames: {names}")
    fid = model.getFrameId(name)
    if model.frames[fid].parentJoint == 0:
        raise RobotError(f"end-effector frame '{name}' is not moved by any arm joint")
    return fid


def _set_qpos(mj_model: mujoco.MjModel, mj_data: mujoco.MjData, qpos_adr: np.ndarray, q: np.ndarray) -> None:
    mj_data.qpos[:] = mj_model.qpos0
    mj_data.qpos[qpos_adr] = q
    mujoco.mj_kinematics(mj_model, mj_data)


def _place_ee_site(spec: mujoco.MjSpec, mj_model: mujoco.MjModel, pin_model: pin.Model, frame_id: int,
                   qpos_adr: np.ndarray, q: np.ndarray) -> str:
    """Name of a MuJoCo site at the Pinocchio frame: an existing site of that name, else a new site 'ee'
    (at the origin of the body of that name, or at the frame's pose relative to the body of its parent joint)."""
    name = pin_model.frames[frame_id].name
    if spec.site(name) is not None:
        return name
    site_name = "ee" if spec.site("ee") is None else f"ee_{name}"
    body = spec.body(name)
    if body is not None:
        body.add_site(name=site_name, size=[0.01, 0.0, 0.0], rgba=[0.9, 0.2, 0.2, 1.0], group=3)
        return site_name
    data = pin_model.createData()
    pin.framesForwardKinematics(pin_model, data, q)
    joint_name = pin_model.names[pin_model.frames[frame_id].parentJoint]
    bid = mj_model.jnt_bodyid[mj_model.joint(joint_name).id]
    mj_data = mujoco.MjData(mj_model)
    _set_qpos(mj_model, mj_data, qpos_adr, q)
    rot_b = mj_data.xmat[bid].reshape(3, 3)
    frame = data.oMf[frame_id]
    pos = rot_b.T @ (frame.translation - mj_data.xpos[bid])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (rot_b.T @ frame.rotation).ravel())
    spec.body(mj_model.body(bid).name).add_site(name=site_name, pos=pos, quat=quat, size=[0.01, 0.0, 0.0],
                                               rgba=[0.9, 0.2, 0.2, 1.0], group=3)
    return site_name


def _camera(pin_model: pin.Model, frame_id: int, q_home: np.ndarray, planar: bool) -> tuple[np.ndarray, np.ndarray]:
    """(eye, target) of the 'workspace' camera. Planar arm: from above (tilted 20 deg), centred between base and tool
    at home. Other arms: aimed at the region in front of the robot around the tool's home position, from the
    front-right and above. The distance scales with the reach r = |p_tool(q_home) - p_base| (base on the floor)."""
    data = pin_model.createData()
    pin.framesForwardKinematics(pin_model, data, q_home)
    tool = data.oMf[frame_id].translation.copy()
    base = data.oMi[1].translation.copy()
    base[2] = 0.0
    reach = max(float(np.linalg.norm(tool - base)), 0.3)
    if planar:
        target = np.array([(tool[0] + base[0]) / 2, (tool[1] + base[1]) / 2, tool[2]])
        direction, distance = np.array([0.0, -0.36, 1.0]), 2.2 * reach
    else:
        target = np.array([tool[0] * 1.1, tool[1], tool[2] * 0.7])
        direction, distance = np.array([0.9, -1.3, 0.7]), 2.0 * reach
    eye = target + distance * direction / np.linalg.norm(direction)
    return eye, target


def _table_extent(pin_model: pin.Model, frame_id: int, q_home: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), shape (2,) each: the (x, y) rectangle of a table top under the base and the tool's
    home position with 0.3 m to spare on every side."""
    data = pin_model.createData()
    pin.framesForwardKinematics(pin_model, data, q_home)
    pts = np.array([data.oMi[1].translation[:2], data.oMf[frame_id].translation[:2]])
    return pts.min(0) - 0.3, pts.max(0) + 0.3


def _is_planar(pin_model: pin.Model, q: np.ndarray) -> bool:
    """All arm joints revolute about world z at q (then at every q: z axes stay z under rotations about z),
    so gravity does no work and the task is the (x, y) position."""
    data = pin_model.createData()
    pin.computeJointJacobians(pin_model, data, q)
    jac = data.J  # (6, n) world frame
    return bool(np.allclose(jac[[2, 3, 4]], 0.0, atol=1e-12) and np.allclose(np.abs(jac[5]), 1.0, atol=1e-12))


def _resolve_visual(uri: str, urdf_dir: Path) -> Path:
    try:
        return sources.resolve_uri(uri, urdf_dir)
    except RobotError as e:
        raise ValueError(str(e)) from None


def _compile_arm(mj_spec: mujoco.MjSpec, source: _Source, joints: tuple[str, ...]
                 ) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """Lock the source's fixed joints, set its armature and damping, and compile the bare arm.

    Returns the MuJoCo model and, shape (n,) each, the qpos and dof addresses of ``joints``.
    """
    sources.drop_joint_couplings(mj_spec, joints + tuple(source.locked))
    sources.lock_mujoco_joints(mj_spec, source.locked)
    for name in joints:
        joint = mj_spec.joint(name)
        if joint is None:
            raise RobotError(f"joint '{name}' is in Pinocchio's model but not in MuJoCo's")
        if source.armature is not None:
            joint.armature = source.armature
        if source.damping is not None:
            joint.damping = [source.damping, 0.0, 0.0]
    mj_spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    try:
        mj_model = mj_spec.compile()
    except ValueError as exc:
        raise RobotError(f"MuJoCo cannot compile '{source.path}': {exc}") from None
    qpos_adr = np.array([mj_model.jnt_qposadr[mj_model.joint(j).id] for j in joints], dtype=int)
    dof_adr = np.array([mj_model.jnt_dofadr[mj_model.joint(j).id] for j in joints], dtype=int)
    return mj_model, qpos_adr, dof_adr


def _servo_gains(mj_model: mujoco.MjModel, pin_model: pin.Model, joints: tuple[str, ...], qpos_adr: np.ndarray,
                 dof_adr: np.ndarray, q_home: np.ndarray) -> list[tuple[float, float, float]]:
    """(kp, kv, force limit) per arm joint: the source's own position servo where it has one, else
    kp = M_ii(q_home) w^2 and kv = 2 zeta w M_ii (``robots.scene``), limited by the URDF effort."""
    mj_data = mujoco.MjData(mj_model)
    _set_qpos(mj_model, mj_data, qpos_adr, q_home)
    mujoco.mj_fwdPosition(mj_model, mj_data)
    mass = np.zeros((mj_model.nv, mj_model.nv))
    mujoco.mj_fullM(mj_model, mj_data, mass)
    diag = mass[dof_adr, dof_adr]
    gains = []
    for i, name in enumerate(joints):
        found = scene.source_servo_gains(mj_model, name)
        effort = float(pin_model.effortLimit[i]) if 0 < pin_model.effortLimit[i] < 1e6 else np.inf
        if found is None:
            w, z = scene.SERVO_OMEGA, scene.SERVO_ZETA
            gains.append((diag[i] * w * w, 2 * z * w * diag[i], effort))
        else:
            gains.append((found[0], found[1], min(found[2], effort)))
    return gains


def _build_scene(mj_spec: mujoco.MjSpec, assets: dict[str, bytes], source: _Source, pin_model: pin.Model,
                 frame_id: int, joints: tuple[str, ...], actuation: str, q_home: np.ndarray,
                 limits: tuple[np.ndarray, np.ndarray], gains: list[tuple[float, float, float]],
                 table: bool) -> tuple[str, mujoco.MjModel]:
    """Add actuators, floor, lights, camera (and a table) to the arm; returns the exact MJCF and its model."""
    planar = _is_planar(pin_model, (limits[0] + limits[1]) / 2)
    scene.add_actuators(mj_spec, joints, actuation, limits[0], limits[1], gains)
    scene.add_environment(mj_spec, *_camera(pin_model, frame_id, q_home, planar),
                          floor_z=-scene.TABLE_HEIGHT if table else 0.0)
    if table:
        scene.add_table(mj_spec, *_table_extent(pin_model, frame_id, q_home))
    try:
        compiled = mj_spec.compile()
        mjcf_xml = scene.exact_xml(mj_spec, compiled)
        return mjcf_xml, mujoco.MjModel.from_xml_string(mjcf_xml, assets)
    except ValueError as exc:
        raise RobotError(f"MuJoCo cannot compile the scene of '{source.path}': {exc}") from None


def load_robot(spec: str, ee_frame: str | None = None, actuation: str = "position", visuals: bool = True,
               table: bool = False) -> RobotModel:
    """Load an arm in MuJoCo and Pinocchio.

    Parameters
    ----------
    spec, ee_frame : str, and str or None
        ``"planar"``, ``"panda"`` or a .urdf / MJCF .xml path; the tool's Pinocchio frame (required for a path).
    actuation : str
        ``"position"`` (PD servos + gravity compensation) or ``"torque"`` (motors, ctrl = joint torque).
        Checked here only: the robot carries it (``RobotModel.actuation``) to the simulation.
    visuals, table : bool
        Draw a URDF's <visual> meshes (converted once into a user cache, ``robots.visual``; False: the
        collision meshes, a colour per link); add a table under the workspace. Neither collides.

    Returns
    -------
    RobotModel
        The arm (``RobotError``: unknown robot, frame or actuation, or a file the engines read differently).
    """
    if actuation not in ACTUATIONS:
        raise RobotError(f"unknown actuation '{actuation}'; known: {', '.join(ACTUATIONS)}")
    source = _resolve(spec, ee_frame)
    kind = sources.source_kind(source.path)
    mj_spec, assets = sources.urdf_spec(source.path) if kind == "urdf" else sources.mjcf_spec(source.path)
    if kind == "urdf":
        _add_visuals(mj_spec, source, assets, visuals)
    pin_model = sources.pinocchio_model(source.path, kind, source.locked)
    frame_id = _frame_id(pin_model, source.ee_frame)
    joints = tuple(pin_model.names[1:])
    mj_model, qpos_adr, dof_adr = _compile_arm(mj_spec, source, joints)
    pin_model.armature = mj_model.dof_armature[dof_adr].copy()
    pin_model.damping = mj_model.dof_damping[dof_adr].copy()

    q_min, q_max, v_max = _limits(pin_model)
    planar = _is_planar(pin_model, (q_min + q_max) / 2)
    if source.q_home is None:
        q_home = _auto_home(pin_model, frame_id, q_min, q_max, planar)
    else:
        q_home = np.array(source.q_home, dtype=float)

    mj_ee_site = _place_ee_site(mj_spec, mj_model, pin_model, frame_id, qpos_adr, q_home)
    gains = _servo_gains(mj_model, pin_model, joints, qpos_adr, dof_adr, q_home)
    mjcf_xml, mj_model = _build_scene(mj_spec, assets, source, pin_model, frame_id, joints, actuation, q_home,
                                      (q_min, q_max), gains, table)

    robot = RobotModel(
        name=source.name, mjcf_xml=mjcf_xml, mj_assets=assets, mj_model=mj_model, pin_model=pin_model,
        ee_frame=source.ee_frame, mj_ee_site=mj_ee_site, arm_joints=joints,
        mj_qpos_adr=np.array([mj_model.jnt_qposadr[mj_model.joint(j).id] for j in joints], dtype=int),
        mj_dof_adr=np.array([mj_model.jnt_dofadr[mj_model.joint(j).id] for j in joints], dtype=int),
        mj_actuator_ids=np.array([mj_model.actuator(f"act_{j}").id for j in joints], dtype=int),
        q_home=q_home, q_min=q_min, q_max=q_max, v_max=v_max, planar=planar, actuation=actuation,
    )
    _check_ee_site(robot, frame_id)
    for array in (robot.mj_qpos_adr, robot.mj_dof_adr, robot.mj_actuator_ids, robot.q_home, robot.q_min, robot.q_max,
                  robot.v_max):
        array.setflags(write=False)
    return robot


def _add_visuals(mj_spec: mujoco.MjSpec, source: _Source, assets: dict[str, bytes], enabled: bool) -> None:
    """Add a URDF's visual meshes (``robots.visual``); warn once about links drawn with their collision meshes."""
    report = visual.add_visuals(mj_spec, source.path, assets, _resolve_visual, enabled=enabled)
    if report.fallback:
        first = next(iter(report.fallback.items()))
        warnings.warn(f"{source.name}: {len(report.fallback)} link(s) drawn with their collision meshes "
                      f"({first[0]}: {first[1]})", RuntimeWarning, stacklevel=3)


def _check_ee_site(robot: RobotModel, frame_id: int) -> None:
    """The MuJoCo site and the Pinocchio frame must coincide at q_home (else the two models disagree)."""
    data = robot.pin_model.createData()
    pin.framesForwardKinematics(robot.pin_model, data, robot.q_home)
    mj_data = mujoco.MjData(robot.mj_model)
    _set_qpos(robot.mj_model, mj_data, robot.mj_qpos_adr, robot.q_home)
    site = robot.mj_model.site(robot.mj_ee_site).id
    frame = data.oMf[frame_id]
    err = max(np.abs(mj_data.site_xpos[site] - frame.translation).max(),
              np.abs(mj_data.site_xmat[site].reshape(3, 3) - frame.rotation).max())
    if err > _FRAME_CHECK_TOL:
        raise RobotError(f"MuJoCo site '{robot.mj_ee_site}' and Pinocchio frame '{robot.ee_frame}' differ by "
                         f"{err:.2e} at q_home: the file uses a feature one of the two engines reads differently")
