"""One control step: task velocity -> tool twist -> differential IK -> actuator command.

Twist (world axes, LOCAL_WORLD_ALIGNED, rows vx vy vz wx wy wz) from a task velocity v, shape (d,):

    v_lin = s A v - k_n n n^T (p - o)         (second term: 2-D task on a spatial arm; holds p on the plane)
    w     = k_r log(R_ref R^T)                (spatial arm: holds the tool orientation R at R_ref)

qdot = IK(q, twist) (``robots.DifferentialIK``), then the actuator command:

* ``position`` servos (MuJoCo tau = kp (u - q) - kv qdot + gravity compensation), with
  u = q + qdot_ref (kv + b) / kp, so tau = kv (qdot_ref - qdot) + b qdot_ref: a velocity servo
  that also pays the joint's viscous damping b (``feedforward=True``, the default), or the plain
  u = q + qdot_ref dt (``feedforward=False``; it lags and under-speeds, see scripts/bench_loop.py).
* ``torque`` motors, computed torque:
  tau = M(q) a + c(q, qdot) + b qdot = RNEA(q, qdot, a) + b qdot, a = qddot_ref + k_d (qdot_ref - qdot),
  qddot_ref = (qdot_ref - qdot_ref_prev) / dt. With ``dynamics="mujoco"`` (the default) M(q) a comes
  from ``mujoco.mj_mulM`` and c = ``qfrc_bias`` of the step's own ``mj_step1`` (the loop splits
  ``mj_step`` into ``mj_step1`` / ``mj_step2``), so no second inverse-dynamics pass runs; with
  ``dynamics="pinocchio"`` Pinocchio's RNEA on the same model. Both agree to ~1e-14 N m on the
  Panda (same inertias and armature), and the closed-loop tool paths to ~1e-9 m
  (tests/test_control_step.py).

Fast path (``fast_command``): twist, the DLS solve (Cholesky fast path of ``robots.ik.dls``) and the
actuator command are one compiled numba function (``_kernel``, compiled once per machine, cached
beside this file); it hands back to the Python path (``twist`` / ``solve_ik`` / ``actuate``, same
results) whenever the DLS fast path does not apply (near a singularity or a joint limit, tool
orientation error near pi) and for the ``pink`` IK or custom IK rows.

Choice of actuation: computed torque is the default; the measured comparison of the three
commands and of the damping gain k_d is in reports/arm.md (scripts/bench_loop.py refreshes it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin

from robots import DifferentialIK, RobotModel
from sim.errors import SimError
from sim.placement import Placement

ACTUATIONS: tuple[str, ...] = ("position", "torque")
DYNAMICS: tuple[str, ...] = ("mujoco", "pinocchio")

# layout of the kernel's parameter vector: _HEADER scalars, then Rref (9), k_n n (3), n (3), s A (3 d),
# then q_home, mid, fast_half, damping, lead, dof address (n each)
_HEADER = 16
_KERNEL: Any = None


def _compile() -> Any:
    import numba

    @numba.njit(cache=True, fastmath=False, nogil=True)
    def kernel(jac: np.ndarray, p: np.ndarray, rot: np.ndarray, v: np.ndarray, q: np.ndarray,
               qvel: np.ndarray, bias: np.ndarray, qprev: np.ndarray, prm: np.ndarray,
               out: np.ndarray) -> int:  # pragma: no cover - compiled
        """Twist + DLS fast path + actuator command; see ``FieldController.fast_command``.
        Returns 0 (done: out holds qdot_ref (n), a (nv, torque) and the command's base (n)), else the
        reason to take the Python path (1: rotation near pi, 2: near a singularity, 3: near a limit)."""
        plane, spatial, n_o, kr = prm[0] != 0.0, prm[1] != 0.0, prm[2], prm[3]
        eps2, fast_speed2, c_ref, inv_dt, kd, kp = prm[4], prm[5], prm[6], prm[7], prm[8], prm[9]
        torque = prm[10] != 0.0
        d, n, nv, m = int(prm[11]), int(prm[12]), int(prm[13]), int(prm[14])
        o = _HEADER
        rref = prm[o:o + 9]
        knn = prm[o + 9:o + 12]
        nrm = prm[o + 12:o + 15]
        o += 15
        sa = prm[o:o + 3 * d]
        o += 3 * d
        qh, mid, half = prm[o:o + n], prm[o + n:o + 2 * n], prm[o + 2 * n:o + 3 * n]
        damp, lead, dadr = prm[o + 3 * n:o + 4 * n], prm[o + 4 * n:o + 5 * n], prm[o + 5 * n:o + 6 * n]
        tw = np.zeros(6)
        for i in range(3):
            acc = 0.0
            for j in range(d):
                acc += sa[i * d + j] * v[j]
            tw[i] = acc
        if plane:
            e = nrm[0] * p[0] + nrm[1] * p[1] + nrm[2] * p[2] - n_o
            for i in range(3):
                tw[i] -= knn[i] * e
        if spatial:
            # E = Rref R^T; w = k_r log3(E)
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
            tw[3], tw[4], tw[5] = kr * f * wx, kr * f * wy, kr * f * wz
        # DLS: qdot = z + J^T (J J^T)^-1 (v - J z), J = jac[:m]; valid if J J^T - eps^2 I > 0
        z = np.empty(n)
        for k in range(n):
            z[k] = kp * (qh[k] - q[k])
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
        low = np.zeros((m, m))
        for shift in (eps2, 0.0):   # Cholesky of J J^T - eps^2 I (the test), then of J J^T (the solve)
            for j in range(m):
                acc = jjt[j, j] - shift
                for k in range(j):
                    acc -= low[j, k] * low[j, k]
                if not acc > 0.0:
                    return 2
                low[j, j] = np.sqrt(acc)
                for i in range(j + 1, m):
                    acc = jjt[i, j]
                    for k in range(j):
                        acc -= low[i, k] * low[j, k]
                    low[i, j] = acc / low[j, j]
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
        speed2 = 0.0
        for k in range(n):
            acc = z[k]
            for i in range(m):
                acc += y[i] * jac[i, k]
            out[k] = acc
            speed2 += acc * acc
            if abs(q[k] - mid[k]) > half[k]:
                return 3
        if speed2 > fast_speed2:
            return 3
        if torque:
            for i in range(nv):
                out[n + i] = 0.0
            for k in range(n):
                dof = int(dadr[k])
                out[n + dof] = c_ref * out[k] - inv_dt * qprev[k] - kd * qvel[dof]
                out[n + nv + k] = bias[dof] + damp[k] * qvel[dof]
                qprev[k] = out[k]
        else:
            for k in range(n):
                out[n + nv + k] = q[k] + lead[k] * out[k]
        return 0

    return kernel


def _get_kernel() -> Any:
    global _KERNEL
    if _KERNEL is None:
        _KERNEL = _compile()
    return _KERNEL


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
                 mj_model: mujoco.MjModel | None = None, dynamics: str = "mujoco") -> None:
        model = robot.mj_model if mj_model is None else mj_model
        if dynamics not in DYNAMICS:
            raise SimError(f"unknown inverse dynamics '{dynamics}'; known: {', '.join(DYNAMICS)}")
        self.dynamics = dynamics
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
        # the fused fast path (module docstring): only for the dls IK with rows 0..m-1
        nv = model.nv
        self.uses_mj_dynamics = actuation == "torque" and dynamics == "mujoco"
        self._fast = ik == "dls" and tuple(self.ik.rows) == tuple(range(len(self.ik.rows)))
        self._nv = nv
        self._out = np.zeros(2 * robot.n + nv)
        self._acc_full = self._out[robot.n:robot.n + nv]
        self._base = self._out[robot.n + nv:]
        self._qdot_ref = self._out[:robot.n]
        self._macc = np.zeros(nv)
        self._dofs = np.asarray(dofs, dtype=np.intp)
        lo = int(self._dofs[0])
        contiguous = bool(np.array_equal(self._dofs, np.arange(lo, lo + robot.n)))
        self._macc_arm: np.ndarray | None = self._macc[lo:lo + robot.n] if contiguous else None
        self._prm = self._pack(model) if self._fast else None
        self._torque = actuation == "torque"
        self._fast_ok = self._fast and (not self._torque or dynamics == "mujoco")
        self._kernel: Any = _get_kernel() if self._fast_ok else None
        self._data: mujoco.MjData | None = None
        self._site = int(model.site(robot.mj_ee_site).id)
        self._from_site = False

    def _pack(self, model: mujoco.MjModel) -> np.ndarray:
        """The kernel's parameter vector, shape (_HEADER + 15 + 3 d + 6 n,) (layout at ``_HEADER``)."""
        fp = self.ik._impl.fast_params(self.dt)
        n, d = self.robot.n, self.placement.dim
        torque = self.actuation == "torque"
        head = np.zeros(_HEADER)
        head[:15] = (float(self._plane), float(self._spatial), self._n_o, self._kr, fp["eps2"],
                     fp["fast_speed2"], getattr(self, "_c_ref", 0.0), getattr(self, "_inv_dt", 0.0),
                     getattr(self, "_kd", 0.0), fp["posture_gain"], float(torque), d, n, model.nv,
                     len(self.ik.rows))
        rref = np.zeros(9) if self.rotation_ref is None else self.rotation_ref.reshape(9)
        lead = self._lead if not torque else np.zeros(n)
        return np.concatenate([head, rref, self._kn_n, self._normal, self._sA.reshape(3 * d), fp["q_home"],
                               fp["mid"], fp["fast_half"], self._damping, lead,
                               self._dofs.astype(np.float64)]).astype(np.float64)

    def reset(self, q: np.ndarray) -> None:
        """Start a run at rest at q, shape (n,); sets R_ref to the tool orientation there if unset."""
        self._qdot_prev = np.zeros(self.robot.n)
        self.kin.update(np.asarray(q, dtype=np.float64))
        if self.rotation_ref is None and self._spatial:
            self.rotation_ref = self.kin.ee_rotation().copy()
        if self._prm is not None and self.rotation_ref is not None:
            self._prm[_HEADER:_HEADER + 9] = self.rotation_ref.reshape(9)
        if self._kernel is not None:   # compile (or load from the cache) now, not in the first control step
            _, pos, rot = self.kin._placement()
            zeros = np.zeros(self._nv)
            for p_, r_ in ((pos, rot), (np.ascontiguousarray(pos), np.ascontiguousarray(rot))):  # Pinocchio, MuJoCo
                self._kernel(self.kin._jac, p_, r_, np.zeros(self.placement.dim), np.asarray(q, dtype=np.float64),
                             zeros, zeros, self._qdot_prev.copy(), self._prm, self._out.copy())

    def measure(self, q: np.ndarray) -> np.ndarray:
        """FK at q, shape (n,): the tool position p, shape (3,) (a view valid until the next call)."""
        self._from_site = False
        return self.kin.update_position(q)

    def measure_site(self, q: np.ndarray) -> np.ndarray:
        """As ``measure``, for a state where MuJoCo has just run its kinematics at q (``mj_step1``)
        on the data given to ``bind``: the tool pose is MuJoCo's tool site (equal to Pinocchio's
        frame to ~1e-16), and Pinocchio computes only the Jacobian (lazily, the pose too if the
        Python path needs it). Returns a view of ``data.site_xpos``, shape (3,)."""
        self._from_site = True
        self.kin.update(q)
        return self._site_pos

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
        if self._spatial and self.rotation_ref is not None:   # set by reset() on a spatial arm
            tw[3:] = self._kr * pin.log3(self.rotation_ref.dot(self.kin.ee_rotation().T))
        return tw

    def solve_ik(self, q: np.ndarray, twist: np.ndarray) -> np.ndarray:
        """qdot_ref, shape (n,), for the twist, shape (6,), at the measured q (FK already done)."""
        if self._pass_kin:
            return self.ik.solve(q, twist, self.dt, kin=self.kin)
        return self.ik.solve(q, twist, self.dt)

    def actuate(self, q: np.ndarray, qdot: np.ndarray, qdot_ref: np.ndarray,
                model: mujoco.MjModel | None = None, data: mujoco.MjData | None = None) -> np.ndarray:
        """Actuator controls, shape (n,), that make the joints move at qdot_ref, shape (n,), at the
        measured q, qdot, shape (n,) (module docstring). With ``model`` and ``data`` and
        ``dynamics="mujoco"``, computed torque reads ``data.qM`` / ``data.qfrc_bias``, which must be
        those of q, qdot (after ``mj_step1`` or ``mj_forward`` there); else Pinocchio's RNEA."""
        if self.actuation == "position":
            return q + self._lead * qdot_ref
        # qddot_ref + k_d (qdot_ref - qdot) = (1/dt + k_d) qdot_ref - qdot_ref_prev / dt - k_d qdot
        acc = self._c_ref * qdot_ref - self._inv_dt * self._qdot_prev - self._kd * qdot
        self._qdot_prev = np.array(qdot_ref, dtype=np.float64)
        if data is not None and model is not None and self.dynamics == "mujoco":
            self._acc_full[:] = 0.0
            self._acc_full[self._dofs] = acc
            mujoco.mj_mulM(model, data, self._macc, self._acc_full)
            return self._macc[self._dofs] + data.qfrc_bias[self._dofs] + self._damping * qdot
        return pin.rnea(self._pin_model, self._pin_data, q, qdot, acc) + self._damping * qdot

    def command(self, q: np.ndarray, qdot: np.ndarray, v: np.ndarray, model: mujoco.MjModel | None = None,
                data: mujoco.MjData | None = None) -> np.ndarray:
        """Actuator controls, shape (n,), for task velocity v, shape (d,), at the measured q, qdot,
        shape (n,) (``model``, ``data``: see ``actuate``)."""
        return self.actuate(q, qdot, self.solve_ik(q, self.twist(v)), model, data)

    def fast_command(self, model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray, v: np.ndarray) -> None:
        """Write ``data.ctrl`` for task velocity v, shape (d,), at the measured q, shape (n,)
        (``measure(q)`` called; with ``uses_mj_dynamics`` the step's ``mj_step1`` done): twist, DLS
        and command in one compiled call, else the Python path (same results, module docstring)."""
        if self._fast_ok:
            if data is not self._data:
                self.bind(data)
            if self._from_site:
                pos, rot = self._site_pos, self._site_rot
            else:
                _, pos, rot = self.kin._pose or self.kin._placement()
            if self._kernel(self.kin._jac, pos, rot, v, q, self._qvel, self._bias, self._qdot_prev, self._prm,
                            self._out) == 0:
                if self._torque:
                    mujoco.mj_mulM(model, data, self._macc, self._acc_full)
                    if self._ctrl_arm is not None and self._macc_arm is not None:
                        np.add(self._macc_arm, self._base, out=self._ctrl_arm)
                    else:
                        data.ctrl[self.robot.mj_actuator_ids] = self._macc[self._dofs] + self._base
                elif self._ctrl_arm is not None:
                    self._ctrl_arm[:] = self._base
                else:
                    data.ctrl[self.robot.mj_actuator_ids] = self._base
                return
        data.ctrl[self.robot.mj_actuator_ids] = self.command(q, data.qvel[self._dofs], v, model, data)

    def bind(self, data: mujoco.MjData) -> None:
        """Keep numpy views of ``data``'s arrays (each attribute access builds a new view)."""
        self._data, self._qvel, self._bias = data, data.qvel, data.qfrc_bias
        self._site_pos = data.site_xpos[self._site]
        self._site_rot = data.site_xmat[self._site].reshape(3, 3)
        acts = np.asarray(self.robot.mj_actuator_ids, dtype=np.intp)
        a0 = int(acts[0])
        contiguous = np.array_equal(acts, np.arange(a0, a0 + len(acts))) and self._macc_arm is not None
        self._ctrl_arm = data.ctrl[a0:a0 + len(acts)] if contiguous else None
