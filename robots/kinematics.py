"""Forward kinematics of the tool frame with Pinocchio, lean enough for a 500 Hz control loop."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from robots.model import ArmModel

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class Kinematics:
    """Tool pose and Jacobian at a joint configuration.

    update(q) runs Pinocchio's computeFrameJacobian (forward kinematics of the tool's supporting joints included):
    p(q) (3,), R(q) (3, 3) and J(q) (6, n) in LOCAL_WORLD_ALIGNED, i.e. [v; w] = J(q) qdot with v the tool point's
    linear velocity and w its angular velocity, both in world axes. Getters return arrays valid until the next update
    (do not modify them).

    Attributes
    ----------
    jacobian : ndarray, shape (6, nv)
        J at the last update (``ee_jacobian``'s value, read as an attribute on the control loop's path).
    pose : tuple of (pin.SE3, ndarray, ndarray) or None
        The tool frame's placement, position (3,) and rotation (3, 3) at the last update, or None until
        ``read_pose`` computes it (``update`` reads it lazily; ``update_position`` at once). The control
        loop reads ``pose or read_pose()``: an attribute, and a call only when it is missing.
    """

    def __init__(self, robot: ArmModel) -> None:
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.frame_id = self.model.getFrameId(robot.ee_frame)
        self.jacobian = np.zeros((6, self.model.nv))
        self.pose: tuple[pin.SE3, np.ndarray, np.ndarray] | None = None

    def update(self, q: np.ndarray) -> None:
        """FK of the tool's supporting joints and tool Jacobian at q, shape (n,); the pose is read lazily."""
        self.jacobian = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id, _LWA)
        self.pose = None

    def update_position(self, q: np.ndarray) -> np.ndarray:
        """``update(q)`` and the tool position, shape (3,), in one call (the control loop's FK)."""
        model, data, fid = self.model, self.data, self.frame_id
        self.jacobian = pin.computeFrameJacobian(model, data, q, fid, _LWA)
        placement = pin.updateFramePlacement(model, data, fid)
        self.pose = pose = (placement, placement.translation, placement.rotation)
        return pose[1]

    def read_pose(self) -> tuple[pin.SE3, np.ndarray, np.ndarray]:
        """The tool pose at the last update, computed on first use after it (``pose``).

        Returns
        -------
        placement : pin.SE3
            The tool frame in world.
        position : ndarray, shape (3,)
            Its translation (a view of ``placement``).
        rotation : ndarray, shape (3, 3)
            Its rotation (a view of ``placement``).
        """
        if self.pose is None:
            placement = pin.updateFramePlacement(self.model, self.data, self.frame_id)
            self.pose = (placement, placement.translation, placement.rotation)
        return self.pose

    def ee_position(self) -> np.ndarray:
        """Tool position in world, shape (3,)."""
        return self.read_pose()[1]

    def ee_rotation(self) -> np.ndarray:
        """Tool orientation in world, shape (3, 3)."""
        return self.read_pose()[2]

    def ee_jacobian(self) -> np.ndarray:
        """Tool Jacobian [v; w] = J qdot, shape (6, n), LOCAL_WORLD_ALIGNED."""
        return self.jacobian
