"""The command of one control step: task velocity -> tool twist -> differential IK -> actuator command.

The twist from a task velocity v (Eqs. (S1)-(S2) of docs/equations.md): s A v, with a pull back onto
the plane for a 2-D task on a spatial arm and the tool orientation held at R_ref on a position task;
a pose task's chart velocity z_dot gives the whole twist (Eq. (P3)). Then qdot = IK(q, twist)
(``robots.DifferentialIK``) and the actuator command: velocity servos with a feed-forward for
``position`` actuators, computed torque from MuJoCo's M(q) and bias forces (or Pinocchio's RNEA)
for ``torque`` motors, Eq. (S3).

``fast_command`` runs twist, DLS and command in one compiled numba function
(``sim.control._control_kernel.kernel``) on MuJoCo's tool site and its Jacobian after ``mj_step1``; it hands
back to the Python path (``twist``, ``solve_ik``, ``actuate``: the same results up to round-off) near
a singularity or a joint limit, for a tool orientation error near pi on a position task, and for the
``pink`` IK. A pose task's chart point (``to_task``) is one compiled call too
(``sim.control._control_kernel.pose_point``).
"""

from __future__ import annotations

import functools
import importlib
import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin

from robots import DifferentialIK, RobotModel
from robots.ik.constrained import ConstrainedIK, QpGains
from robots.loader import ACTUATIONS as ACTUATIONS  # re-exported: the actuations a robot is loaded with
from sim.control._kernel_layout import HEADER as _HEADER  # the kernel parameter vector's head
from sim.control._kernel_layout import POSE_BLOCK as _POSE_BLOCK
from sim.errors import SimError
from sim.scene.collision import ArmClearance, Clearance
from sim.scene.placement import Placement

DYNAMICS: tuple[str, ...] = ("mujoco", "pinocchio")
_mul_m, _add, _jac_site = mujoco.mj_mulM, np.add, mujoco.mj_jacSite   # bound once: called every control step

@functools.cache
def _get_kernels() -> Any:
    """The compiled control step and chart point (``sim.control._control_kernel``; numba is imported on first use)."""
    return importlib.import_module("sim.control._control_kernel")


@dataclass(frozen=True)
class Gains:
    """plane : k_n (1/s); rotation : k_r (1/s); torque_kd : k_d (1/s) of computed torque;
    lead_s : tau_lead (s), a phase lead on the task velocity, v_k + (tau_lead / dt) (v_k - v_{k-1})
    (0: none, the default).

    The lead cancels a first-order lag tau of the arm's velocity response to its command when
    tau_lead = tau. The Panda's response lags like that, and a field whose direction turns fast (an
    obstacle-avoiding field beside the obstacle) then drifts outward on every pass and can orbit the
    goal; a lead of the lag's size removes the orbit (the arm job uses one with obstacles). The
    lead amplifies fast changes of the command by 1 + 2 tau_lead / dt (a push, joint-velocity
    noise), so it is off unless asked for."""

    plane: float = 20.0
    rotation: float = 10.0
    torque_kd: float = 150.0
    lead_s: float = 0.0


class FieldController:
    """Maps a task velocity to actuator commands for ``robot`` placed by ``placement``.

    Call ``measure(q)`` (Pinocchio FK at the measured joints; returns the tool position p,
    shape (3,)) and then ``command(q, qdot, v)`` with the task velocity v, shape (d,), at the
    same q; it returns the actuator controls, shape (n,), in ``robot.mj_actuator_ids`` order.

    Parameters
    ----------
    robot : RobotModel
        The arm; its actuation (``RobotModel.actuation``, set by ``robots.load_robot``) selects the command.
    placement : Placement
        Task space -> world.
    control_dt : float
        Control period, s.
    ik : str
        Differential IK back-end (``robots.IK_BACKENDS``).
    rotation_ref : ndarray, shape (3, 3), optional
        Tool orientation to hold on a spatial arm on a position task (``RunSetup.rotation_ref``;
        None: the orientation is not held).
    gains : Gains
    feedforward : bool
        Position servos: the velocity feed-forward (module docstring).
    mj_model : mujoco.MjModel, optional
        The simulated model (default ``robot.mj_model``; e.g. a scene with obstacles).
    dynamics : str
        Computed torque from ``"mujoco"`` (default) or ``"pinocchio"`` (module docstring).
    clearance : Clearance, optional
        Keep every collision geom of the arm clear of the scene's obstacles, its table and the arm
        itself (``sim.scene.collision``): while a pair is within the influence distance, ``fast_command``
        solves the IK as the QP of ``robots.ik.constrained`` with one velocity damper per pair;
        ``guard`` is the ``ArmClearance``, ``guard_active`` whether the last step's QP had a damper
        at its bound. Needs ``model`` and ``data`` (``fast_command``).

    Attributes
    ----------
    split : bool
        The loop runs ``mj_step1`` before ``measure_site`` and the command and ``mj_step2`` after
        it (``sim.control.loop``): for computed torque from MuJoCo's dynamics (M(q) and the bias forces of
        this state), and for whole-arm clearance (MuJoCo's poses of this state for the dampers)
        unless the integrator is RK4 (whose ``mj_step`` is not ``mj_step1`` + ``mj_step2``) or
        the scene has mocap bodies (moving obstacles, placed after the command).
    """

    def __init__(self, robot: RobotModel, placement: Placement, control_dt: float, ik: str = "dls",
                 rotation_ref: np.ndarray | None = None, gains: Gains = Gains(), feedforward: bool = True,
                 mj_model: mujoco.MjModel | None = None, dynamics: str = "mujoco",
                 clearance: Clearance | None = None) -> None:
        model = robot.mj_model if mj_model is None else mj_model
        if dynamics not in DYNAMICS:
            raise SimError(f"unknown inverse dynamics '{dynamics}'; known: {', '.join(DYNAMICS)}")
        if robot.planar and placement.dim != 2:
            raise SimError(f"robot '{robot.name}' moves in a plane; it cannot follow a {placement.dim}-D field")
        self.robot, self.placement, self.dt, self.dynamics = robot, placement, float(control_dt), dynamics
        self.actuation, self.gains, self.feedforward = robot.actuation, gains, feedforward
        self.ik = DifferentialIK(robot, backend=ik, rows=(0, 1) if robot.planar else None)
        self.kin = self.ik.kinematics
        self._pass_kin = ik == "dls"
        self.rotation_ref = None if rotation_ref is None else np.asarray(rotation_ref, dtype=np.float64).copy()
        self._twist = np.zeros(6)
        self._qdot_prev = np.zeros(robot.n)
        if not (math.isfinite(gains.lead_s) and 0.0 <= gains.lead_s <= 1.0):
            raise SimError(f"lead_s must be in [0, 1] s, got {gains.lead_s}")
        self._v_lead = gains.lead_s / self.dt
        self._v_prev: np.ndarray | None = None
        self._setup_geometry(placement, gains)
        self._setup_actuation(model, gains, feedforward)
        self._setup_fast_path(model, ik)
        self.guard: ArmClearance | None = None
        self.guard_active = False
        if clearance is not None:
            if clearance.rate * self.dt > 1.0:
                raise SimError(f"clearance rate {clearance.rate:g}/s times the control step {self.dt:g} s exceeds 1: "
                               "a damper would overshoot its safety distance in one step")
            own = self.ik.gains   # DlsGains or PinkGains: the QP keeps the IK's posture and limits
            self.guard = ArmClearance(model, robot, clearance)
            self._prev = np.zeros(robot.n)
            # the loop then runs mj_step1 before the command: MuJoCo's poses for the dampers come free
            if model.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4 and model.nmocap == 0:
                self.split = True
            self._cik = ConstrainedIK(robot, tuple(self.ik.rows), self.kin, QpGains(
                posture_gain=own.posture_gain, limit_margin=own.limit_margin, speed_fraction=own.speed_fraction))

    def _setup_geometry(self, placement: Placement, gains: Gains) -> None:
        """The twist's constants: o (3,), s A (3, d), A^T / s (d, 3), k_n n and n (3,), n . o, k_r."""
        self._origin = placement.origin.copy()
        self._sA = np.ascontiguousarray(placement.scale * placement.axes)        # (3, d)
        self._At_s = np.ascontiguousarray(placement.axes.T / placement.scale)     # (d, 3)
        self._plane = placement.dim == 2 and not self.robot.planar
        self._chart = placement.chart
        self._pose = placement.chart is not None
        # holds R at R_ref (a spatial arm on a position task)
        self._spatial = not self.robot.planar and not self._pose and self.rotation_ref is not None
        self._rot_t = np.ascontiguousarray(placement.rotation.T)
        self._rot = np.ascontiguousarray(placement.rotation)
        self._z = np.zeros(6)
        # to_task of a position task on Python floats (numpy's call overhead dominates at d <= 3)
        self._origin_l: list[float] = self._origin.tolist()
        # A^T / s row by row, padded to 3 rows (d <= 3; a pose task does not use it)
        self._At_s_l: list[float] = np.vstack([self._At_s, np.zeros((3, 3))])[:3].ravel().tolist()
        self._d3 = placement.dim == 3
        self._kn_n = gains.plane * placement.normal
        self._normal = placement.normal.copy()
        self._n_o = float(placement.normal @ placement.origin)
        self._kr = float(gains.rotation)

    def _setup_actuation(self, model: mujoco.MjModel, gains: Gains, feedforward: bool) -> None:
        """The command's constants (module docstring): the joints' damping b (n,); position servos:
        the lead (kv + b) / kp or dt (n,); computed torque: Pinocchio's model and data, k_d, 1/dt, c_ref."""
        robot = self.robot
        self._torque = self.actuation == "torque"
        self._damping = model.dof_damping[robot.mj_dof_adr].copy()
        if not self._torque:
            acts = robot.mj_actuator_ids
            kp = model.actuator_gainprm[acts, 0].copy()
            kv = -model.actuator_biasprm[acts, 2].copy()
            self._lead = (kv + self._damping) / kp if feedforward else np.full(len(kp), self.dt)
            return
        self._pin_model = robot.pin_model
        self._pin_data = robot.pin_model.createData()
        self._kd, self._inv_dt = float(gains.torque_kd), 1.0 / self.dt
        self._c_ref = self._inv_dt + self._kd

    def _setup_fast_path(self, model: mujoco.MjModel, ik: str) -> None:
        """The fused fast path (module docstring; only for the dls IK with rows 0..m-1): its output
        buffer (2 n + nv,) with views qdot_ref (n,), a (nv,) and base (n,), M a (nv,), the packed
        parameters and the compiled kernel."""
        n, nv = self.robot.n, model.nv
        self.uses_mj_dynamics = self._torque and self.dynamics == "mujoco"
        self.split = self.uses_mj_dynamics
        self._fast = ik == "dls" and tuple(self.ik.rows) == tuple(range(len(self.ik.rows)))
        self._nv = nv
        self._out = np.zeros(2 * n + nv)
        self._acc_full = self._out[n:n + nv]
        self._base = self._out[n + nv:]
        self._qdot_ref = self._out[:n]
        self._macc = np.zeros(nv)
        self._dofs = np.asarray(self.robot.mj_dof_adr, dtype=np.intp)
        lo = int(self._dofs[0])
        contiguous = bool(np.array_equal(self._dofs, np.arange(lo, lo + n)))
        self._macc_arm: np.ndarray | None = self._macc[lo:lo + n] if contiguous else None
        self._prm = self._pack(model) if self._fast else None
        self._fast_ok = self._fast and (not self._torque or self.dynamics == "mujoco")
        self._kernel: Any = _get_kernels().kernel if self._fast_ok else None
        # a pose task's chart point, Eq. (P1), in one compiled call (from the pose block of the parameters)
        self._pose_point: Any = _get_kernels().pose_point if self._prm is not None and self._pose else None
        self._data: mujoco.MjData | None = None
        self._site = int(model.site(self.robot.mj_ee_site).id)
        self._from_site = False
        # after mj_step1 the compiled path takes MuJoCo's Jacobian of the tool site (equal to
        # Pinocchio's up to round-off; columns = the arm's dofs when they are MuJoCo's first n), and
        # Pinocchio's kinematics run only if the Python path needs them (``_kinematics``)
        self._model = model
        self._mj_jac = self._fast_ok and contiguous and lo == 0
        self._jac_mj = np.zeros((6, nv))
        self._jacp, self._jacr = self._jac_mj[:3], self._jac_mj[3:]
        self._kin_q: np.ndarray | None = None

    def _pack(self, model: mujoco.MjModel) -> np.ndarray:
        """The kernel's parameter vector, shape (_HEADER + 15 + 3 d + 6 n + _POSE_BLOCK,) (layout:
        ``sim.control._kernel_layout``)."""
        fp = self.ik.fast_params(self.dt)
        n, d = self.robot.n, self.placement.dim
        torque = self.actuation == "torque"
        head = np.zeros(_HEADER)
        if self._pose:
            d = 3   # the kernel takes the world twist (6,) as its v (``fast_command``), and sA is 3 x 3
        head[:16] = (float(self._plane), float(self._spatial), self._n_o, self._kr, fp["eps2"],
                     fp["fast_speed2"], getattr(self, "_c_ref", 0.0), getattr(self, "_inv_dt", 0.0),
                     getattr(self, "_kd", 0.0), fp["posture_gain"], float(torque), d, n, model.nv,
                     len(self.ik.rows), float(self._pose))
        rref = np.zeros(9) if self.rotation_ref is None else self.rotation_ref.reshape(9)
        lead = self._lead if not torque else np.zeros(n)
        pose = np.zeros(_POSE_BLOCK)
        if self._chart is not None:   # Eq. (P1): z = (A^T (p - o) / s, l log(R_g^T R^T rot)); Eq. (P3)
            chart = self._chart
            pose[:] = np.concatenate([self._origin, self._At_s.reshape(9),
                                      (chart.goal_rotation.T @ self._rot_t).ravel(),
                                      (self._rot @ chart.goal_rotation / chart.length).ravel(), [chart.length]])
        return np.concatenate([head, rref, self._kn_n, self._normal, self._sA.reshape(3 * d), fp["q_home"],
                               fp["mid"], fp["fast_half"], self._damping, lead,
                               self._dofs.astype(np.float64), pose]).astype(np.float64)

    def reset(self, q: np.ndarray) -> None:
        """Start a run at rest at q, shape (n,)."""
        self._qdot_prev = np.zeros(self.robot.n)
        self._v_prev = None
        self._kin_q = None
        self.kin.update(np.asarray(q, dtype=np.float64))
        if self._prm is not None and self.rotation_ref is not None:
            self._prm[_HEADER:_HEADER + 9] = self.rotation_ref.reshape(9)
        if self._pose_point is not None:   # compile (or load) now, as the kernel below
            _, pos, rot = self.kin.read_pose()
            self._pose_point(pos, rot, self._prm, np.empty(6))
        if self._kernel is not None:   # compile (or load from the cache) now, not in the first control step
            _, pos, rot = self.kin.read_pose()
            zeros = np.zeros(self._nv)
            v0 = np.zeros(6 if self._pose else self.placement.dim)
            for j_, p_, r_ in ((self.kin.jacobian, pos, rot),   # Pinocchio's, then MuJoCo's arrays
                               (self._jac_mj, np.ascontiguousarray(pos), np.ascontiguousarray(rot))):
                self._kernel(j_, p_, r_, v0, np.asarray(q, dtype=np.float64),
                             zeros, zeros, self._qdot_prev.copy(), self._prm, self._out.copy())

    def get_state(self) -> np.ndarray:
        """The controller's only memory between control steps (for ``FieldTrackingTask.get_state``).

        Returns
        -------
        ndarray, shape (n,)
            A copy of the joint-velocity reference of the last step (computed torque's qddot_ref).
        """
        return self._qdot_prev.copy()

    def set_state(self, qdot_prev: np.ndarray) -> None:
        """Restore a ``get_state`` vector.

        Parameters
        ----------
        qdot_prev : ndarray, shape (n,)
            The joint-velocity reference of the last step, copied.
        """
        self._qdot_prev = np.array(qdot_prev, dtype=np.float64)

    def measure(self, q: np.ndarray) -> np.ndarray:
        """FK at q, shape (n,): the tool position p, shape (3,) (a view valid until the next call)."""
        self._from_site = False
        self._kin_q = None
        return self.kin.update_position(q)

    def measure_site(self, q: np.ndarray) -> np.ndarray:
        """As ``measure``, for a state where MuJoCo has just run its kinematics at q (``mj_step1``)
        on the data given to ``bind``: the tool pose is MuJoCo's tool site (equal to Pinocchio's
        frame up to round-off), and so is the compiled path's Jacobian (``mj_jacSite``) where the
        arm's dofs are MuJoCo's first; Pinocchio's kinematics at q (the Jacobian, the pose lazily)
        run only when the Python path needs them, during this control step (q, shape (n,), must not
        change before). Returns a view of ``data.site_xpos``, shape (3,)."""
        self._from_site = True
        if self._mj_jac:
            _jac_site(self._model, self._data, self._jacp, self._jacr, self._site)
            self._kin_q = q
        else:
            self.kin.update(q)
        return self._site_pos

    def _kinematics(self) -> None:
        """Bring Pinocchio's kinematics to the q of the last ``measure_site`` if it left them behind."""
        if self._kin_q is not None:
            self.kin.update(self._kin_q)
            self._kin_q = None

    def to_task(self, p: np.ndarray) -> np.ndarray:
        """x = A^T (p - o) / s, shape (d,); for a pose task the chart point z (6,) of the last
        measured pose (module docstring), remembered for the twist."""
        if not self._pose:
            px, py, pz = p.tolist()
            ox, oy, oz = self._origin_l
            dx, dy, dz = px - ox, py - oy, pz - oz
            a0, a1, a2, b0, b1, b2, c0, c1, c2 = self._At_s_l
            if self._d3:
                return np.array((a0 * dx + a1 * dy + a2 * dz, b0 * dx + b1 * dy + b2 * dz, c0 * dx + c1 * dy + c2 * dz))
            return np.array((a0 * dx + a1 * dy + a2 * dz, b0 * dx + b1 * dy + b2 * dz))
        self._z = z = self.chart_point(p, self.measured_rotation())
        return z

    def chart_point(self, p: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """A pose task's chart point z (6,) of the tool pose p (3,), rot (3, 3), world (Eq. (P1)),
        in one compiled call; nothing is remembered."""
        z = np.empty(6)
        if self._pose_point is not None:
            self._pose_point(p, rot, self._prm, z)
            return z
        assert self._chart is not None
        return self._chart.point(self._At_s.dot(p - self._origin), self._rot_t.dot(rot))

    def measured_rotation(self) -> np.ndarray:
        """The tool rotation, shape (3, 3), world, of the last ``measure`` / ``measure_site``."""
        return self._site_rot if self._from_site else self.kin.ee_rotation()

    def pose_twist(self, v: np.ndarray) -> np.ndarray:
        """The world twist (6,) of a pose task's command v = z_dot (6,) at the last ``to_task``
        point: s A z_dot[:3] and A omega (Eq. (P3))."""
        assert self._chart is not None
        tw = self._chart.twist(self._z, v)
        tw[:3] = self._sA.dot(tw[:3])
        tw[3:] = self._rot.dot(tw[3:])
        return tw

    def twist(self, v: np.ndarray) -> np.ndarray:
        """The tool twist, shape (6,), for task velocity v, shape (d,), at the last measured pose."""
        # ndarray.dot costs about half of @ on these tiny operands (call overhead dominates)
        self._kinematics()
        if self._pose:
            return self.pose_twist(v)
        tw = self._twist
        if self._plane:
            tw[:3] = self._sA.dot(v) - self._kn_n * (self._normal.dot(self.kin.ee_position()) - self._n_o)
        else:
            tw[:3] = self._sA.dot(v)
        if self._spatial and self.rotation_ref is not None:
            tw[3:] = self._kr * pin.log3(self.rotation_ref.dot(self.kin.ee_rotation().T))
        return tw

    def solve_ik(self, q: np.ndarray, twist: np.ndarray) -> np.ndarray:
        """qdot_ref, shape (n,), for the twist, shape (6,), at the measured q (FK already done)."""
        self._kinematics()
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
        return self.actuate(q, qdot, self.solve_ik(q, self.twist(self.lead(v))), model, data)

    def lead(self, v: np.ndarray) -> np.ndarray:
        """The task velocity with the phase lead of ``Gains.lead_s``, shape (d,): v (unchanged) when
        it is 0 or at a run's first step; remembers v for the next step."""
        if self._v_lead == 0.0:
            return v
        prev, self._v_prev = self._v_prev, np.array(v, dtype=np.float64)
        return v if prev is None else v + self._v_lead * (v - prev)

    def fast_command(self, model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray, v: np.ndarray) -> None:
        """Write ``data.ctrl`` for task velocity v, shape (d,), at the measured q, shape (n,)
        (``measure(q)`` called; with ``split`` the step's ``mj_step1`` done): twist, DLS and
        command in one compiled call, else the Python path (same results, module docstring). With
        whole-arm clearance the dampers are checked against the DLS's qdot_ref
        (``ArmClearance.check``); where one binds, or the compiled call hands back, the IK is the QP
        with every damper row within reach (``ArmClearance.rows``)."""
        if self._v_lead != 0.0:
            v = self.lead(v)
        guard = self.guard
        if guard is not None:
            if not self.split:   # no mj_step1 this step: MuJoCo's poses are the last step's
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
            self.guard_active = False
            if not self._fast_ok:
                A, b = guard.rows(data)
                if len(b):
                    self._guarded(model, data, q, v, A, b)
                    return
        if self._fast_ok:
            if data is not self._data:
                self.bind(data)
            if self._from_site:
                pos, rot = self._site_pos, self._site_rot
                jac = self._jac_mj if self._mj_jac else self.kin.jacobian
            else:
                _, pos, rot = self.kin.pose or self.kin.read_pose()
                jac = self.kin.jacobian
            if guard is not None and self._torque:
                self._prev[:] = self._qdot_prev
            # a pose task's twist (Eq. (P3)) is the kernel's, at the chart point of this pose
            status = self._kernel(jac, pos, rot, v, q, self._qvel, self._bias, self._qdot_prev,
                                  self._prm, self._out)
            # a damper binds for the DLS's qdot_ref (or the kernel handed back): the IK as a QP with the
            # dampers (``sim.scene.collision``); ``check`` measures only the pairs whose row could bind
            if guard is not None and (status != 0 or guard.check(data, self._qdot_ref)):
                A, b = guard.rows(data)
                if len(b):
                    if self._torque:
                        self._qdot_prev = self._prev.copy()
                    self._guarded(model, data, q, v, A, b)
                    return
            if status == 0:
                if self._torque:
                    _mul_m(model, data, self._macc, self._acc_full)
                    if self._ctrl_arm is not None and self._macc_arm is not None:
                        _add(self._macc_arm, self._base, self._ctrl_arm)
                    else:
                        data.ctrl[self.robot.mj_actuator_ids] = self._macc[self._dofs] + self._base
                elif self._ctrl_arm is not None:
                    self._ctrl_arm[:] = self._base
                else:
                    data.ctrl[self.robot.mj_actuator_ids] = self._base
                return
        qdot_ref = self.solve_ik(q, self.twist(v))   # v already led
        data.ctrl[self.robot.mj_actuator_ids] = self.actuate(q, data.qvel[self._dofs], qdot_ref, model, data)

    def _guarded(self, model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray, v: np.ndarray,
                 A: np.ndarray, b: np.ndarray) -> None:
        """``data.ctrl`` from the IK QP with the damper rows A qdot <= b (``robots.ik.constrained``)
        for the (led) task velocity v at the measured q."""
        tw = self.twist(v)   # Pinocchio's kinematics at q first (``_kinematics``)
        qdot_ref, _ = self._cik.solve(q, tw, self.dt, A, b, kin=self.kin)
        self.guard_active = bool(self._cik.active.any())
        data.ctrl[self.robot.mj_actuator_ids] = self.actuate(q, data.qvel[self._dofs], qdot_ref, model, data)

    def bind(self, data: mujoco.MjData) -> None:
        """Keep numpy views of ``data``'s arrays (each attribute access builds a new view)."""
        self._data, self._qvel, self._bias = data, data.qvel, data.qfrc_bias
        self._site_pos = data.site_xpos[self._site]
        self._site_rot = data.site_xmat[self._site].reshape(3, 3)
        acts = np.asarray(self.robot.mj_actuator_ids, dtype=np.intp)
        a0 = int(acts[0])
        contiguous = np.array_equal(acts, np.arange(a0, a0 + len(acts))) and self._macc_arm is not None
        self._ctrl_arm = data.ctrl[a0:a0 + len(acts)] if contiguous else None
