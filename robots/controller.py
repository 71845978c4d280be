"""The arm's controller without a simulator: measured joints in, the next joint-velocity command out.

One control step k at time t_k (the loop's, on hardware or in ``sim``):

1. FK: the tool pose p, R = FK(q) (Pinocchio, ``robots.Kinematics``) and its task point
   x = ``TaskFrame.point(p, R)`` (``robots.task_frame``);
2. the policy: v = pi(x - dg, t_k), the learned field's runner (``lfd.runner``: it carries a phase
   or the time itself) at the point shifted by a goal offset dg (zero unless set);
3. the twist ``TaskFrame.twist`` and the differential IK, qdot_IK = IK(q, twist) (damped least
   squares with the null-space posture and the joint position and velocity limits, ``robots.ik.dls``);
   where a guard (``guard``: safety rows, e.g. whole-arm collision dampers) says a row binds for
   qdot_IK, the IK is solved again as a QP with its rows A qdot <= b (``robots.ik.constrained``);
4. the limiter: qdot_cmd = L(qdot_IK), the next command of an online jerk-limited stream within the
   arm's velocity, acceleration and jerk limits (``robots.limiter``; None: qdot_IK itself). Where
   the time t advanced by more than one step since the last call (a hardware loop that missed
   cycles), the policy is first stepped once per missed step at the measured point, so that a
   runner that advances its phase per call keeps up with the time.

``ArmController(q, dq, t)`` runs the four; ``point(q)`` (1) and ``command(v)`` (3-4) are its two halves,
which ``sim``'s control step calls around the field so that a simulated run records x and v. The
controller imports nothing of MuJoCo, dm_control or rendering: it runs wherever Pinocchio, Ruckig
and the policy do.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from robots.errors import RobotError
from robots.ik import DifferentialIK
from robots.ik.constrained import ConstrainedIK, QpGains
from robots.limiter import JointLimiter
from robots.limits import Limits
from robots.model import ArmModel
from robots.task_frame import TaskFrame

#: a guard: the rows (A (r, n), b (r,)) of A qdot <= b to impose when one binds for the IK's qdot at q, else None
Guard = Callable[[np.ndarray, np.ndarray], "tuple[np.ndarray, np.ndarray] | None"]
#: a policy: the task velocity v (d,) at the task point x (d,) and the time t, s (``lfd.runner.Runner``)
Policy = Callable[[np.ndarray, float], np.ndarray]


class ArmController:
    """The controller of the module docstring for one arm and one task.

    Parameters
    ----------
    arm : ArmModel
        The arm's kinematics (``robots.load_robot`` or, without MuJoCo, ``robots.pinocchio_arm.load_urdf_arm``).
    frame : TaskFrame
        Where the task sits on the arm.
    dt : float
        The control step, s.
    limits : Limits, optional
        The arm's limits for the limiter (None: no limiter, the IK's joint velocity is the command).
    fraction : float
        The share of each limit the limited stream may use (``robots.limiter``).
    guard : Guard, optional
        guard(q, qdot_IK) -> (A, b) or None: safety rows for step 3 (module docstring).

    Attributes
    ----------
    x : ndarray, shape (d,)
        The task point of the last ``point`` (unshifted).
    p, rot : ndarray, shape (3,) and (3, 3)
        The tool pose of the last ``point``, world (views valid until the next).
    v : ndarray, shape (d,)
        The task velocity of the last step.
    dq_ik, dq_cmd : ndarray, shape (n,)
        The IK's joint velocity and the command of the last step, rad/s.
    offset : ndarray, shape (d,)
        The goal offset dg subtracted from the task point before the policy (zero by default).
    guarded : bool
        Whether a guard row was at its bound in the last step's QP.
    """

    def __init__(self, arm: ArmModel, frame: TaskFrame, dt: float, limits: Limits | None = None,
                 fraction: float = 0.95, guard: Guard | None = None) -> None:
        if arm.planar and frame.dim != 2:
            raise RobotError(f"robot '{arm.name}' moves in a plane; it cannot follow a {frame.dim}-D field")
        self.arm, self.frame, self.dt = arm, frame, float(dt)
        self.ik = DifferentialIK(arm, backend="dls", rows=(0, 1) if arm.planar else None)
        self.kin = self.ik.kinematics
        self.limiter = None if limits is None else JointLimiter(limits, self.dt, fraction)
        self.guard = guard
        self.guarded = False
        self._cik: ConstrainedIK | None = None
        if guard is not None:
            own = self.ik.gains   # the QP keeps the DLS's posture and limits
            self._cik = ConstrainedIK(arm, tuple(self.ik.rows), self.kin, QpGains(
                posture_gain=own.posture_gain, limit_margin=own.limit_margin, speed_fraction=own.speed_fraction))
        self.offset = np.zeros(frame.dim)
        self.policy: Policy | None = None
        self.x = np.zeros(frame.dim)
        self.v = np.zeros(frame.dim)
        self.p, self.rot = np.zeros(3), np.eye(3)
        self.dq_ik = self.dq_cmd = np.zeros(arm.n)
        self._q = np.zeros(arm.n)
        self._t_prev: float | None = None

    def start(self, policy: Policy | None = None, dq: np.ndarray | None = None) -> None:
        """Begin a motion with ``policy`` (v = policy(x - dg, t); None: a caller that runs ``point``
        and ``command`` around its own policy) from the joint velocity dq, shape (n,) (default
        rest): the limiter's stream starts there."""
        self.policy = policy
        self._t_prev = None
        if self.limiter is not None:
            self.limiter.reset(np.zeros(self.arm.n) if dq is None else dq)

    def point(self, q: np.ndarray) -> np.ndarray:
        """Step 1: FK at the measured joints q, shape (n,); returns the task point x - dg, shape (d,)."""
        q = np.asarray(q, dtype=np.float64)
        self._q = q
        self.p = self.kin.update_position(q)
        self.rot = self.kin.pose[2] if self.kin.pose is not None else self.kin.read_pose()[2]
        self.x = self.frame.point(self.p, self.rot)
        return self.x - self.offset

    def command(self, v: np.ndarray) -> np.ndarray:
        """Steps 3-4 for the task velocity v, shape (d,), at the pose of the last ``point``: the joint
        velocity command, shape (n,), rad/s."""
        self.v = v
        tw = self.frame.twist(self.x, v, self.p, self.rot)
        dq = self.ik.solve(self._q, tw, self.dt, kin=self.kin)
        if self.guard is not None and self._cik is not None:
            rows = self.guard(self._q, dq)
            self.guarded = False
            if rows is not None and len(rows[1]):
                dq, _ = self._cik.solve(self._q, tw, self.dt, rows[0], rows[1], kin=self.kin)
                self.guarded = bool(self._cik.active.any())
        self.dq_ik = dq
        self.dq_cmd = dq if self.limiter is None else self.limiter(dq)
        return self.dq_cmd

    def __call__(self, q: np.ndarray, dq: np.ndarray, t: float) -> np.ndarray:
        """One control step (module docstring) at the measured joints q, dq, shape (n,), and time t, s.

        Returns
        -------
        ndarray, shape (n,)
            The joint velocity command, rad/s.
        """
        if self.policy is None:
            raise RobotError("start the controller with a policy first (ArmController.start)")
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.arm.n,) or not np.isfinite(q).all():
            raise RobotError(f"the measured joints must be {self.arm.n} finite numbers, got {np.asarray(q).tolist()}")
        x = self.point(q)
        if self._t_prev is not None:
            missed = int(round((t - self._t_prev) / self.dt)) - 1
            for k in range(missed):   # a runner that steps its phase per call catches up with the time
                self.policy(x, self._t_prev + (k + 1) * self.dt)
        self._t_prev = t
        return self.command(self.policy(x, t))
