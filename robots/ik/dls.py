"""Damped least-squares differential IK with singularity-robust damping, null-space posture and joint limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dsyev

from robots.kinematics import Kinematics
from robots.model import RobotModel


@dataclass(frozen=True)
class DlsGains:
    """damping: lambda_max; sv_threshold: eps, the smallest singular value below which damping starts;
    posture_gain: k_p [1/s] of the null-space pull toward q_home;
    limit_margin: kept distance to joint limits [rad|m]."""

    damping: float = 0.05
    sv_threshold: float = 0.05
    posture_gain: float = 1.0
    limit_margin: float = 0.02


class DlsBackend:
    """qdot from a twist by damped least squares (Nakamura & Hanafusa 1986; Chiaverini 1997; Maciejewski & Klein 1988).

    With J = J(q)[rows] (m, n), v = twist[rows] (m,), z = k_p (q_home - q) (n,):
        qdot = J# v + (I - J# J) z = z + J^T (J J^T + lambda^2 I)^-1 (v - J z),  J# = J^T (J J^T + lambda^2 I)^-1
        lambda^2 = lambda_max^2 (1 - (s_min / eps)^2) if s_min < eps else 0   (s_min: smallest singular value of J)
    Away from singularities lambda = 0, J# = J^+ and the posture term moves only in the null space of J.
    Limits, in order: (1) position: each joint whose qdot would leave [q_min + margin, q_max - margin] within dt is
    fixed at the bound and the task is re-solved with the remaining joints (repeat until none violates);
    (2) velocity: qdot is scaled uniformly by min_i v_max_i / |qdot_i| when above 1, keeping its direction;
    (3) a final clip to both bounds. A joint already beyond a soft bound (a measured q after servo overshoot) may
    not move further out. limit_hits counts the solve() calls where any of these changed qdot.
    """

    def __init__(self, robot: RobotModel, rows: tuple[int, ...], kinematics: Kinematics, gains: DlsGains) -> None:
        self.kinematics = kinematics
        self.rows = np.asarray(rows, dtype=int)
        self.gains = gains
        self._lam2_max = gains.damping ** 2
        self._eps2 = gains.sv_threshold ** 2
        self._q_home = np.asarray(robot.q_home, dtype=float)
        self._q_lo = robot.q_min + gains.limit_margin
        self._q_hi = robot.q_max - gains.limit_margin
        self._v_max = np.asarray(robot.v_max, dtype=float)
        self._all_rows = len(rows) == 6
        self.limit_hits = 0

    def _resolve(self, jac: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        """z + J^T (J J^T + lambda^2 I)^-1 (v - J z) for J (m, k), v (m,), z (k,) -> (k,), with J J^T = U S^2 U^T
        from one symmetric eigendecomposition (LAPACK dsyev): (J J^T + lambda^2 I)^-1 = U (S^2 + lambda^2)^-1 U^T."""
        s2, u, _ = dsyev(jac @ jac.T)
        s2_min = s2[0]
        if s2_min < self._eps2:
            s2 = s2 + self._lam2_max * (1.0 - max(s2_min, 0.0) / self._eps2)
        return z + jac.T @ (u @ ((u.T @ (v - jac @ z)) / s2))

    def solve(self, q: np.ndarray, twist: np.ndarray, dt: float, kin: Kinematics | None = None) -> np.ndarray:
        """qdot (n,) for joint positions q (n,) and desired tool twist [v; w] (6,) over a step dt [s]."""
        if kin is None:
            kin = self.kinematics
            kin.update(q)
        jac_full = kin.ee_jacobian()
        jac = jac_full if self._all_rows else jac_full[self.rows]
        v = twist if self._all_rows else twist[self.rows]
        z = self.gains.posture_gain * (self._q_home - q)
        qdot = self._resolve(jac, v, z)
        lo_pos = np.minimum(self._q_lo - q, 0.0) / dt
        hi_pos = np.maximum(self._q_hi - q, 0.0) / dt
        lo = np.maximum(lo_pos, -self._v_max)
        hi = np.minimum(hi_pos, self._v_max)
        if not ((qdot < lo) | (qdot > hi)).any():
            return qdot
        self.limit_hits += 1
        over = (qdot < lo_pos) | (qdot > hi_pos)
        fixed = np.zeros(len(q), dtype=bool)
        while over.any():
            fixed |= over
            qdot[fixed] = np.clip(qdot[fixed], lo_pos[fixed], hi_pos[fixed])
            free = ~fixed
            if not free.any():
                break
            qdot[free] = self._resolve(jac[:, free], v - jac[:, fixed] @ qdot[fixed], z[free])
            over = free & ((qdot < lo_pos) | (qdot > hi_pos))
        ratio = np.max(np.abs(qdot) / self._v_max)
        if ratio > 1.0:
            qdot /= ratio
        return np.clip(qdot, np.minimum(lo, self._v_max), np.maximum(hi, -self._v_max))
