"""The control step, once: measure, command, perturb, advance the physics.

Every control step k (t_k = k dt), on the raw MuJoCo model and data:

1. ``begin``: with ``FieldController.split`` (MuJoCo's computed torque, whole-arm clearance)
   ``mj_step1`` first, so the mass matrix, the bias forces and the geoms' poses describe this
   state; then q of the arm joints and the tool pose p = FK(q) (MuJoCo's tool site after
   ``mj_step1``, else Pinocchio); a pose task's chart point (``lfd.pose``, Eq. (P1));
2. ``field_point``: the measured task point x = A^T (p - o) / s, minus a goal shift dg
   (``sim.scene.perturbations.GoalShift``), where the field is evaluated;
3. ``command(v)``: the task velocity v -> twist -> differential IK (with its safety rows) ->
   actuator command (``FieldController.fast_command``), then the step's perturbations (push, release,
   moving obstacles, joint-velocity noise);
4. ``end``: ``mj_step2`` and the remaining physics steps (or ``mj_step`` without the split);
   inside a ``Hold`` window the arm joints are then clamped at rest where the hold began. A load held
   until a ``Release`` (its weld) is fed forward until then, Eq. (H1) of docs/equations.md.

With an ``ArmController`` (``robots.controller``: the controller a real arm runs, MuJoCo-free) the
step streams joint velocities as a real arm takes them: ``begin`` measures q and runs its step 1
(Pinocchio's FK and the task point; the goal shift is its ``offset``), ``command(v)`` its steps 3-4
(twist, IK with the whole-arm guard, the jerk-limited limiter) and the actuators track the limited
joint-velocity command (``FieldController.actuate``: the servos' feed-forward, or computed torque).

The lean loop (``sim.control.loop``), the dm_env environment's step and dm_control's generic step
(``FieldTrackingTask.before_step``) all call these; the loop only adds recording.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from robots import RobotModel
from robots.controller import ArmController
from sim.control.controller import FieldController
from sim.scene.perturbations import Schedule

#: the physics calls of a step, looked up at each call (``sim.speed.tasks`` times them inside the step)
physics_step1, physics_step2, physics_step = mujoco.mj_step1, mujoco.mj_step2, mujoco.mj_step
_forward = mujoco.mj_forward


def contiguous(a: np.ndarray, idx: np.ndarray) -> np.ndarray | None:
    """The view ``a[idx[0]:idx[-1] + 1]`` when the indices idx, shape (n,), are consecutive, else
    None (copying a slice view costs less than fancy indexing)."""
    lo = int(idx[0])
    return a[lo:lo + len(idx)] if np.array_equal(idx, np.arange(lo, lo + len(idx))) else None


class ControlStep:
    """The control step of the module docstring for one task.

    Parameters
    ----------
    robot : RobotModel
        The arm (its MuJoCo joint, dof and actuator indices).
    controller : FieldController
        Twist -> IK -> actuator command.
    schedule : Schedule
        The run's perturbations, compiled (``sim.scene.perturbations.compile_schedule``).
    n_sub : int
        Physics steps per control step.
    arm : ArmController, optional
        Stream joint velocities through this controller (module docstring); its ``offset`` is set to
        the schedule's goal shift.

    Attributes
    ----------
    k : int
        The index of the next control step (0 after ``reset``).
    q : ndarray, shape (n,)
        The arm joints measured by the last ``begin`` (a view of ``qpos``: valid until ``end``).
    p : ndarray, shape (3,)
        The tool position measured by the last ``begin``, world, m (a view, valid until the next).
    """

    def __init__(self, robot: RobotModel, controller: FieldController, schedule: Schedule, n_sub: int,
                 arm: ArmController | None = None) -> None:
        self.robot, self.controller, self.schedule, self.n_sub = robot, controller, schedule, int(n_sub)
        self.arm = arm
        if arm is not None:
            arm.offset = schedule.goal_offset_task.copy()
        self.k = 0
        self.q: np.ndarray = np.zeros(robot.n)
        self.p: np.ndarray = np.zeros(3)
        self._x: np.ndarray = np.zeros(controller.placement.dim)
        self._qadr, self._dadr = np.asarray(robot.mj_qpos_adr), np.asarray(robot.mj_dof_adr)
        self._pose = controller.placement.pose
        self._shift = schedule.goal_offset_task
        self._shifted = bool(np.any(self._shift != 0))
        self._h0, self._h1 = schedule.hold_steps
        self._q_hold: np.ndarray | None = None
        self.model: Any = None
        self.data: Any = None
        #: feed a held load's weight forward (Eq. (H1)); False measures the arm without it (read by ``bind``)
        self.feed_load = True

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Keep the raw model and data, and views of the arrays a step reads (each attribute access of
        ``MjData`` builds a new view); binds the controller too."""
        self.model, self.data = model, data
        ctl = self.controller
        ctl.bind(data)
        self._split = ctl.split
        # after mj_step1 the tool pose is MuJoCo's site (Pinocchio computes only what the IK needs)
        self._measure: Callable[[np.ndarray], np.ndarray] = ctl.measure_site if ctl.split else ctl.measure
        self._to_task, self._fast = ctl.to_task, ctl.fast_command
        self._qpos, self._qvel = data.qpos, data.qvel
        self._q_arm = contiguous(data.qpos, self._qadr)
        s = self.schedule
        self._push = s.push_body
        self._push_row = data.xfrc_applied[max(s.push_body, 0)]
        self._k0, self._k1 = s.push_steps
        self._acts = np.asarray(self.robot.mj_actuator_ids)
        self._qvel_arm = contiguous(data.qvel, self._dadr)
        self._load = self._held_load(model, data) if self.controller.actuation == "torque" and self.feed_load else None

    def _held_load(self, model: mujoco.MjModel, data: mujoco.MjData) -> Callable[[], None] | None:
        """The feed-forward of the load the release lets go of (Eq. (H1)), bound to ``data``: adds
        J_c(q)^T (-m g) to the arm's controls; None without a release (``mj_applyFT`` does J^T f)."""
        eq = self.schedule.release_eq
        if eq < 0 or int(model.eq_type[eq]) != int(mujoco.mjtEq.mjEQ_WELD):
            return None
        held, tool = int(model.eq_obj1id[eq]), int(model.eq_obj2id[eq])
        rel_pos, rel_quat = model.eq_data[eq, 3:6], model.eq_data[eq, 6:10]   # the tool's pose in the object's
        rel = np.zeros(9)
        mujoco.mju_quat2Mat(rel, rel_quat)
        com = rel.reshape(3, 3).T @ (model.body_ipos[held] - rel_pos)        # c in the tool body's frame
        lift = -float(model.body_mass[held]) * np.asarray(model.opt.gravity, dtype=np.float64)
        qfrc, point, zero = np.zeros(model.nv), np.zeros(3), np.zeros(3)
        rot, pos = data.xmat[tool].reshape(3, 3), data.xpos[tool]
        dofs, acts = self._dadr, self._acts
        arm = contiguous(qfrc, dofs)
        ctrl = contiguous(data.ctrl, acts)
        apply_ft, matmul, add = mujoco.mj_applyFT, np.matmul, np.add

        def feed() -> None:
            matmul(rot, com, out=point)
            add(point, pos, out=point)
            qfrc[:] = 0.0
            apply_ft(model, data, lift, zero, point, tool, qfrc)
            if arm is not None and ctrl is not None:
                add(ctrl, arm, out=ctrl)
            else:
                data.ctrl[acts] += qfrc[dofs]
        return feed

    def reset(self) -> None:
        """Start a run: the step index back to 0."""
        self.k = 0
        self._q_hold = None

    def begin(self) -> np.ndarray:
        """Steps 1 of the module docstring: returns the measured tool position p, shape (3,), world."""
        if self.arm is not None:
            self._x = self._begin_arm()
            return self.p
        if self._split:
            physics_step1(self.model, self.data)
        q = self.q = self._q_arm if self._q_arm is not None else self._qpos[self._qadr]
        p = self.p = self._measure(q)
        if self._pose:   # the twist of a pose command is taken at the measured chart point
            self._x = self._to_task(p)
        if self.k == self._h0:
            self._q_hold = q.copy()
        return p

    def field_point(self) -> np.ndarray:
        """Step 2: the task point x - dg, shape (d,), where the field is evaluated."""
        if self.arm is not None:
            return self._x
        x = self._x if self._pose else self._to_task(self.p)
        return x - self._shift if self._shifted else x

    def begin_at_point(self) -> np.ndarray:
        """Steps 1 and 2 in one call (the loop's): ``begin``, then the field's point x - dg, shape (d,)."""
        if self.arm is not None:
            return self._begin_arm()
        if self._split:
            physics_step1(self.model, self.data)
        q = self.q = self._q_arm if self._q_arm is not None else self._qpos[self._qadr]
        p = self.p = self._measure(q)
        if self.k == self._h0:
            self._q_hold = q.copy()
        x = self._x = self._to_task(p)
        return x - self._shift if self._shifted else x

    def command(self, v: np.ndarray) -> None:
        """Step 3: write the actuator commands for the task velocity v, shape (d,), task units/s, at
        the state measured by ``begin``, then this step's perturbations."""
        model, data, k, s = self.model, self.data, self.k, self.schedule
        if self.arm is not None:
            dq = self._qvel[self._dadr] if self._qvel_arm is None else self._qvel_arm
            data.ctrl[self._acts] = self.controller.actuate(self.q, dq, self.arm.command(v), model, data)
        else:
            self._fast(model, data, self.q, v)
        if self._push >= 0:
            if self._k0 <= k < self._k1:
                self._push_row[:] = s.push_force
            elif k == self._k1:
                self._push_row[:] = 0.0
        if self._load is not None and k < s.release_step:   # the held load's weight, fed forward
            self._load()
        if k == s.release_step and s.release_eq >= 0:   # the hand lets go
            data.eq_active[s.release_eq] = 0
        if s.mocap_pos is not None and k < len(s.mocap_pos):   # moving obstacles where they are at t_k
            data.mocap_pos[:] = s.mocap_pos[k]
        if s.qvel_noise is not None and k < len(s.qvel_noise):
            data.qvel[self._dadr] += s.qvel_noise[k]
            if self._split:   # the physics must see the noisy velocity, as a plain mj_step would
                physics_step1(model, data)
        self.k = k + 1

    def _begin_arm(self) -> np.ndarray:
        """Step 1 through the ``ArmController``: q measured (after ``mj_step1`` with ``split``), its
        FK and task point; returns x - dg, shape (d,)."""
        if self._split:
            physics_step1(self.model, self.data)
        q = self.q = self._q_arm if self._q_arm is not None else self._qpos[self._qadr]
        if self.k == self._h0:
            self._q_hold = q.copy()
        assert self.arm is not None
        x = self.arm.point(q)
        self.p = self.arm.p
        return x

    def measured_rotation(self) -> np.ndarray:
        """The tool rotation, shape (3, 3), world, measured by the last ``begin``."""
        return self.arm.rot if self.arm is not None else self.controller.measured_rotation()

    def end(self) -> None:
        """Step 4: advance the physics by one control period (and clamp the arm inside a hold)."""
        m, d, n_sub = self.model, self.data, self.n_sub
        if self._split:
            physics_step2(m, d)
            if n_sub > 1:
                physics_step(m, d, n_sub - 1)
        else:
            physics_step(m, d, n_sub)
        if self._h0 <= self.k - 1 < self._h1 and self._q_hold is not None:
            self._qpos[self._qadr] = self._q_hold
            self._qvel[self._dadr] = 0.0
            _forward(m, d)
