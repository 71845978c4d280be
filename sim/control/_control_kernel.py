"""The compiled control step of ``sim.control.controller.FieldController.fast_command``: twist, the DLS fast path
and the actuator command in one numba function (``kernel``).

Imported lazily by ``sim.control.controller`` (``import sim`` never pays for numba); every function is compiled
once per machine (``cache=True`` keeps the machine code beside this file). The helpers are small
``njit`` functions that numba inlines into ``kernel`` (``inline="always"``): one compiled function.

The parameter vector ``prm`` is written by ``FieldController._pack``; its layout, and ``HEADER``,
live in ``sim.control._kernel_layout``, which both sides import. A pose task's chart point (Eq. (P1),
``pose_point``) and twist (Eq. (P3), inside ``kernel``) use ``lfd.pose_kernel``'s log and right
Jacobian of SO(3), inlined.
"""

from __future__ import annotations

import numba
import numpy as np

from lfd.pose_kernel import jexp3, log3
from sim.control._kernel_layout import HEADER


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _linear_twist(v: np.ndarray, p: np.ndarray, prm: np.ndarray, d: int, tw: np.ndarray
                  ) -> None:  # pragma: no cover - compiled
    """tw[:3] = s A v - k_n n (n . p - n . o) (the second term on a task plane only); tw[3:] = 0.

    v : (d,) task velocity; p : (3,) tool position; prm : the parameter vector; tw : (6,) output.
    """
    o = HEADER
    for i in range(3):
        acc = 0.0
        for j in range(d):
            acc += prm[o + 15 + i * d + j] * v[j]
        tw[i] = acc
        tw[3 + i] = 0.0
    if prm[0] != 0.0:
        e = prm[o + 12] * p[0] + prm[o + 13] * p[1] + prm[o + 14] * p[2] - prm[2]
        for i in range(3):
            tw[i] -= prm[o + 9 + i] * e


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _pose_log(rot: np.ndarray, prm: np.ndarray, b: int, out: np.ndarray, o: int
              ) -> None:  # pragma: no cover - compiled
    """out[o:o + 3] = l log(R_g^T R^T rot), the rotation coordinates of Eq. (P1) of the world tool
    rotation rot (3, 3); the pose block of prm starts at b (``sim.control._kernel_layout``)."""
    rel = np.empty((3, 3))
    for i in range(3):
        m0, m1, m2 = prm[b + 12 + 3 * i], prm[b + 13 + 3 * i], prm[b + 14 + 3 * i]
        for j in range(3):
            rel[i, j] = m0 * rot[0, j] + m1 * rot[1, j] + m2 * rot[2, j]
    log3(rel, prm[b + 30], out, o)


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _pose_twist(v: np.ndarray, rot: np.ndarray, prm: np.ndarray, b: int, tw: np.ndarray
                ) -> None:  # pragma: no cover - compiled
    """The world twist of a pose task's command v = z_dot (6,) at the chart point z of the tool
    rotation rot (3, 3) (Eq. (P3)): tw[:3] = s A v[:3], tw[3:] = R R_g / l J_r(-z_rot / l) v[3:]."""
    zr = np.empty(3)
    _pose_log(rot, prm, b, zr, 0)
    k = -1.0 / prm[b + 30]
    y0, y1, y2 = jexp3(zr[0] * k, zr[1] * k, zr[2] * k, v, 3)
    o = HEADER + 15
    for i in range(3):
        tw[i] = prm[o + 3 * i] * v[0] + prm[o + 3 * i + 1] * v[1] + prm[o + 3 * i + 2] * v[2]
        tw[3 + i] = prm[b + 21 + 3 * i] * y0 + prm[b + 22 + 3 * i] * y1 + prm[b + 23 + 3 * i] * y2


@numba.njit(cache=True, fastmath=False, nogil=True)
def pose_point(p: np.ndarray, rot: np.ndarray, prm: np.ndarray, z: np.ndarray) -> None:  # pragma: no cover
    """z (6,) = (A^T (p - o) / s, l log(R_g^T R^T rot)), Eq. (P1) of the tool pose p (3,), rot (3, 3),
    world, on a pose task (``FieldController.to_task``)."""
    b = HEADER + 15 + 3 * int(prm[11]) + 6 * int(prm[12])
    dx, dy, dz = p[0] - prm[b], p[1] - prm[b + 1], p[2] - prm[b + 2]
    for i in range(3):
        z[i] = prm[b + 3 + 3 * i] * dx + prm[b + 4 + 3 * i] * dy + prm[b + 5 + 3 * i] * dz
    _pose_log(rot, prm, b, z, 3)


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _rotation_twist(rot: np.ndarray, prm: np.ndarray, tw: np.ndarray) -> int:  # pragma: no cover - compiled
    """tw[3:] = k_r log3(R_ref R^T) for the tool rotation rot (3, 3); returns 1 (take the Python
    path) when the rotation error is near pi, else 0."""
    rref = prm[HEADER:HEADER + 9]
    e_ = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            e_[i, j] = rref[3 * i] * rot[j, 0] + rref[3 * i + 1] * rot[j, 1] + rref[3 * i + 2] * rot[j, 2]
    wx, wy, wz = e_[2, 1] - e_[1, 2], e_[0, 2] - e_[2, 0], e_[1, 0] - e_[0, 1]
    c = 0.5 * (e_[0, 0] + e_[1, 1] + e_[2, 2] - 1.0)
    sn = 0.5 * np.sqrt(wx * wx + wy * wy + wz * wz)
    if c < 0.0 and sn < 1e-3:
        return 1
    th = np.arctan2(sn, c)
    f = 0.5 * (1.0 + th * th / 6.0) if sn < 1e-6 else 0.5 * th / sn
    kr = prm[3]
    tw[3], tw[4], tw[5] = kr * f * wx, kr * f * wy, kr * f * wz
    return 0


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _normal_equations(jac: np.ndarray, tw: np.ndarray, z: np.ndarray, m: int, n: int
                      ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(J J^T (m, m), tw - J z (m,)) for J = jac[:m], the posture term z (n,)."""
    jjt = np.empty((m, m))
    rhs = np.empty(m)
    for i in range(m):
        acc = 0.0
        for k in range(n):
            acc += jac[i, k] * z[k]
        rhs[i] = tw[i] - acc
        for j in range(i + 1):
            acc = 0.0
            for k in range(n):
                acc += jac[i, k] * jac[j, k]
            jjt[i, j] = acc
            jjt[j, i] = acc
    return jjt, rhs


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _cholesky(a: np.ndarray, shift: float, low: np.ndarray) -> bool:  # pragma: no cover - compiled
    """low (m, m) <- the Cholesky factor of a - shift I, a (m, m); False if that is not positive definite."""
    m = a.shape[0]
    for j in range(m):
        acc = a[j, j] - shift
        for k in range(j):
            acc -= low[j, k] * low[j, k]
        if not acc > 0.0:
            return False
        low[j, j] = np.sqrt(acc)
        for i in range(j + 1, m):
            acc = a[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = acc / low[j, j]
    return True


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _cho_solve(low: np.ndarray, rhs: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """y (m,) with L L^T y = rhs, for the Cholesky factor low (m, m) and rhs (m,)."""
    m = rhs.shape[0]
    y = np.empty(m)
    for i in range(m):
        acc = rhs[i]
        for k in range(i):
            acc -= low[i, k] * y[k]
        y[i] = acc / low[i, i]
    for i in range(m - 1, -1, -1):
        acc = y[i]
        for k in range(i + 1, m):
            acc -= low[k, i] * y[k]
        y[i] = acc / low[i, i]
    return y


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _dls(jac: np.ndarray, tw: np.ndarray, q: np.ndarray, prm: np.ndarray, n: int, m: int,
         out: np.ndarray) -> int:  # pragma: no cover - compiled
    """DLS fast path: out[:n] = z + J^T (J J^T)^-1 (tw - J z), z = k_p (q_home - q), J = jac[:m] (m, n);
    returns 0, or 2 near a singularity (J J^T - eps^2 I not positive definite), 3 near a joint
    limit or too fast (then take the Python path)."""
    o = HEADER + 15 + 3 * int(prm[11])
    kp = prm[9]
    z = np.empty(n)
    for k in range(n):
        z[k] = kp * (prm[o + k] - q[k])
    jjt, rhs = _normal_equations(jac, tw, z, m, n)
    low = np.zeros((m, m))
    if not _cholesky(jjt, prm[4], low) or not _cholesky(jjt, 0.0, low):
        return 2
    y = _cho_solve(low, rhs)
    speed2 = 0.0
    for k in range(n):
        acc = z[k]
        for i in range(m):
            acc += y[i] * jac[i, k]
        out[k] = acc
        speed2 += acc * acc
        if abs(q[k] - prm[o + n + k]) > prm[o + 2 * n + k]:
            return 3
    return 3 if speed2 > prm[5] else 0


@numba.njit(cache=True, fastmath=False, nogil=True, inline="always")
def _actuate(q: np.ndarray, qvel: np.ndarray, bias: np.ndarray, qprev: np.ndarray, prm: np.ndarray,
             n: int, nv: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """The actuator command from qdot_ref = out[:n]: computed torque writes a = c_ref qdot_ref -
    qprev / dt - k_d qdot into out[n:n + nv] (by dof) and bias + damping qdot into out[n + nv:], and
    qdot_ref into qprev (n,); position servos write q + lead qdot_ref into out[n + nv:]."""
    o = HEADER + 15 + 3 * int(prm[11])
    if prm[10] != 0.0:
        c_ref, inv_dt, kd = prm[6], prm[7], prm[8]
        for i in range(nv):
            out[n + i] = 0.0
        for k in range(n):
            dof = int(prm[o + 5 * n + k])
            out[n + dof] = c_ref * out[k] - inv_dt * qprev[k] - kd * qvel[dof]
            out[n + nv + k] = bias[dof] + prm[o + 3 * n + k] * qvel[dof]
            qprev[k] = out[k]
    else:
        for k in range(n):
            out[n + nv + k] = q[k] + prm[o + 4 * n + k] * out[k]


@numba.njit(cache=True, fastmath=False, nogil=True)
def kernel(jac: np.ndarray, p: np.ndarray, rot: np.ndarray, v: np.ndarray, q: np.ndarray,
           qvel: np.ndarray, bias: np.ndarray, qprev: np.ndarray, prm: np.ndarray,
           out: np.ndarray) -> int:  # pragma: no cover - compiled
    """Twist + DLS fast path + actuator command; see ``FieldController.fast_command``.

    jac : (6, n) tool Jacobian; p : (3,) tool position; rot : (3, 3) tool rotation; v : (d,) task
    velocity (a pose task: the chart velocity z_dot (6,), Eq. (P3)); q : (n,) joints; qvel, bias :
    (nv,) MuJoCo's qvel and qfrc_bias; qprev : (n,) the last qdot_ref (updated); prm : the parameter
    vector (layout: ``sim.control._kernel_layout``); out : (2 n + nv,).
    Returns 0 (done: out holds qdot_ref (n), a (nv, torque) and the command's base (n)), else the
    reason to take the Python path (1: rotation near pi, 2: near a singularity, 3: near a limit).
    """
    d, n, nv, m = int(prm[11]), int(prm[12]), int(prm[13]), int(prm[14])
    tw = np.empty(6)
    if prm[15] != 0.0:
        _pose_twist(v, rot, prm, HEADER + 15 + 3 * d + 6 * n, tw)
    else:
        _linear_twist(v, p, prm, d, tw)
    if prm[1] != 0.0 and _rotation_twist(rot, prm, tw) != 0:
        return 1
    status = _dls(jac, tw, q, prm, n, m, out)
    if status != 0:
        return status
    _actuate(q, qvel, bias, qprev, prm, n, nv, out)
    return 0


@numba.njit(cache=True, fastmath=False, nogil=True)
def observe(qpos: np.ndarray, qvel: np.ndarray, site: np.ndarray, goal: np.ndarray, goal_world: np.ndarray,
            prm: np.ndarray, out: np.ndarray) -> float:  # pragma: no cover - compiled
    """The observation and reward of ``sim.control.task.FieldTrackingTask.outputs`` for a position task, in
    one pass.

    qpos (nq,), qvel (nv,) : MuJoCo's; site (3,) : the tool site's world position, m; goal (d,) :
    the goal, task units; goal_world (3,) : the goal in world, m; prm : n, d, the reward's goal
    tolerance, margin and Gaussian scale, o (3,), A^T / s row by row (3 d), q_min (n), q_max (n),
    and the arm's qpos and qvel addresses (n each), shape (8 + 3 d + 4 n,); out (3 n + 3 + 2 d,)
    : receives q (n), qdot (n), p (3), x = A^T (p - o) / s (d), goal (d) and the joint-limit flags
    (n: 1.0 where q is outside [q_min, q_max], else 0.0). Returns the reward (1 within the
    tolerance of the goal, else exp(-((dist - tol) / margin scale)^2 / 2); NaN for a non-finite p).
    """
    n, d = int(prm[0]), int(prm[1])
    tol, margin, scale = prm[2], prm[3], prm[4]
    a_ = 8
    lo_ = a_ + 3 * d
    hi_ = lo_ + n
    qa_ = hi_ + n
    da_ = qa_ + n
    for k in range(n):
        qk = qpos[int(prm[qa_ + k])]
        out[k] = qk
        out[n + k] = qvel[int(prm[da_ + k])]
        out[2 * n + 3 + 2 * d + k] = 1.0 if (qk < prm[lo_ + k] or qk > prm[hi_ + k]) else 0.0
    px, py, pz = site[0], site[1], site[2]
    out[2 * n], out[2 * n + 1], out[2 * n + 2] = px, py, pz
    dx, dy, dz = px - prm[5], py - prm[6], pz - prm[7]
    for i in range(d):
        out[2 * n + 3 + i] = prm[a_ + 3 * i] * dx + prm[a_ + 3 * i + 1] * dy + prm[a_ + 3 * i + 2] * dz
        out[2 * n + 3 + d + i] = goal[i]
    gx, gy, gz = goal_world[0], goal_world[1], goal_world[2]
    dist = np.sqrt((px - gx) ** 2 + (py - gy) ** 2 + (pz - gz) ** 2)
    if dist <= tol:
        return 1.0
    r = (dist - tol) / margin * scale
    return np.exp(-0.5 * r * r)
