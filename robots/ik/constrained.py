"""Differential IK as a small QP with extra linear inequality rows (collision velocity dampers).

    min_qdot  1/2 |W (J qdot - v)|^2 + 1/2 mu |qdot - z|^2
    s.t.      max(-v_max, g (q_lo - q) / dt) <= qdot <= min(v_max, g (q_hi - q) / dt)
              A qdot <= b

(Eq. (A2) of docs/equations.md) with J = J(q)[rows] (m, n), v = twist[rows], W = diag(weights[rows]),
z = k_p (q_home - q) the posture pull of ``robots.ik.dls`` and mu > 0 a small regularisation: far
from every bound and singularity the task is met to O(mu) and the posture term acts in J's null
space, as in ``DlsBackend``.
A joint already beyond a soft bound may stay there (its bound is widened to 0). The rows (A, b)
come from the caller; ``sim.scene.collision`` builds one velocity damper per (arm geom, obstacle) pair
(Faverjon and Tournassoud 1987).

Solved by DAQP (Arnström, Bemporad and Axehill 2022; a dependency of pink). If the rows conflict
with the bounds (a push drove the arm inside a damper's safety distance), they are relaxed to
``A qdot <= max(b, 0)`` (no approach, no forced retreat), which qdot = 0 always satisfies; if DAQP
still reports no solution (it cannot, short of a numerical failure) the arm is commanded to stop.

References
----------
B. Faverjon and P. Tournassoud, "A local based approach for path planning of manipulators with a
high number of degrees of freedom", IEEE ICRA 1987, 1152-1159.
D. Arnström, A. Bemporad and D. Axehill, "A dual active-set solver for embedded quadratic
programming using recursive LDL^T updates", IEEE TAC 67(8), 4362-4369, 2022.
"""

from __future__ import annotations

from dataclasses import dataclass

import daqp
import numpy as np

from robots.errors import RobotError
from robots.ik.gains import JointGains, check_gain, is_number
from robots.kinematics import Kinematics
from robots.model import ArmModel

__all__ = ["ConstrainedIK", "QpGains"]

_INF = 1e30
_EXIT_OK = (1, 2)      # DAQP: optimal, or optimal with a soft constraint violated


@dataclass(frozen=True)
class QpGains(JointGains):
    """mu: regularisation toward the posture pull, per unit joint speed^2 against 1 (m/s)^2 of task
    error; limit_gain: g in (0, 1], the share of the distance to a soft joint bound that one step may
    cover; rotation_weight: W of the three rotation rows (1 rad/s against 1 m/s of the position rows);
    the joints' gains as ``JointGains``."""

    mu: float = 1e-6
    limit_gain: float = 0.5
    rotation_weight: float = 0.3

    def __post_init__(self) -> None:
        check_gain("QP IK", "mu", self.mu, "a number > 0", lambda v: 0 < v < 1e6)
        for name in ("posture_gain", "limit_margin", "rotation_weight"):
            check_gain("QP IK", name, getattr(self, name), "a number >= 0", lambda v: 0 <= v < 1e6)
        if not all(is_number(v) and 0 < v <= 1 for v in (self.limit_gain, self.speed_fraction)):
            raise RobotError("QP IK gains limit_gain and speed_fraction must be in (0, 1]")


class ConstrainedIK:
    """qdot (n,) from a tool twist (6,) and inequality rows A qdot <= b (module docstring).

    ``solve`` returns qdot and whether the rows had to be relaxed; ``active`` after a solve: the
    rows that hold with equality (within 1e-9 m/s), shape (k,) of bool."""

    def __init__(self, robot: ArmModel, rows: tuple[int, ...], kinematics: Kinematics,
                 gains: QpGains = QpGains()) -> None:
        self.kinematics = kinematics
        self.gains = gains
        self.rows = np.asarray(rows, dtype=int)
        n = robot.n
        self.n = n
        w = np.array([1.0, 1.0, 1.0] + [gains.rotation_weight] * 3)[self.rows]
        self._w2 = (w * w)[:, None]
        self._q_home = np.asarray(robot.q_home, dtype=float)
        self._q_lo = robot.q_min + gains.limit_margin
        self._q_hi = robot.q_max - gains.limit_margin
        self._v_max = np.asarray(robot.v_max, dtype=float) * gains.speed_fraction
        self._mu_eye = gains.mu * np.eye(n)
        self.active = np.zeros(0, dtype=bool)
        self.relaxed = 0

    def bounds(self, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) joint velocity bounds, shape (n,) each, at q (n,) for a step of dt s."""
        g = self.gains.limit_gain / dt
        lo = np.maximum(-self._v_max, np.minimum(g * (self._q_lo - q), 0.0))
        hi = np.minimum(self._v_max, np.maximum(g * (self._q_hi - q), 0.0))
        return lo, hi

    def solve(self, q: np.ndarray, twist: np.ndarray, dt: float, A: np.ndarray, b: np.ndarray,
              kin: Kinematics | None = None) -> tuple[np.ndarray, bool]:
        """Solve Eq. (A2).

        Parameters
        ----------
        q : ndarray, shape (n,)
            Joint positions, rad or m.
        twist : ndarray, shape (6,)
            The desired tool twist (vx vy vz wx wy wz), world, m/s and rad/s.
        dt : float
            The control step, s (> 0).
        A, b : ndarray, shapes (k, n) and (k,)
            The rows A qdot <= b (m/s).
        kin : Kinematics, optional
            Already updated at q.

        Returns
        -------
        (ndarray, bool)
            qdot, shape (n,), and whether the rows had to be relaxed (module docstring).
        """
        if not dt > 0:
            raise RobotError(f"QP IK: the step must be > 0 s, got {dt}")
        A = np.asarray(A, dtype=float)
        b = np.asarray(b, dtype=float)
        if A.ndim != 2 or A.shape[1] != self.n or b.shape != (A.shape[0],):
            raise RobotError(f"QP IK: rows must be A ({A.shape[0] if A.ndim == 2 else '?'}, {self.n}) and b of "
                             f"matching length, got {A.shape} and {b.shape}")
        if kin is None:
            kin = self.kinematics
            kin.update(q)
        jac = kin.ee_jacobian()[self.rows]
        v = np.asarray(twist, dtype=float)[self.rows]
        z = self.gains.posture_gain * (self._q_home - q)
        wj = self._w2 * jac
        H = jac.T @ wj + self._mu_eye
        f = -(wj.T @ v) - self.gains.mu * z
        lo, hi = self.bounds(q, dt)
        A = np.ascontiguousarray(A)
        x, ok = self._qp(H, f, A, b, lo, hi)
        relaxed = False
        if not ok:
            x, ok = self._qp(H, f, A, np.maximum(b, 0.0), lo, hi)
            relaxed = True
            self.relaxed += 1
            if not ok:   # qdot = 0 meets the relaxed rows and every bound: stop
                x = np.zeros(self.n)
        self.active = A @ x >= b - 1e-9 if len(b) else np.zeros(0, dtype=bool)
        return x, relaxed

    def _qp(self, H: np.ndarray, f: np.ndarray, A: np.ndarray, b: np.ndarray, lo: np.ndarray,
            hi: np.ndarray) -> tuple[np.ndarray, bool]:
        """DAQP on the bounds (the first n constraints, simple bounds) and the rows."""
        k = len(b)
        upper = np.concatenate([hi, b])
        lower = np.concatenate([lo, np.full(k, -_INF)])
        sense = np.zeros(self.n + k, dtype=np.int32)
        x, _, flag, _ = daqp.solve(H, f, A, upper, lower, sense)
        return np.asarray(x, dtype=float), flag in _EXIT_OK
