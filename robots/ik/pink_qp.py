"""Differential IK through pin-pink's QP: FrameTask toward the tool pose advanced by twist dt, PostureTask, limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import qpsolvers
from pink import Configuration, build_ik
from pink.limits import ConfigurationLimit, VelocityLimit
from pink.tasks import FrameTask, PostureTask

from robots.errors import RobotError
from robots.ik.gains import JointGains
from robots.kinematics import Kinematics
from robots.model import RobotModel


@dataclass(frozen=True)
class PinkGains(JointGains):
    """posture_cost: weight of the posture task relative to the tool task (cost 1 per m and per rad);
    config_limit_gain: pink's ConfigurationLimit gain in (0, 1]; damping: Tikhonov regularisation of the QP;
    the joints' gains as ``JointGains`` (speed_fraction: the QP's velocity limit)."""

    posture_cost: float = 1e-3
    config_limit_gain: float = 0.5
    damping: float = 1e-12


def _task_costs(robot: RobotModel, rows: tuple[int, ...], rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FrameTask (position, orientation) costs, per axis of the TOOL frame, selecting the world-frame ``rows``.

    A cost vector in the tool frame selects world rows only when the selection is rotation invariant: all position
    rows and/or all orientation rows, or, for a planar arm whose tool z is world z, the position rows x, y."""
    rows_set = set(rows)
    pos, ori = rows_set & {0, 1, 2}, rows_set & {3, 4, 5}
    if pos in (set(), {0, 1, 2}) and ori in (set(), {3, 4, 5}):
        return np.full(3, float(bool(pos))), np.full(3, float(bool(ori)))
    if robot.planar and rows_set == {0, 1} and abs(abs(rotation[2, 2]) - 1.0) < 1e-9:
        return np.array([1.0, 1.0, 0.0]), np.zeros(3)
    raise RobotError(f"pink backend cannot select rows {rows} (tool-frame costs); use backend 'dls'")


class PinkBackend:
    """qdot = dq / dt with dq the solution of pink's QP (solver daqp):
        min_dq  || J_b dq - log(T_b^-1 T_target) ||^2_W + c_p || dq - alpha (q_home - q) ||^2 + mu ||dq||^2
        s.t.    -v dt <= dq <= v dt,   g min(q_min + margin - q, 0) <= dq <= g max(q_max - margin - q, 0)
    with T_target = (exp(w dt) R, p + v dt) the current tool pose advanced by the twist [v; w], W the tool-frame
    row selection, alpha = min(1, k_p dt), v = speed_fraction v_max. limit_hits counts the solve() calls whose
    solution touches a bound."""

    def __init__(self, robot: RobotModel, rows: tuple[int, ...], kinematics: Kinematics, gains: PinkGains) -> None:
        self.kinematics = kinematics
        self.gains = gains
        model = robot.pin_model.copy()
        model.lowerPositionLimit = robot.q_min + gains.limit_margin
        model.upperPositionLimit = robot.q_max - gains.limit_margin
        model.velocityLimit = np.asarray(robot.v_max, dtype=float) * gains.speed_fraction
        self._model = model
        self._v_max = model.velocityLimit.copy()
        self._q_lo, self._q_hi = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
        self._configuration = Configuration(model, model.createData(), np.asarray(robot.q_home, dtype=float),
                                            copy_data=False)
        self._frame = robot.ee_frame
        rotation = self._configuration.get_transform_frame_to_world(self._frame).rotation
        position_cost, orientation_cost = _task_costs(robot, rows, rotation)
        self._frame_task = FrameTask(robot.ee_frame, position_cost=position_cost, orientation_cost=orientation_cost)
        self._posture_task = PostureTask(cost=gains.posture_cost)
        self._posture_task.set_target(np.asarray(robot.q_home, dtype=float))
        self._tasks = [self._frame_task, self._posture_task]
        self._limits = [ConfigurationLimit(model, gains.config_limit_gain), VelocityLimit(model)]
        self.limit_hits = 0

    def solve(self, q: np.ndarray, twist: np.ndarray, dt: float, kin: Kinematics | None = None) -> np.ndarray:
        """qdot (n,) for joint positions q (n,) and desired tool twist [v; w] (6,) over a step dt [s]."""
        configuration = self._configuration
        self._model.lowerPositionLimit = np.minimum(self._q_lo, q)  # beyond a soft bound: do not go further out
        self._model.upperPositionLimit = np.maximum(self._q_hi, q)
        configuration.update(q)
        pose = configuration.get_transform_frame_to_world(self._frame)
        target = pin.SE3(pin.exp3(np.asarray(twist[3:]) * dt) @ pose.rotation,
                         pose.translation + np.asarray(twist[:3]) * dt)
        self._frame_task.set_target(target)
        self._posture_task.gain = min(1.0, self.gains.posture_gain * dt)
        problem = build_ik(configuration, self._tasks, dt, damping=self.gains.damping, limits=self._limits)
        result = qpsolvers.solve_problem(problem, solver="daqp")
        if not result.found or result.x is None:
            raise RobotError("pink IK: the QP has no solution at this configuration")
        qdot = result.x / dt
        g = self.gains.config_limit_gain
        tol = 1e-9
        at_bound = ((np.abs(qdot) >= self._v_max * (1 - 1e-7))
                    | (qdot * dt <= g * np.minimum(self._q_lo - q, 0.0) + tol)
                    | (qdot * dt >= g * np.maximum(self._q_hi - q, 0.0) - tol))
        self.limit_hits += bool(at_bound.any())
        return qdot
