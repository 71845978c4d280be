"""One control step: task velocity -> tool twist -> differential IK -> actuator command.

Twist (world axes, LOCAL_WORLD_ALIGNED, rows vx vy vz wx wy wz) from a task velocity v, shape (d,):

    v_lin = s A v - k_n n n^T (p - o)         (second term: 2-D task on a spatial arm; holds p on the plane)
    w     = k_r log(R_ref R^T)                (spatial arm: holds the tool orientation R at R_ref)

qdot = IK(q, twist) (``robots.DifferentialIK``), then the actuator command:

* ``position`` servos (MuJoCo tau = kp (u - q) - kv qdot + gravity compensation), with
  u = q + qdot_ref (kv + b) / kp, so tau = kv (qdot_ref - qdot) + b qdot_ref: a velocity servo
  that also pays the joint's viscous damping b (``feedforward=True``, the default), or the plain
  u = q + qdot_ref dt (``feedforward=False``; it lags and under-speeds, see scripts/bench_loop.py).
* ``torque`` motors, computed torque with Pinocchio's RNEA:
  tau = RNEA(q, qdot, qddot_ref + k_d (qdot_ref - qdot)) + b qdot, qddot_ref = (qdot_ref - qdot_ref_prev) / dt.

Choice of actuation (measured by scripts/bench_loop.py; Panda, default spiral ~13 cm, horizontal
plane, dls IK, 500 Hz; 20 N / 0.2 s push on the hand at t = 1 s; load average ~3 on 2 cores):

    field        actuation                  tracking RMSE  final goal  push max dev  recovery
    NODE         servo u = q + qdot dt         79.6 mm      67.4 mm      13.8 mm      never
    NODE         servo + velocity feed-fwd      7.6 mm       0.12 mm     22.4 mm      4.08 s
    NODE         computed torque (RNEA)         0.90 mm      0.06 mm      6.0 mm      0.32 s
    contraction  servo u = q + qdot dt         79.4 mm      68.5 mm      13.8 mm      never
    contraction  servo + velocity feed-fwd     10.4 mm       1.58 mm     25.0 mm      1.09 s
    contraction  computed torque (RNEA)         0.95 mm      0.61 mm      8.5 mm      0.82 s

The plain servo command only asks for the distance of one step, so the arm crawls (kp dt / kv
of the requested speed); the velocity feed-forward fixes the speed but the servo's first-order
lag (time constant M / kv = 1 / (2 zeta w) ~ 8 ms with the robots' w = 60 rad/s) still costs
~10 mm. Computed torque cancels the arm's
dynamics with Pinocchio's RNEA on the same model and adds the acceleration feed-forward, so the
tool follows the field to ~1 mm, ~10x better: it is the default. k_d trades tracking against
compliance: 40 / 80 / 150 / 300 1/s gave 2.6 / 1.4 / 0.90 / 0.74 mm tracking and 21 / 11 / 6.0 /
3.0 mm push deviation (NODE); 150 keeps the push visible (> 5 mm) and the tracking below 1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import pinocchio as pin

from robots import DifferentialIK, RobotModel
from sim.errors import SimError
from sim.placement import Placement

ACTUATIONS: tuple[str, ...] = ("position", "torque")


@dataclass(frozen=True)
class Gains:
    """plane : k_n (1/s); rotation : k_r (1/s); torque_kd : k_d (1/s) of computed torque."""

    plane: float = 20.0
    rotation: float = 10.0
    torque_kd: float = 150.0


def actuation_of(robot: RobotModel, model: mujoco.MjModel | None = None) -> str:
    """``position`` if every arm actuator is a servo (affine bias), ``torque`` if none is."""
    model = robot.mj_model if model is None else model
    servo = model.actuator_biastype[robot.mj_actuator_ids] == mujoco.mjtBias.mjBIAS_AFFINE
    if servo.any() != servo.all():
        raise SimError(f"robot '{robot.name}' mixes position servos and motors on its arm joints")
    return "position" if servo.all() else "torque"


class FieldController:
    """Maps a task velocity to actuator commands for ``robot`` placed by ``placement``.

    Call ``measure(q)`` (Pinocchio FK at the measured joints; returns the tool position p,
    shape (3,)) and then ``command(q, qdot, v)`` with the task velocity v, shape (d,), at the
    same q; it returns the actuator controls, shape (n,), in ``robot.mj_actuator_ids`` order.
    """

    def __init__(self, robot: RobotModel, placement: Placement, control_dt: float, ik: str = "dls",
                 actuation: str | None = None, rotation_ref: np.ndarray | None = None,
                 gains: Gains = Gains(), feedforward: bool = True,
                 mj_model: mujoco.MjModel | None = None) -> None:
        model = robot.mj_model if mj_model is None else mj_model
        found = actuation_of(robot, model)
        if actuation is None:
            actuation = found
        if actuation not in ACTUATIONS:
            raise SimError(f"unknown actuation '{actuation}'; known: {', '.join(ACTUATIONS)}")
        if actuation != found:
            raise SimError(f"actuation '{actuation}' needs the robot loaded with actuation='{actuation}'")
        if robot.planar and placement.dim != 2:
            raise SimError(f"robot '{robot.name}' moves in a plane; it cannot follow a {placement.dim}-D field")
        self.robot, self.placement, self.dt = robot, placement, float(control_dt)
        self.actuation, self.gains, self.feedforward = actuation, gains, feedforward
        rows = (0, 1) if robot.planar else None
        self.ik = DifferentialIK(robot, backend=ik, rows=rows)
        self.kin = self.ik.kinematics
        self._pass_kin = ik == "dls"
        self._origin = placement.origin.copy()
        self._sA = np.ascontiguousarray(placement.scale * placement.axes)        # (3, d)
        self._At_s = np.ascontiguousarray(placement.axes.T / placement.scale)     # (d, 3)
        self._plane = placement.dim == 2 and not robot.planar
        self._spatial = not robot.planar
        self._kn_n = gains.plane * placement.normal
        self._normal = placement.normal.copy()
        self._n_o = float(placement.normal @ placement.origin)
        self._kr = float(gains.rotation)
        self.rotation_ref = None if rotation_ref is None else np.asarray(rotation_ref, dtype=np.float64).copy()
        self._twist = np.zeros(6)
        dofs = robot.mj_dof_adr
        self._damping = model.dof_damping[dofs].copy()
        acts = robot.mj_actuator_ids
        if actuation == "position":
            kp = model.actuator_gainprm[acts, 0].copy()
            kv = -model.actuator_biasprm[acts, 2].copy()
            if (kp <= 0).any():
                raise SimError(f"robot '{robot.name}' has no position servos (load it with actuation='position')")
            self._lead = (kv + self._damping) / kp if feedforward else np.full(len(kp), self.dt)
        else:
            self._pin_model = robot.pin_model
            self._pin_data = robot.pin_model.createData()
            self._kd, self._inv_dt = float(gains.torque_kd), 1.0 / self.dt
            self._c_ref = self._inv_dt + self._kd
        self._qdot_prev = np.zeros(robot.n)

    def reset(self, q: np.ndarray) -> None:
        """Start a run at rest at q, shape (n,); sets R_ref to the tool orientation there if unset."""
        self._qdot_prev = np.zeros(self.robot.n)
        self.kin.update(np.asarray(q, dtype=np.float64))
        if self.rotation_ref is None and self._spatial:
            self.rotation_ref = self.kin.ee_rotation().copy()

    def measure(self, q: np.ndarray) -> np.ndarray:
        """FK at q, shape (n,): the tool position p, shape (3,) (a view valid until the next call)."""
        self.kin.update(q)
        return self.kin.ee_position()

    def to_task(self, p: np.ndarray) -> np.ndarray:
        """x = A^T (p - o) / s, shape (d,)."""
        return self._At_s.dot(p - self._origin)

    def twist(self, v: np.ndarray) -> np.ndarray:
        """The tool twist, shape (6,), for task velocity v, shape (d,), at the last measured pose."""
        # ndarray.dot costs about half of @ on these tiny operands (call overhead dominates)
        tw = self._twist
        if self._plane:
            tw[:3] = self._sA.dot(v) - self._kn_n * (self._normal.dot(self.kin.ee_position()) - self._n_o)
        else:
            tw[:3] = self._sA.dot(v)
        if self._spatial:
            tw[3:] = self._kr * pin.log3(self.rotation_ref.dot(self.kin.ee_rotation().T))
        return tw

    def solve_ik(self, q: np.ndarray, twist: np.ndarray) -> np.ndarray:
        """qdot_ref, shape (n,), for the twist, shape (6,), at the measured q (FK already done)."""
        if self._pass_kin:
            return self.ik.solve(q, twist, self.dt, kin=self.kin)
        return self.ik.solve(q, twist, self.dt)

    def actuate(self, q: np.ndarray, qdot: np.ndarray, qdot_ref: np.ndarray) -> np.ndarray:
        """Actuator controls, shape (n,), that make the joints move at qdot_ref (module docstring)."""
        if self.actuation == "position":
            return q + self._lead * qdot_ref
        # qddot_ref + k_d (qdot_ref - qdot) = (1/dt + k_d) qdot_ref - qdot_ref_prev / dt - k_d qdot
        acc = self._c_ref * qdot_ref - self._inv_dt * self._qdot_prev - self._kd * qdot
        self._qdot_prev = qdot_ref
        return pin.rnea(self._pin_model, self._pin_data, q, qdot, acc) + self._damping * qdot

    def command(self, q: np.ndarray, qdot: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Actuator controls, shape (n,), for task velocity v, shape (d,), at the measured q, qdot."""
        return self.actuate(q, qdot, self.solve_ik(q, self.twist(v)))
