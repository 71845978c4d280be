"""An online jerk-limited limiter of a joint-velocity command stream (Ruckig's velocity interface).

A real arm checks every command it receives: the Franka's FCI aborts a motion (a "reflex") when the
commanded joint velocity, or its acceleration or jerk by finite differences at 1 kHz, leaves its
limits (``robots.limits``). ``JointLimiter`` sits between the IK and the arm: each control step it
takes the IK's joint velocity as a target and returns the next command of Ruckig's time-optimal,
jerk-limited trajectory toward it (Berscheid and Kroeger, "Jerk-limited real-time trajectory
generation with arbitrary target states", RSS 2021), each joint on its own (no synchronisation: a
velocity target has no common arrival time to agree on). Its state is the command stream's own
(velocity and acceleration of the last command), never the measured joints, so the stream is
continuous to the second derivative whatever the arm does.

Guarantee: with ``fraction`` <= 1, every command's velocity is within ``fraction`` dq_max and the
stream's accelerations and jerks by finite differences over one step, (v_k - v_{k-1}) / dt and
(a_k - a_{k-1}) / dt, are within ``fraction`` ddq_max and ``fraction`` dddq_max: Ruckig's
trajectory has its acceleration and jerk within those bounds at every instant, so its averages over
a step do too. A target beyond the velocity bound is saturated to it.
"""

from __future__ import annotations

import math

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, Synchronization

from robots.errors import RobotError
from robots.limits import Limits

#: the share of each limit the stream may use: a margin against the float round-off of the checks
DEFAULT_FRACTION = 0.95
_WORKING, _FINISHED = Result.Working, Result.Finished


class JointLimiter:
    """The limiter of the module docstring for one arm.

    Parameters
    ----------
    limits : Limits
        The arm's joint velocity, acceleration and jerk limits (all finite).
    dt : float
        The control step, s.
    fraction : float
        The share of each limit the command stream may use, in (0, 1].

    Attributes
    ----------
    v_max : ndarray, shape (n,)
        The velocity bound, ``fraction`` dq_max, rad/s.
    """

    def __init__(self, limits: Limits, dt: float, fraction: float = DEFAULT_FRACTION) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise RobotError(f"the limiter's step must be a positive time, got {dt}")
        if not (math.isfinite(fraction) and 0 < fraction <= 1):
            raise RobotError(f"the limiter's fraction of the limits must be in (0, 1], got {fraction}")
        bounds = (limits.dq_max, limits.ddq_max, limits.dddq_max)
        if not all(np.isfinite(b).all() for b in bounds):
            raise RobotError(f"'{limits.name}' has no finite joint acceleration and jerk limits "
                             f"(assumed: {', '.join(limits.assumed)}); a limiter needs them")
        self.n, self.dt, self.fraction = limits.n, float(dt), float(fraction)
        self.v_max = fraction * limits.dq_max
        self._v_min = -self.v_max
        self._otg = Ruckig(self.n, self.dt)
        inp = self._inp = InputParameter(self.n)
        self._out = OutputParameter(self.n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.max_velocity = self.v_max.tolist()
        inp.max_acceleration = (fraction * limits.ddq_max).tolist()
        inp.max_jerk = (fraction * limits.dddq_max).tolist()
        self._last = (np.zeros(self.n), np.zeros(self.n))
        self.reset(np.zeros(self.n))

    def reset(self, dq: np.ndarray, ddq: np.ndarray | None = None) -> None:
        """Start a stream at the joint velocity dq, shape (n,) (rad/s; saturated to the bound), and
        acceleration ddq, shape (n,) (default zero)."""
        v = np.clip(np.asarray(dq, dtype=np.float64).reshape(-1), -self.v_max, self.v_max)
        a = np.zeros(self.n) if ddq is None else np.asarray(ddq, dtype=np.float64).reshape(-1)
        if v.shape != (self.n,) or a.shape != (self.n,) or not (np.isfinite(v).all() and np.isfinite(a).all()):
            raise RobotError(f"the limiter starts from {self.n} finite joint velocities and accelerations")
        inp = self._inp
        inp.current_position = [0.0] * self.n
        inp.current_velocity = v.tolist()
        inp.current_acceleration = a.tolist()
        self._last = (v, v)

    def __call__(self, target: np.ndarray) -> np.ndarray:
        """The next command toward the joint velocity ``target``, shape (n,), rad/s.

        Returns
        -------
        ndarray, shape (n,)
            The command, rad/s (module docstring).
        """
        t = np.minimum(np.maximum(target, self._v_min), self.v_max)   # np.clip costs 2.5x this here
        inp, out = self._inp, self._out
        inp.target_velocity = t.tolist()
        result = self._otg.update(inp, out)
        if result != _WORKING and result != _FINISHED:
            raise RobotError(f"the limiter failed ({result.name}) for the target {np.round(target, 4).tolist()}")
        v = np.array(out.new_velocity)
        out.pass_to_input(inp)   # positions are not limited here (the IK keeps them)
        self._last = (v, target)
        return v

    @property
    def acted(self) -> bool:
        """Whether the last command differs from its target by more than 1e-9 rad/s on any joint
        (measured when read, off the control step's path)."""
        v, target = self._last
        return bool(np.max(np.abs(v - target)) > 1e-9)

    @property
    def acceleration(self) -> np.ndarray:
        """The command stream's acceleration after the last step, shape (n,), rad/s^2."""
        return np.array(self._inp.current_acceleration)
