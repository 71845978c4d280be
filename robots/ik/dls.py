"""Damped least-squares differential IK with singularity-robust damping, null-space posture and joint limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv, dpotrf, dsyev

from robots.ik.gains import JointGains
from robots.kinematics import Kinematics
from robots.model import ArmModel

_FAST_TOL = 1e-9  # margin of the fast limit test over rounding: a qdot this close to a limit takes the full test


@dataclass(frozen=True)
class DlsGains(JointGains):
    """damping: lambda_max; sv_threshold: eps, the smallest singular value below which damping starts;
    the joints' gains as ``JointGains``."""

    damping: float = 0.05
    sv_threshold: float = 0.05


class DlsBackend:
    """qdot from a twist by damped least squares (Nakamura & Hanafusa 1986; Chiaverini 1997; Maciejewski & Klein 1988).

    With J = J(q)[rows] (m, n), v = twist[rows] (m,), z = k_p (q_home - q) (n,):
        qdot = J# v + (I - J# J) z = z + J^T (J J^T + lambda^2 I)^-1 (v - J z),  J# = J^T (J J^T + lambda^2 I)^-1
        lambda^2 = lambda_max^2 (1 - (s_min / eps)^2) if s_min < eps else 0   (s_min: smallest singular value of J)
    Away from singularities lambda = 0, J# = J^+ and the posture term moves only in the null space of J.
    Limits, in order: (1) position: each joint whose qdot would leave [q_min + margin, q_max - margin] within dt is
    fixed at the bound and the task is re-solved with the remaining joints (repeat until none violates);
    (2) velocity: qdot is scaled uniformly by min_i v_i / |qdot_i| when above 1, keeping its direction
    (v = speed_fraction v_max, the commanded speed limit);
    (3) a final clip to both bounds. A joint already beyond a soft bound (a measured q after servo overshoot) may
    not move further out. limit_hits counts the solve() calls where any of these changed qdot.

    Fast paths (same results): a Cholesky factorization of J J^T - eps^2 I that succeeds proves s_min > eps, so
    the solve is one Cholesky solve (LAPACK dposv) and the eigendecomposition runs only near a singularity; the
    limits run only when the cheap sufficient test fails: |qdot|^2 <= min_i v_max_i^2 (1 - tol) (so |qdot| < v_max)
    and |q - mid| <= half - v_max dt - tol (mid, half: centre and half-width of the soft range; so q + qdot dt stays
    inside it).
    """

    def __init__(self, robot: ArmModel, rows: tuple[int, ...], kinematics: Kinematics, gains: DlsGains) -> None:
        self.kinematics = kinematics
        self.rows = np.asarray(rows, dtype=int)
        self.gains = gains
        self._lam2_max = gains.damping ** 2
        self._eps2 = gains.sv_threshold ** 2
        self._q_home = np.asarray(robot.q_home, dtype=float)
        self._q_lo = robot.q_min + gains.limit_margin
        self._q_hi = robot.q_max - gains.limit_margin
        self._v_max = np.asarray(robot.v_max, dtype=float) * gains.speed_fraction   # the commanded limit
        self._all_rows = len(rows) == 6
        self._shift = self._eps2 * np.eye(len(rows))
        self._fast_speed2 = float(np.min(self._v_max)) ** 2 * (1.0 - _FAST_TOL)
        self._mid = 0.5 * (self._q_lo + self._q_hi)
        self._half = 0.5 * (self._q_hi - self._q_lo) - _FAST_TOL
        self._unit_gain = gains.posture_gain == 1.0
        self._fast_dt, self._fast_half = 0.0, self._half
        self.limit_hits = 0

    def fast_params(self, dt: float) -> dict[str, np.ndarray | float]:
        """The constants of the fast path at step dt [s], for a compiled copy of it (``sim.control.controller``).

        Returns ``q_home`` (n,), ``mid`` (n,), ``fast_half`` (n,) (the limit test |q - mid| <= fast_half),
        ``posture_gain``, ``eps2`` (eps^2 of the Cholesky test) and ``fast_speed2`` (the speed test |qdot|^2 <=
        fast_speed2). A compiled copy that finds either test failing, or J J^T - eps^2 I not positive definite, must
        call ``solve`` instead (which then counts ``limit_hits``)."""
        return {"q_home": self._q_home.copy(), "mid": self._mid.copy(), "fast_half": self._half - self._v_max * dt,
                "posture_gain": float(self.gains.posture_gain), "eps2": float(self._eps2),
                "fast_speed2": float(self._fast_speed2)}

    def _resolve(self, jac: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        """z + J^T (J J^T + lambda^2 I)^-1 (v - J z) for J (m, k), v (m,), z (k,) -> (k,). If J J^T - eps^2 I is
        positive definite (its Cholesky factorization succeeds), lambda = 0 and one Cholesky solve gives the result;
        else J J^T = U S^2 U^T from a symmetric eigendecomposition (LAPACK dsyev) and
        (J J^T + lambda^2 I)^-1 = U (S^2 + lambda^2)^-1 U^T."""
        jjt = jac.dot(jac.T)
        rhs = v - jac.dot(z)
        if dpotrf((jjt - self._shift).T, overwrite_a=1, clean=0)[1] == 0:  # .T: Fortran order, factored in place
            _, x, info = dposv(jjt, rhs)
            if info == 0:
                return z + x.dot(jac)
        s2, u, _ = dsyev(jjt)
        s2_min = s2[0]
        if s2_min < self._eps2:
            s2 = s2 + self._lam2_max * (1.0 - max(s2_min, 0.0) / self._eps2)
        return z + jac.T @ (u @ ((u.T @ rhs) / s2))

    def solve(self, q: np.ndarray, twist: np.ndarray, dt: float, kin: Kinematics | None = None) -> np.ndarray:
        """qdot (n,) for joint positions q (n,) and desired tool twist [v; w] (6,) over a step dt [s]."""
        if kin is None:
            kin = self.kinematics
            kin.update(q)
        jac_full = kin.ee_jacobian()
        jac = jac_full if self._all_rows else jac_full[self.rows]
        v = twist if self._all_rows else twist[self.rows]
        z = self._q_home - q
        if not self._unit_gain:
            z *= self.gains.posture_gain
        qdot = self._resolve(jac, v, z)
        if dt != self._fast_dt:
            self._fast_dt, self._fast_half = dt, self._half - self._v_max * dt
        # ndarray.tolist() + builtin any() is cheaper than ndarray.any() on so few entries
        if qdot.dot(qdot) <= self._fast_speed2 and not any((np.abs(q - self._mid) > self._fast_half).tolist()):
            return qdot
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
