"""Differential IK chosen by name ("dls", "pink") from a small registry, and iterative position IK."""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

import numpy as np

from robots.errors import RobotError
from robots.ik.gains import JointGains
from robots.ik.position import solve_pose_ik, solve_position_ik
from robots.kinematics import Kinematics
from robots.model import ArmModel

_REGISTRY: dict[str, tuple[str, str, str]] = {
    "dls": ("robots.ik.dls", "DlsBackend", "DlsGains"),
    "pink": ("robots.ik.pink_qp", "PinkBackend", "PinkGains"),
}
IK_BACKENDS: tuple[str, ...] = tuple(_REGISTRY)


def _check_rows(rows: tuple[int, ...] | None, robot: ArmModel) -> tuple[int, ...]:
    if rows is None:
        return (0, 1) if robot.planar else (0, 1, 2, 3, 4, 5)
    rows = tuple(int(r) for r in rows)
    if not rows or len(set(rows)) != len(rows) or any(r < 0 or r > 5 for r in rows):
        raise RobotError(f"IK rows must be distinct twist rows in 0..5 (vx vy vz wx wy wz), got {rows}")
    return tuple(sorted(rows))


class DifferentialIK:
    """qdot (n,) from a desired tool twist [v; w] (6,) in world axes, by the chosen backend.

    "dls": damped least squares with singularity-robust damping, null-space posture toward q_home, position and
    velocity limits (robots.ik.dls). "pink": the same task as a QP in pin-pink with solver daqp (robots.ik.pink_qp).
    rows: which twist rows are tasks (default: (0, 1) for a planar arm, all six otherwise). gains: backend options
    (DlsGains / PinkGains fields). ``kinematics`` is a Kinematics of the robot; ``limit_hits`` counts the solves
    that had to respect a joint limit.
    """

    def __init__(self, robot: ArmModel, backend: str = "dls", rows: tuple[int, ...] | None = None,
                 **gains: Any) -> None:
        if backend not in _REGISTRY:
            raise RobotError(f"unknown IK backend '{backend}'; known: {', '.join(IK_BACKENDS)}")
        module_name, class_name, gains_name = _REGISTRY[backend]
        module = importlib.import_module(module_name)
        gains_cls = getattr(module, gains_name)
        known = [f.name for f in dataclasses.fields(gains_cls)]
        unknown = sorted(set(gains) - set(known))
        if unknown:
            raise RobotError(f"unknown gain(s) {', '.join(unknown)} for IK backend '{backend}'; "
                             f"known: {', '.join(known)}")
        self.robot = robot
        self.backend = backend
        self.rows = _check_rows(rows, robot)
        self.kinematics = Kinematics(robot)
        self._impl = getattr(module, class_name)(robot, self.rows, self.kinematics, gains_cls(**gains))

    @property
    def gains(self) -> JointGains:
        """The back-end's gains as it took them (``DlsGains`` or ``PinkGains``)."""
        gains: JointGains = self._impl.gains
        return gains

    def fast_params(self, dt: float) -> dict[str, np.ndarray | float]:
        """The constants of the "dls" back-end's fast path at step dt [s], for a compiled copy of it.

        Parameters
        ----------
        dt : float
            The control step [s].

        Returns
        -------
        dict of str to ndarray or float
            ``robots.ik.dls.DlsBackend.fast_params``: ``q_home``, ``mid``, ``fast_half``, ``posture_gain``,
            ``eps2`` and ``fast_speed2``.

        Raises
        ------
        RobotError
            Another back-end, which has no fast path.
        """
        if self.backend != "dls":
            raise RobotError(f"IK backend '{self.backend}' has no fast path (only 'dls' has)")
        params: dict[str, np.ndarray | float] = self._impl.fast_params(float(dt))
        return params

    @property
    def limit_hits(self) -> int:
        """Number of solve() calls that clamped qdot to a joint position or velocity limit."""
        return self._impl.limit_hits

    @limit_hits.setter
    def limit_hits(self, value: int) -> None:
        self._impl.limit_hits = int(value)

    def solve(self, q: np.ndarray, twist: np.ndarray, dt: float, kin: Kinematics | None = None) -> np.ndarray:
        """qdot (n,) at joint positions q (n,) for tool twist (6,) over dt [s]. kin: a Kinematics already updated
        at q whose Jacobian "dls" reuses (else it updates self.kinematics at q); "pink" computes its own."""
        return self._impl.solve(np.asarray(q, dtype=float), np.asarray(twist, dtype=float), float(dt), kin)


__all__ = ["DifferentialIK", "IK_BACKENDS", "solve_pose_ik", "solve_position_ik"]
