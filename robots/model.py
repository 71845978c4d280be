"""The loaded robot: one source file compiled into a MuJoCo scene and a Pinocchio model that agree joint by joint."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
import pinocchio

if TYPE_CHECKING:
    import mujoco


class ArmModel(Protocol):
    """What the kinematics, the differential IK, the limits and the controller read of an arm: its
    Pinocchio model and tool frame, joint names, home posture and joint limits. ``RobotModel`` (both
    engines) and ``robots.pinocchio_arm.PinocchioArm`` (Pinocchio alone, no MuJoCo) are ``ArmModel``s.

    Attributes
    ----------
    name : str
    pin_model : pinocchio.Model
        The arm joints only.
    ee_frame : str
        The tool's Pinocchio frame.
    arm_joints : tuple of str, length n
    q_home, q_min, q_max, v_max : ndarray, shape (n,)
    planar : bool
    n : int
    """

    @property
    def name(self) -> str: ...
    @property
    def pin_model(self) -> pinocchio.Model: ...
    @property
    def ee_frame(self) -> str: ...
    @property
    def arm_joints(self) -> tuple[str, ...]: ...
    @property
    def q_home(self) -> np.ndarray: ...
    @property
    def q_min(self) -> np.ndarray: ...
    @property
    def q_max(self) -> np.ndarray: ...
    @property
    def v_max(self) -> np.ndarray: ...
    @property
    def planar(self) -> bool: ...
    @property
    def n(self) -> int: ...


@dataclass(frozen=True)
class RobotModel:
    """A robot arm in both engines (n arm joints). The arrays are read-only (copy before modifying).

    Attributes
    ----------
    name : str
    mjcf_xml : str
        Full MuJoCo scene (robot, floor, lights, camera "workspace", actuators); compile it with ``mj_assets``.
    mj_assets : dict of str to bytes
    mj_model : mujoco.MjModel
    pin_model : pinocchio.Model
        The arm joints only (fingers and other locked joints removed).
    ee_frame, mj_ee_site : str
        The tool's Pinocchio frame and the MuJoCo site placed on it.
    arm_joints : tuple of str, length n
        Controlled joint names in Pinocchio q order; the mj_* index arrays follow that order.
    mj_qpos_adr, mj_dof_adr, mj_actuator_ids : ndarray of int, shape (n,)
    q_home, q_min, q_max, v_max : ndarray, shape (n,)
        Home posture and joint position / velocity limits.
    planar : bool
        True when every arm joint turns about world z, so the task is the 2-D position (rows x, y).
    actuation : str
        ``"position"`` (a PD servo with gravity compensation per arm joint) or ``"torque"`` (a motor per
        arm joint, ctrl = joint torque): what ``load_robot`` built into the scene, and the one source
        the simulation (``sim.control.controller``, ``sim.Experiment``) reads it from.
    """

    name: str
    mjcf_xml: str
    mj_assets: dict[str, bytes]
    mj_model: mujoco.MjModel
    pin_model: pinocchio.Model
    ee_frame: str
    mj_ee_site: str
    arm_joints: tuple[str, ...]
    mj_qpos_adr: np.ndarray
    mj_dof_adr: np.ndarray
    mj_actuator_ids: np.ndarray
    q_home: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    planar: bool
    actuation: str

    @property
    def n(self) -> int:
        """Number of arm joints."""
        return len(self.arm_joints)
