"""The pose chart of ``lfd.pose`` for one point, compiled: SO(3)'s log and right Jacobian in numba.

``log3`` and ``jexp3`` follow Pinocchio's ``log3`` and ``Jexp3`` (the matrix renormalised first,
Taylor branches below eps^(1/3) and eps^(1/4), the half-turn branch of ``log3`` by the largest
diagonal entry); ``log3`` takes the angle by atan2 where Pinocchio takes acos, which loses digits
within a few degrees of a half turn, so it agrees with Pinocchio to round-off wherever Pinocchio is
exact and is exact there too (tests/test_pose_kernel.py). On them: ``chart_point`` and
``chart_rotation`` (Eq. (P1)), ``chart_twist`` (Eq. (P3)) and ``quaternion_rotation`` (a unit
quaternion's matrix, as Pinocchio's ``Quaternion.normalized().toRotationMatrix()``), each one call
from Python; ``sim.control._control_kernel`` inlines ``log3`` and ``jexp3`` into the arm's control step.
Compiled once per machine (``cache=True``); imported on first use (``lfd.pose``), so ``import lfd``
never pays for numba.

Written once: these kernels are the only single-pose chart maps in this repository. Batches
(``PoseChart.to_chart``, ``PoseChart.rotations``) go through Pinocchio's ``log3`` and ``exp3``, the
library these kernels follow and the tests' reference, not a second implementation.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_EPS = float(np.finfo(np.float64).eps)
#: Pinocchio's ``TaylorSeriesExpansion<double>::precision<2>()`` and ``precision<3>()``
_PREC2 = _EPS ** (1.0 / 3.0)
_PREC3 = _EPS ** (1.0 / 4.0)

__all__ = ["chart_point", "chart_rotation", "chart_twist", "jexp3", "log3", "quaternion_rotation"]


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
def _axis_angle(i0: int, val: float, r: np.ndarray) -> tuple[float, float, float, float]:  # pragma: no cover
    """The half-turn branch of ``log3`` by the diagonal entry i0 of the orthonormal r (3, 3)
    (Pinocchio's ``compute_theta_axis``): (angle, unit axis (3 floats))."""
    i1, i2 = (i0 + 1) % 3, (i0 + 2) % 3
    s = math.sqrt(val + _EPS + _EPS * _EPS) * (1.0 if r[i2, i1] >= r[i1, i2] else -1.0)
    a = np.empty(3)
    a[i0] = s / 2.0
    a[i1] = 1.0 / (2.0 * s) * (r[i1, i0] + r[i0, i1])
    a[i2] = 1.0 / (2.0 * s) * (r[i2, i0] + r[i0, i2])
    w = 1.0 / (2.0 * s) * (r[i2, i1] - r[i1, i2])
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return 2.0 * math.atan2(n, w), a[0] / n, a[1] / n, a[2] / n


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
def log3(rot: np.ndarray, scale: float, out: np.ndarray, o: int) -> None:  # pragma: no cover - compiled
    """out[o:o + 3] = scale log(rot), the rotation vector of rot (3, 3) [rad] times scale.

    As Pinocchio's ``log3``: rot renormalised (columns 0 and 1 normalised, the rest by cross
    products); within eps^(1/3) of a half turn (cos(theta) < -1 + eps^(1/3)) the axis comes from
    the largest of 2 R_ii - tr + 1, else r = theta / sin(theta) w with w = vee(R - R^T) / 2 and
    theta = atan2(|w|, (tr - 1) / 2) (Pinocchio's acos loses digits near a half turn; atan2 does
    not), theta / sin(theta) by its Taylor series below theta = eps^(1/3).
    """
    r = np.empty((3, 3))
    n0 = math.sqrt(rot[0, 0] * rot[0, 0] + rot[1, 0] * rot[1, 0] + rot[2, 0] * rot[2, 0])
    n1 = math.sqrt(rot[0, 1] * rot[0, 1] + rot[1, 1] * rot[1, 1] + rot[2, 1] * rot[2, 1])
    for i in range(3):
        r[i, 0] = rot[i, 0] / n0
        r[i, 1] = rot[i, 1] / n1
    r[0, 2] = r[1, 0] * r[2, 1] - r[2, 0] * r[1, 1]     # c2 = c0 x c1
    r[1, 2] = r[2, 0] * r[0, 1] - r[0, 0] * r[2, 1]
    r[2, 2] = r[0, 0] * r[1, 1] - r[1, 0] * r[0, 1]
    c0x = r[1, 1] * r[2, 2] - r[2, 1] * r[1, 2]         # c0 = c1 x c2
    c0y = r[2, 1] * r[0, 2] - r[0, 1] * r[2, 2]
    c0z = r[0, 1] * r[1, 2] - r[1, 1] * r[0, 2]
    r[0, 0], r[1, 0], r[2, 0] = c0x, c0y, c0z
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    cos_value = (tr - 1.0) / 2.0
    if cos_value < -1.0 + _PREC2:   # within eps^(1/3) of a half turn
        v0, v1, v2 = 2.0 * r[0, 0] - tr + 1.0, 2.0 * r[1, 1] - tr + 1.0, 2.0 * r[2, 2] - tr + 1.0
        if v0 >= v1:
            i0 = 0 if v0 >= v2 else 2
        else:
            i0 = 1 if v1 >= v2 else 2
        th, ax, ay, az = _axis_angle(i0, (v0, v1, v2)[i0], r)
        out[o], out[o + 1], out[o + 2] = scale * (th * ax), scale * (th * ay), scale * (th * az)
        return
    wx, wy, wz = 0.5 * (r[2, 1] - r[1, 2]), 0.5 * (r[0, 2] - r[2, 0]), 0.5 * (r[1, 0] - r[0, 1])
    n2 = wx * wx + wy * wy + wz * wz
    sn = math.sqrt(n2)                       # sin(theta)
    theta = math.atan2(sn, cos_value)
    t = theta / sn if theta >= _PREC2 else 1.0 + n2 / 6.0 + n2 * n2 * 3.0 / 40.0   # theta / sin(theta)
    out[o], out[o + 1], out[o + 2] = scale * (t * wx), scale * (t * wy), scale * (t * wz)


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
def jexp3(rx: float, ry: float, rz: float, v: np.ndarray, vo: int) -> tuple[float, float, float]:  # pragma: no cover
    """J_r(r) v[vo:vo + 3] for r = (rx, ry, rz), SO(3)'s right Jacobian as Pinocchio's ``Jexp3``:
    J_r(r) = a I + b [r]_x + c r r^T with a = sin|r| / |r|, b = -(1 - cos|r|) / |r|^2 and
    c = (1 - a) / |r|^2 (their Taylor series below |r| = eps^(1/4)); returns 3 floats."""
    n2 = rx * rx + ry * ry + rz * rz
    n = math.sqrt(n2)
    if n < _PREC3:
        a = 1.0 - n2 / 6.0
        b = -1.0 / 2.0 - n2 / 24.0
        c = 1.0 / 6.0 - n2 / 120.0
    else:
        n_inv = 1.0 / n
        n2_inv = n_inv * n_inv
        a = math.sin(n) * n_inv
        b = -(1.0 - math.cos(n)) * n2_inv
        c = n2_inv * (1.0 - a)
    j01, j02, j12 = -b * rz, b * ry, -b * rx
    j00, j11, j22 = a + c * rx * rx, a + c * ry * ry, a + c * rz * rz
    j01, j10 = j01 + c * rx * ry, -j01 + c * ry * rx
    j02, j20 = j02 + c * rx * rz, -j02 + c * rz * rx
    j12, j21 = j12 + c * ry * rz, -j12 + c * rz * ry
    v0, v1, v2 = v[vo], v[vo + 1], v[vo + 2]
    return (j00 * v0 + j01 * v1 + j02 * v2, j10 * v0 + j11 * v1 + j12 * v2, j20 * v0 + j21 * v1 + j22 * v2)


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
def _chart_log(rot: np.ndarray, goal_t: np.ndarray, length: float, out: np.ndarray,
               o: int) -> None:  # pragma: no cover - compiled
    """out[o:o + 3] = l log(R_g^T rot); rot (3, 3), goal_t = R_g^T (3, 3)."""
    rel = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            rel[i, j] = goal_t[i, 0] * rot[0, j] + goal_t[i, 1] * rot[1, j] + goal_t[i, 2] * rot[2, j]
    log3(rel, length, out, o)


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def chart_point(x: np.ndarray, rot: np.ndarray, goal_t: np.ndarray, length: float,
                out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Eq. (P1) for one pose: out (6,) = (x, l log(R_g^T rot)); x (3,), rot (3, 3), goal_t = R_g^T (3, 3)."""
    for i in range(3):
        out[i] = x[i]
    _chart_log(rot, goal_t, length, out, 3)


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def chart_rotation(rot: np.ndarray, goal_t: np.ndarray, length: float,
                   out: np.ndarray) -> None:  # pragma: no cover - compiled
    """The rotation coordinates of Eq. (P1) of one rotation: out (3,) = l log(R_g^T rot)."""
    _chart_log(rot, goal_t, length, out, 0)


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def chart_twist(z: np.ndarray, zdot: np.ndarray, goal_over_l: np.ndarray, length: float,
                out: np.ndarray) -> None:  # pragma: no cover - compiled
    """Eq. (P3) for one chart point: out (6,) = (zdot[:3], R_g / l J_r(-z_rot / l) zdot_rot);
    z, zdot (6,), goal_over_l = R_g / l (3, 3), length = l."""
    k = -1.0 / length
    y0, y1, y2 = jexp3(z[3] * k, z[4] * k, z[5] * k, zdot, 3)
    for i in range(3):
        out[i] = zdot[i]
        out[3 + i] = goal_over_l[i, 0] * y0 + goal_over_l[i, 1] * y1 + goal_over_l[i, 2] * y2


@numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def quaternion_rotation(q: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out (3, 3) = the rotation matrix of q (4,) = (w, x, y, z) normalised (Eigen's formula)."""
    n = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3] + q[0] * q[0])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    tx, ty, tz = 2.0 * x, 2.0 * y, 2.0 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    out[0, 0], out[0, 1], out[0, 2] = 1.0 - (tyy + tzz), txy - twz, txz + twy
    out[1, 0], out[1, 1], out[1, 2] = txy + twz, 1.0 - (txx + tzz), tyz - twx
    out[2, 0], out[2, 1], out[2, 2] = txz - twy, tyz + twx, 1.0 - (txx + tyy)
