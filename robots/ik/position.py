"""Iterative IK to a tool position (and optional orientation), for placement reachability and start postures."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from robots.kinematics import Kinematics
from robots.model import ArmModel

_DAMPING2 = 1e-8       # lambda^2 of the Levenberg-Marquardt step
_MAX_STEP = 0.3        # largest joint step per iteration [rad|m]
_RESTARTS = 8          # extra seeded starts when the first one fails


def _descend(kin: Kinematics, robot: ArmModel, position: np.ndarray, rotation: np.ndarray | None, rows: np.ndarray,
             q: np.ndarray, tol: float, max_iters: int, posture: float = 0.0) -> tuple[np.ndarray, float, float]:
    """Damped Gauss-Newton from q: dq = J# e + posture (I - J# J) (q_home - q), J# = J^T (J J^T + lambda^2 I)^-1,
    q <- clip(q + dq, q_min, q_max); e = [p* - p; log(R* R^T)] restricted to ``rows``. Returns (q, position
    error [m], rotation error [rad])."""
    eye = np.eye(len(rows))
    for _ in range(max_iters + 1):
        kin.update(q)
        err = np.zeros(6)
        err[:3] = position - kin.ee_position()
        if rotation is not None:
            err[3:] = pin.log3(rotation @ kin.ee_rotation().T)
        e = err[rows]
        pos_err = float(np.linalg.norm(e[rows < 3]))
        rot_err = float(np.linalg.norm(e[rows >= 3])) if rotation is not None else 0.0
        if pos_err < tol and rot_err < tol:
            break
        jac = kin.ee_jacobian()[rows]
        if posture:
            z = posture * (robot.q_home - q)
            dq = z + jac.T @ np.linalg.solve(jac @ jac.T + _DAMPING2 * eye, e - jac @ z)
        else:
            dq = jac.T @ np.linalg.solve(jac @ jac.T + _DAMPING2 * eye, e)
        step = np.max(np.abs(dq))
        if step > _MAX_STEP:
            dq *= _MAX_STEP / step
        q = np.clip(q + dq, robot.q_min, robot.q_max)
    return q, pos_err, rot_err


def solve_position_ik(robot: ArmModel, position: np.ndarray, rotation: np.ndarray | None = None,
                      q0: np.ndarray | None = None, tol: float = 1e-6,
                      max_iters: int = 500) -> tuple[np.ndarray, float]:
    """Joint positions q (n,) within limits putting the tool at ``position`` (3,) (and ``rotation`` (3, 3) if given).

    Starts from q0 (default q_home), then from up to 8 seeded random postures within limits if that fails; returns
    the best (q, position error in m). For a planar arm only x, y count (the tool stays in its plane). An
    unreachable target is not an error here: the caller compares the returned error with its tolerance.
    """
    q, pos_err, _ = solve_pose_ik(robot, position, rotation, q0, tol, max_iters)
    return q, pos_err


def solve_pose_ik(robot: ArmModel, position: np.ndarray, rotation: np.ndarray | None = None,
                  q0: np.ndarray | None = None, tol: float = 1e-6,
                  max_iters: int = 500, posture: float = 0.0) -> tuple[np.ndarray, float, float]:
    """As ``solve_position_ik``, returning (q (n,), position error [m], rotation error [rad]); the
    rotation error is 0 without a ``rotation``. ``posture`` > 0 pulls the redundant joints toward
    q_home in the task's null space at that gain per iteration (the control loop's IK does the same),
    so a path followed warm-started stays away from the joint limits where it can."""
    kin = Kinematics(robot)
    position = np.asarray(position, dtype=float)
    rows = np.array([0, 1] if robot.planar else [0, 1, 2])
    if rotation is not None:
        rotation = np.asarray(rotation, dtype=float)
        rows = np.concatenate([rows, [5] if robot.planar else [3, 4, 5]])
    start = np.asarray(robot.q_home if q0 is None else q0, dtype=float)
    best = _descend(kin, robot, position, rotation, rows, np.clip(start, robot.q_min, robot.q_max), tol, max_iters,
                    posture)
    rng = np.random.default_rng(0)
    for _ in range(_RESTARTS):
        if best[1] < tol and best[2] < tol:
            break
        trial = _descend(kin, robot, position, rotation, rows, rng.uniform(robot.q_min, robot.q_max), tol, max_iters,
                         posture)
        if trial[1] + trial[2] < best[1] + best[2]:
            best = trial
    return best
