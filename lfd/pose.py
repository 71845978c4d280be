"""Orientations as a chart at the goal: poses (x, q) in R^3 x S^3 as points z of R^6.

A pose field learns its motion in the log chart of SO(3) at the goal orientation R_g (docs/equations.md,
Eqs. (P1)-(P4)):

    Eq. (P1): z = (x, l r),  r = log(R_g^T R) in R^3,  |r| = the geodesic angle from R to R_g [rad],
    Eq. (P2): R = R_g exp(r)  (the inverse map, defined for every r in R^3),
    Eq. (P3): omega = R J_r(r) r_dot  (the world angular velocity of z_dot; J_r: SO(3)'s right
              Jacobian, Pinocchio's ``Jexp3``),
    Eq. (P4): angle(R_1, R_2) = |log(R_1^T R_2)| <= |r_1 - r_2|  (exp at R_g does not increase
              distances; the reason below),

with l = ``ROTATION_LENGTH`` metres per radian (Eq. (P4): J_r's singular values are 1, 1 and
|sin(theta / 2)| / (theta / 2) <= 1, so the curve R_g exp(r_1 + s (r_2 - r_1)), s in [0, 1], is at
most |r_1 - r_2| long), so that one learner's single scale fits positions and turns alike. Every
learner then learns a field on R^6 as it would on positions, and a pose field is that field with its
``PoseChart``. The chart is one-to-one for angles below pi; at the goal's antipode (a half turn
away, the cut locus) log jumps, the known obstruction: no continuous field on SO(3) has a globally
attracting equilibrium.

Quaternions are (w, x, y, z), scalar first, as in the data sets; a quaternion and its negative are
the same orientation (the double cover S^3 -> SO(3)). One pose (``point``, ``point_of``, ``twist``)
is one compiled call (``lfd.pose_kernel``, numba); batches use Pinocchio's ``log3`` and ``exp3``. Both
are imported on first use. Conversions, the mean and the geodesic angle are ``lfd.rotations``'
(re-exported here).
"""

from __future__ import annotations

import functools
import importlib
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.rotations import (
    ROTATION_LENGTH,
    UNIT_TOLERANCE,
    continuous,
    geodesic_angle,
    matrix_quaternions,
    mean_quaternion,
    quaternion_matrices,
)

__all__ = ["ROTATION_LENGTH", "UNIT_TOLERANCE", "PoseChart", "chart_demos", "continuous", "geodesic_angle",
           "matrix_quaternions", "mean_quaternion", "quaternion_matrices"]


@functools.cache
def _kernels() -> Any:
    """``lfd.pose_kernel``, imported on first use (it imports numba: ``import lfd.pose`` stays cheap)."""
    return importlib.import_module("lfd.pose_kernel")


def _pin() -> Any:
    """Pinocchio, imported on first use (a noticeable part of a second that training on positions
    need not pay)."""
    import pinocchio

    return pinocchio


def _f64(a: Any) -> np.ndarray:
    """a as a float64 ndarray (itself when it is one)."""
    return a if type(a) is np.ndarray and a.dtype == np.float64 else np.asarray(a, dtype=np.float64)


@dataclass(frozen=True)
class PoseChart:
    """The log chart at the goal orientation, Eqs. (P1)-(P4).

    goal_rotation : array, shape (3, 3)
        R_g, the orientation the chart is centred on (the demos' mean final orientation).
    length : float
        l, chart metres per radian (``ROTATION_LENGTH``).
    """

    goal_rotation: np.ndarray
    length: float = ROTATION_LENGTH
    _goal_t: np.ndarray = field(init=False, repr=False, compare=False)
    _goal_over_l: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        rot = np.ascontiguousarray(self.goal_rotation, dtype=np.float64)
        object.__setattr__(self, "goal_rotation", rot)
        object.__setattr__(self, "length", float(self.length))
        object.__setattr__(self, "_goal_t", np.ascontiguousarray(rot.T))
        object.__setattr__(self, "_goal_over_l", rot / float(self.length))   # R_g / l

    @classmethod
    def at(cls, goal_q: np.ndarray, length: float = ROTATION_LENGTH) -> PoseChart:
        """The chart at the unit quaternion goal_q (w, x, y, z), shape (4,)."""
        return cls(quaternion_matrices(np.asarray(goal_q, dtype=np.float64)), float(length))

    @classmethod
    def of(cls, demos: DemoSet) -> PoseChart:
        """The chart a pose set is learned in: at its goal orientation ``demos.goal_q``."""
        if demos.goal_q is None:
            raise ValueError(f"{demos.name}: only a set of poses has a pose chart")
        return cls.at(demos.goal_q)

    @property
    def goal_q(self) -> np.ndarray:
        """R_g as a quaternion (w, x, y, z), w >= 0, shape (4,)."""
        return matrix_quaternions(self.goal_rotation)

    def rotation_coordinates(self, rot: np.ndarray) -> np.ndarray:
        """l log(R_g^T R) of Eq. (P1): rotations of shape (..., 3, 3) -> shape (..., 3) (one rotation,
        shape (3, 3): one compiled call, a control loop's observation)."""
        rot = np.asarray(rot, dtype=np.float64)
        if rot.shape == (3, 3):
            one = np.empty(3)
            _kernels().chart_rotation(rot, self._goal_t, self.length, one)
            return one
        rel = np.einsum("ji,...jk->...ik", self.goal_rotation, rot).reshape(-1, 3, 3)
        out = np.stack([_pin().log3(r) for r in rel]) if len(rel) else np.zeros((0, 3))
        return self.length * out.reshape(rot.shape[:-2] + (3,))

    def to_chart(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        """z = (x, l log(R_g^T R(q))) of Eq. (P1): x (..., 3), q (..., 4) -> z (..., 6)."""
        return np.concatenate([np.asarray(x, dtype=np.float64),
                               self.rotation_coordinates(quaternion_matrices(q))], axis=-1)

    def rotations(self, z: np.ndarray) -> np.ndarray:
        """R = R_g exp(z_rot / l) of Eq. (P2): z (..., 6) -> rotations (..., 3, 3)."""
        z = np.asarray(z, dtype=np.float64)
        r = z[..., 3:6].reshape(-1, 3) / self.length
        out = np.stack([self.goal_rotation @ _pin().exp3(v) for v in r]) if len(r) else np.zeros((0, 3, 3))
        return out.reshape(z.shape[:-1] + (3, 3))

    def from_chart(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x (..., 3), q (..., 4)) of z (..., 6), Eq. (P2)."""
        z = np.asarray(z, dtype=np.float64)
        return z[..., :3].copy(), matrix_quaternions(self.rotations(z))

    def point(self, x: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Eq. (P1) for one pose: x (3,) and its rotation matrix rot (3, 3) -> z (6,), one compiled
        call (the control loop's fast path; ``to_chart`` for batches of quaternions)."""
        z = np.empty(6)
        _kernels().chart_point(_f64(x), _f64(rot), self._goal_t, self.length, z)
        return z

    def point_of(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Eq. (P1) for one pose: x (3,) and its quaternion q (4,) (w, x, y, z; normalised here)
        -> z (6,)."""
        k = _kernels()
        rot = np.empty((3, 3))
        k.quaternion_rotation(_f64(q), rot)
        z = np.empty(6)
        k.chart_point(_f64(x), rot, self._goal_t, self.length, z)
        return z

    def twist(self, z: np.ndarray, zdot: np.ndarray) -> np.ndarray:
        """(v, omega) of Eq. (P3), world axes [m/s, rad/s], shape (6,), for one chart point z (6,)
        and its chart velocity zdot (6,): v = zdot[:3], omega = R J_r(r) r_dot = R_g J_l(r) r_dot, since
        exp(r) J_r(r) = J_l(r) = J_r(-r) (SO(3)'s left Jacobian), one compiled call."""
        out = np.empty(6)
        _kernels().chart_twist(_f64(z), _f64(zdot), self._goal_over_l, self.length, out)
        return out

    def angle_to_goal(self, z: np.ndarray) -> np.ndarray:
        """The geodesic angle from R(z) to R_g [rad], z (..., 6) -> (...): |z_rot| / l where that is at
        most pi (Eq. (P1)), else the angle of R_g^T R(z) (a chart point past the half turn)."""
        z = np.asarray(z, dtype=np.float64)
        out = np.linalg.norm(z[..., 3:6], axis=-1) / self.length
        far = out > math.pi
        if np.any(far):
            out[far] = geodesic_angle(self.goal_rotation, self.rotations(z[far]))
        return out

    def to_dict(self) -> dict:
        return {"goal_q": [float(v) for v in self.goal_q], "length": float(self.length)}

    @classmethod
    def from_dict(cls, d: dict) -> PoseChart:
        q = np.asarray(d["goal_q"], dtype=np.float64)
        if q.shape != (4,) or not np.isfinite(q).all() or abs(float(np.linalg.norm(q)) - 1.0) > UNIT_TOLERANCE:
            raise ValueError(f"a pose chart's goal_q must be a unit quaternion, got {q.tolist()}")
        length = float(d["length"])
        if not (math.isfinite(length) and length > 0):
            raise ValueError(f"a pose chart's length must be positive, got {length}")
        return cls.at(q / np.linalg.norm(q), length)


def chart_demos(demos: DemoSet, chart: PoseChart) -> DemoSet:
    """A pose set's demos as chart points of R^6, Eq. (P1): positions (N, T, 3) and quaternions
    (N, T, 4) -> a position set of shape (N, T, 6), named after the poses, with their notes."""
    if demos.q is None:
        raise ValueError(f"{demos.name}: chart_demos needs a set of poses")
    return DemoSet(demos.t, chart.to_chart(demos.x, demos.q), name=demos.name, notes=demos.notes)
