"""The loaded robot: one source file compiled into a MuJoCo scene and a Pinocchio model that agree joint by joint."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio


@dataclass(frozen=True)
class RobotModel:
    """A robot arm in both engines.

    mjcf_xml : full MuJoCo scene (robot, floor, lights, camera "workspace", actuators); compile it with ``mj_assets``.
    pin_model : Pinocchio model of the arm joints only (fingers and other locked joints removed).
    arm_joints : controlled joint names in Pinocchio q order; the mj_* index arrays, shape (n,), follow that order.
    q_home, q_min, q_max, v_max : array, shape (n,): home posture and joint position / velocity limits.
    planar : True when every arm joint turns about world z, so the task is the 2-D position (rows x, y).
    The arrays are read-only (copy before modifying).
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

    @property
    def n(self) -> int:
        """Number of arm joints."""
        return len(self.arm_joints)
