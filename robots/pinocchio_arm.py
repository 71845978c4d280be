"""An arm from its URDF with Pinocchio alone: what a controller on a machine without MuJoCo needs.

``load_urdf_arm`` builds the arm's kinematic model from a URDF (meshes are not read), keeps the
named arm joints (or every revolute and prismatic joint in the chain to the tool frame) and locks
the others (fingers) at zero. The result is a ``robots.model.ArmModel``: ``robots.Kinematics``, the
DLS IK (``robots.DifferentialIK``), ``robots.limits`` and ``robots.controller.ArmController`` take it
as they take a ``RobotModel`` loaded with both engines.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from robots.errors import RobotError


@dataclass(frozen=True)
class PinocchioArm:
    """An ``ArmModel`` without a MuJoCo scene (fields as ``robots.model.RobotModel``'s).

    Attributes
    ----------
    name : str
    pin_model : pinocchio.Model
        The arm joints only.
    ee_frame : str
    arm_joints : tuple of str, length n
    q_home, q_min, q_max, v_max : ndarray, shape (n,)
        Home posture (the mid-range unless given) and the URDF's joint limits.
    planar : bool
        Always False: a URDF arm loaded here moves its tool in space.
    """

    name: str
    pin_model: pin.Model
    ee_frame: str
    arm_joints: tuple[str, ...]
    q_home: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    planar: bool = False

    @property
    def n(self) -> int:
        """Number of arm joints."""
        return len(self.arm_joints)


def load_urdf_arm(urdf: str | Path, ee_frame: str, joints: tuple[str, ...] | None = None,
                  q_home: np.ndarray | None = None, name: str | None = None,
                  tool: np.ndarray | None = None) -> PinocchioArm:
    """The arm of ``urdf`` with Pinocchio alone (module docstring).

    Parameters
    ----------
    urdf : str or Path
        The URDF file.
    ee_frame : str
        The tool frame (a link or joint name of the URDF).
    joints : tuple of str, optional
        The arm joints, in q order (default: the moving joints that support ``ee_frame``).
    q_home : ndarray, shape (n,), optional
        The posture the IK's null space pulls toward (default: the middle of each joint's range).
    name : str, optional
        The arm's name (default: the URDF's robot name).
    tool : ndarray, shape (4, 4), optional
        A tool mounted on ``ee_frame``: its pose in that frame (a homogeneous transform, m). The arm's
        tool frame is then a new frame ``tool`` there (e.g. a hand's centre point on a bare flange).

    Returns
    -------
    PinocchioArm

    Raises
    ------
    RobotError
        A missing or unreadable file, an unknown frame or joint, or a home posture of the wrong shape.
    """
    path = Path(urdf)
    if not path.is_file():
        raise RobotError(f"URDF file not found: {path}")
    try:
        full = pin.buildModelFromUrdf(str(path))
    except (RuntimeError, ValueError) as exc:
        raise RobotError(f"cannot read the URDF {path}: {str(exc).strip().splitlines()[0]}") from None
    if not full.existFrame(ee_frame):
        raise RobotError(f"frame '{ee_frame}' is not in {path.name}")
    if joints is None:
        support = full.supports[full.frames[full.getFrameId(ee_frame)].parentJoint]
        joints = tuple(full.names[j] for j in support if j > 0 and full.joints[j].nv == 1)
    unknown = [j for j in joints if not full.existJointName(j)]
    if unknown:
        raise RobotError(f"joint(s) {', '.join(unknown)} not in {path.name}")
    lock = [j for j in range(1, full.njoints) if full.names[j] not in joints]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    order = [model.joints[model.getJointId(j)].idx_q for j in joints]
    if order != list(range(len(joints))):
        raise RobotError(f"the arm joints must be given in the URDF's chain order: {', '.join(joints)}")
    if tool is not None:
        offset = np.asarray(tool, dtype=np.float64)
        if offset.shape != (4, 4) or not np.isfinite(offset).all():
            raise RobotError(f"the tool must be a finite 4 x 4 transform, got shape {offset.shape}")
        parent = model.frames[model.getFrameId(ee_frame)]
        model.addFrame(pin.Frame("tool", parent.parentJoint, model.getFrameId(ee_frame),
                                 parent.placement * pin.SE3(offset[:3, :3], offset[:3, 3]), pin.FrameType.OP_FRAME))
        ee_frame = "tool"
    q_min, q_max = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    v_max = model.velocityLimit.copy()
    home = (q_min + q_max) / 2 if q_home is None else np.asarray(q_home, dtype=np.float64).reshape(-1)
    if home.shape != (len(joints),) or not np.isfinite(home).all():
        raise RobotError(f"q_home must be {len(joints)} finite numbers, got {home.tolist()}")
    return PinocchioArm(name=name or model.name, pin_model=model, ee_frame=ee_frame, arm_joints=tuple(joints),
                        q_home=home, q_min=q_min, q_max=q_max, v_max=v_max)
