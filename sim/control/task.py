"""The closed-loop task as a dm_control ``control.Environment``: a Physics and a Task kept apart.

* Physics: the robot's MuJoCo scene (``robot.mjcf_xml``), ``ArmPhysics``.
* Task (``FieldTrackingTask``): starts the arm at rest with the tool on the start point (or, with
  ``start_radius`` > 0, on a point drawn uniformly in the ball of that radius around it, from
  ``seed``, anew each episode); takes as action the tool velocity v, shape (d,), in TASK
  coordinates (user units per second, the same units as the learned field's output), and turns it
  into actuator commands through ``sim.control.controller.FieldController``; applies the run's
  perturbations (``sim.scene.perturbations``).
* Action spec: ``BoundedArray`` (d,), ``ee_velocity``, bounds +-v_max = 2 m/s in task units. An
  action of another shape, or with a NaN, raises ``SimError``; a finite action outside the bounds
  is CLIPPED to them, component-wise (``FieldTrackingTask.clipped_actions`` counts those steps).
* Observations: ``OBSERVATION_KEYS`` (``FieldTrackingTask.get_observation``), plus
  ``field_velocity`` with a ``field``.
* Reward: 1 within 5 mm of the (shifted) goal, falling off as a Gaussian over 5 cm
  (``dm_control.utils.rewards.tolerance``).
* Restorable state: ``FieldTrackingTask.get_state`` / ``set_state`` (the physics state alone does
  not replay a run exactly).

The task receives its run's ``sim.scene.setup.RunSetup`` (placement, start, goal, tool orientation)
and owns its ``sim.control.step.ControlStep``, which the lean loop (``sim.control.loop``), the environment's step
(``sim.control.env``) and dm_control's generic step (``before_step``) all call.
"""

from __future__ import annotations

import collections
import functools
import math
import operator
from collections.abc import Callable, Sequence

import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.rl import control
from dm_env import specs

from lfd.field import Field
from lfd.runner import Runner
from robots import RobotError, RobotModel
from robots.controller import ArmController, Guard
from robots.limits import Limits, limits_of
from sim.control.controller import FieldController, Gains
from sim.control.step import ControlStep, contiguous
from sim.errors import PlacementError, SimError
from sim.scene.collision import Clearance
from sim.scene.perturbations import Perturbation, Schedule, compile_schedule
from sim.scene.placement import IK_TOLERANCE_M
from sim.scene.setup import RunSetup

OBSERVATION_KEYS: tuple[str, ...] = ("joint_positions", "joint_velocities", "ee_position", "task_position",
                                     "goal", "joint_limit")   # plus "field_velocity" with a field
V_MAX_M_S = 2.0          # action bound, m/s of tool speed: far above any demo speed
START_DRAWS = 50         # random starts tried per episode before giving up (out of reach)
GOAL_TOLERANCE_M = 0.005
REWARD_MARGIN_M = 0.05   # the reward's Gaussian fall-off: 0.1 this far beyond the goal tolerance
# dm_control.utils.rewards.tolerance's Gaussian with value_at_margin = 0.1: exp(-(d scale)^2 / 2)
_REWARD_SCALE = math.sqrt(-2.0 * math.log(0.1))
_F64 = np.dtype(np.float64)


def tool_body(robot: RobotModel, model: mujoco.MjModel) -> str:
    """The body a push acts on by default: the body carrying the tool site, or its first ancestor
    with mass (a massless tool-centre-point frame is welded to the hand)."""
    b = int(model.site_bodyid[model.site(robot.mj_ee_site).id])
    while b > 0 and model.body_mass[b] <= 0:
        b = int(model.body_parentid[b])
    return model.body(b).name


class ArmPhysics(dm_mujoco.Physics):
    """MuJoCo physics of a robot scene, with arm-joint accessors (Pinocchio joint order)."""

    robot: RobotModel
    _ee_site: int   # the tool site's id, set by ``from_robot``

    @classmethod
    def from_robot(cls, robot: RobotModel) -> ArmPhysics:
        physics = cls.from_xml_string(robot.mjcf_xml, robot.mj_assets or None)
        physics.robot = robot
        physics._ee_site = physics.model.name2id(robot.mj_ee_site, "site")
        return physics

    def joint_positions(self) -> np.ndarray:
        """q, shape (n,)."""
        return self.data.qpos[self.robot.mj_qpos_adr].copy()

    def joint_velocities(self) -> np.ndarray:
        """qdot, shape (n,)."""
        return self.data.qvel[self.robot.mj_dof_adr].copy()

    def ee_position(self) -> np.ndarray:
        """Tool position in world, shape (3,), from the MuJoCo site."""
        return self.data.site_xpos[self._ee_site].copy()

    def ee_rotation(self) -> np.ndarray:
        """Tool rotation in world, shape (3, 3), from the MuJoCo site."""
        return self.data.site_xmat[self._ee_site].reshape(3, 3).copy()


class FieldTrackingTask(control.Task):
    """Drive the tool with a task-space velocity action; see the module docstring.

    Parameters
    ----------
    setup : RunSetup
        The run's robot, placement, start, goal and tool orientation (``sim.scene.setup``).
    control_dt : float
        Control step, s (an integer number of physics steps of ``mj_model``).
    goal : array, shape (d,), optional
        The goal the reward and the observation use, task units, before a ``GoalShift`` (default
        ``setup.goal``; a moving goal's end, ``lfd.goal``). ``start_task`` (this episode's start),
        ``q_start`` and ``goal_task`` hold the actual values.
    start_radius : float
        > 0: each episode starts at a point drawn uniformly in the ball of this radius (task
        units) around the start, from ``np.random.default_rng(seed)``; points out of the arm's
        reach are redrawn (``START_DRAWS`` tries, then ``PlacementError``).
    field : Field, optional
        A velocity field in task units; adds the ``field_velocity`` observation (its runner,
        ``lfd.runner``, stepped once per observation: the action ``sim.control.loop.execute`` would take).
    mj_model : the simulated model (default ``setup.robot.mj_model``).
    limiter : bool
        Control through ``robots.controller.ArmController`` with its jerk-limited limiter within the
        robot's published limits (``robots.limits``; a robot without finite acceleration and jerk
        limits: ``SimError``): the joint-velocity stream a real arm takes (``sim.control.step``).
    on_reset : callable, optional
        on_reset(model, data) after the arm is placed at its start, every episode: the scene's objects
        placed where the arm's start puts them (``sim.scene.pour.place_balls``).
    limits : Limits, optional
        The limiter's limits (default ``robots.limits.limits_of(robot)``; e.g. another arm's that shares
        this one's kinematics).
    Others as ``sim.control.controller.FieldController``.
    """

    def __init__(self, setup: RunSetup, control_dt: float, *, goal: np.ndarray | None = None, ik: str = "dls",
                 perturbations: Sequence[Perturbation] = (), gains: Gains = Gains(), feedforward: bool = True,
                 mj_model: mujoco.MjModel | None = None, start_radius: float = 0.0, seed: int | None = None,
                 field: Field | None = None, dynamics: str = "mujoco", clearance: Clearance | None = None,
                 limiter: bool = False, limits: Limits | None = None,
                 on_reset: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None) -> None:
        robot, placement = setup.robot, setup.placement
        model = robot.mj_model if mj_model is None else mj_model
        self.setup = setup
        self.robot, self.placement, self.control_dt = robot, placement, float(control_dt)
        self.n_steps = int(round(setup.duration_s / control_dt))
        bodies = {model.body(i).name: i for i in range(model.nbody)}
        self.schedule: Schedule = compile_schedule(
            perturbations, placement, bodies, tool_body(robot, model), robot.n, self.n_steps, control_dt,
            {model.equality(i).name: i for i in range(model.neq)})
        self.perturbations = tuple(perturbations)
        self._nmocap = int(model.nmocap)
        self._start_nominal = setup.start + self.schedule.start_offset_task
        # a pose task's start orientation turned by exp(theta u), world
        self._start_nominal = placement.turned(self._start_nominal, self.schedule.start_turn_world)
        self.start_task = self._start_nominal.copy()
        goal = setup.goal if goal is None else np.asarray(goal, dtype=np.float64)
        self.goal_task = goal + self.schedule.goal_offset_task
        self.goal_world = placement.to_world(self.goal_task)
        if not (np.isfinite(start_radius) and start_radius >= 0):
            raise SimError(f"start radius must be >= 0, got {start_radius}")
        self.start_radius = float(start_radius)
        self._rng = np.random.default_rng(seed)
        self.field = field
        self._runner: Runner | None = None
        self._next_goal: np.ndarray | None = None
        self._shift = self.schedule.goal_offset_task.copy()
        self.rotation_ref = setup.rotation_ref
        self.on_reset = on_reset
        q0, err, rot_err, reached = placement.solve_ik(robot, self.start_task, self.rotation_ref)
        if not reached:
            p0 = placement.to_world(self.start_task)
            miss = f"{err * 1e3:.1f} mm" if not err <= IK_TOLERANCE_M else f"{np.degrees(rot_err):.1f} deg"
            raise PlacementError(f"start point {np.round(p0, 3).tolist()} m is out of reach of "
                                 f"'{robot.name}' (missed by {miss})")
        self.q_start = q0
        self.controller = FieldController(robot, placement, control_dt, ik=ik,
                                          rotation_ref=self.rotation_ref, gains=gains, feedforward=feedforward,
                                          mj_model=model, dynamics=dynamics, clearance=clearance)
        #: the controller a real arm would run (``limiter``), or None
        self.arm = self._arm_controller(limits_of(robot) if limits is None else limits) if limiter else None
        #: the control step (``sim.control.step``) that the loop, the environment and ``before_step`` call
        self.step = ControlStep(robot, self.controller, self.schedule,
                                int(round(self.control_dt / float(model.opt.timestep))), arm=self.arm)
        self.clipped_actions = 0
        self._qadr, self._dadr = robot.mj_qpos_adr, robot.mj_dof_adr
        self._acts = robot.mj_actuator_ids
        v_max = V_MAX_M_S / placement.scale
        self._action_spec = specs.BoundedArray((placement.dim,), np.float64, -v_max, v_max, name="ee_velocity")
        # check_action's fast path: the tightest scalar bounds of the spec
        self._action_shape = self._action_spec.shape
        self._v_lo, self._v_hi = float(np.max(self._action_spec.minimum)), float(np.min(self._action_spec.maximum))
        # observation constants (the controller's own x = A^T (p - o) / s, so both see the same x)
        self._At_s = np.ascontiguousarray(placement.axes.T / placement.scale)
        self._origin = placement.origin.copy()
        self._q_min, self._q_max = robot.q_min, robot.q_max
        self._q_min_l, self._q_max_l = robot.q_min.tolist(), robot.q_max.tolist()
        # A^T / s row by row, padded to 3 rows (a pose task does not use it)
        self._At_s_l: list[float] = np.vstack([self._At_s, np.zeros((3, 3))])[:3].ravel().tolist()
        self._d3 = placement.dim == 3
        self._origin_l: list[float] = self._origin.tolist()
        self._pose = placement.pose
        self._n = robot.n
        self._site = int(model.site(robot.mj_ee_site).id)
        self._data: mujoco.MjData | None = None
        # the compiled pass of ``outputs`` (a position task; ``sim.control._control_kernel.observe``): its
        # parameters, the layout of its output row and the keys' slices of it (bound by ``bind``)
        n, d = robot.n, placement.dim
        self._obs_prm = np.concatenate([
            [n, d, GOAL_TOLERANCE_M, REWARD_MARGIN_M, _REWARD_SCALE], self._origin, self._At_s.ravel(),
            self._q_min, self._q_max, np.asarray(self._qadr, dtype=np.float64),
            np.asarray(self._dadr, dtype=np.float64)]).astype(np.float64)
        self._obs_size = 3 * n + 3 + 2 * d
        bounds = np.cumsum([0, n, n, 3, d, d, n]).tolist()
        self._obs_slices = tuple(slice(a, b) for a, b in zip(bounds[:-1], bounds[1:]))
        self._observe: Callable[..., float] | None = None

    def _arm_controller(self, limits: Limits) -> ArmController:
        """The ``ArmController`` of ``limiter``: this placement's frame, the controller's gains, the
        robot's limits, and the whole-arm dampers as its guard (``ArmClearance`` on this run's data)."""
        ctl, robot = self.controller, self.robot
        frame = self.placement.task_frame(robot.planar, self.rotation_ref, ctl.gains.plane, ctl.gains.rotation)
        guard = ctl.guard
        rows: Guard | None = None
        if guard is not None:
            def rows(q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
                model, data = self.step.model, self.step.data
                if not ctl.split:   # no mj_step1 this step: MuJoCo's poses are the last step's
                    mujoco.mj_kinematics(model, data)
                    mujoco.mj_comPos(model, data)
                return guard.rows(data) if guard.check(data, dq) else None
        try:
            return ArmController(robot, frame, self.control_dt, limits=limits, guard=rows)
        except RobotError as exc:
            raise SimError(str(exc)) from None

    def _draw_start(self) -> None:
        """A start uniform in the ball of ``start_radius`` around the nominal start (module docstring)."""
        d = self.placement.dim
        for _ in range(START_DRAWS):
            u = self._rng.normal(size=d)
            r = self.start_radius * self._rng.uniform() ** (1.0 / d)
            x = self._start_nominal + r * u / max(float(np.linalg.norm(u)), 1e-300)
            q, _, _, reached = self.placement.solve_ik(self.robot, x, self.rotation_ref)
            if reached:
                self.start_task, self.q_start = x, q
                return
        raise PlacementError(f"no reachable start found in {START_DRAWS} draws within {self.start_radius:g} "
                             f"task units of {np.round(self._start_nominal, 3).tolist()}")

    # ---------------------------------------------------------------- dm_control Task API
    def set_goal(self, goal: np.ndarray) -> None:
        """Run toward ``goal``, shape (d,), task units, from the next episode on: the ``goal``
        observation, the reward, and the field of ``field_velocity`` (``Field.toward``). Position
        tasks only (a pose task's chart is its goal's: set it when the environment is made)."""
        if self.placement.pose:
            raise SimError("a pose task's goal sets its chart: give it to sim.make_environment(goal=...)")
        g = np.asarray(goal, dtype=np.float64).reshape(-1)
        if g.shape != (self.placement.dim,) or not np.isfinite(g).all():
            raise SimError(f"the goal must be {self.placement.dim} finite task coordinates, got {g.tolist()}")
        self._next_goal = g.copy()

    def initialize_episode(self, physics: ArmPhysics) -> None:
        if self._next_goal is not None:
            goal, self._next_goal = self._next_goal, None
            self.goal_task = goal + self.schedule.goal_offset_task
            self.goal_world = self.placement.to_world(self.goal_task)
            if self.field is not None:
                self.field = self.field.toward(goal)
        if self.start_radius > 0:
            self._draw_start()
        data = physics.data.ptr
        data.qpos[self._qadr] = self.q_start
        data.qvel[:] = 0.0
        data.xfrc_applied[:] = 0.0
        if self.schedule.mocap_pos is not None:
            data.mocap_pos[:] = self.schedule.mocap_pos[0]
        data.ctrl[self._acts] = self.q_start if self.controller.actuation == "position" else 0.0
        if self.on_reset is not None:
            self.on_reset(physics.model.ptr, data)
        self.controller.reset(self.q_start)
        if self.arm is not None:
            self.arm.start()   # the loop calls the field between the controller's halves
        self.step.bind(physics.model.ptr, data)
        self.step.reset()
        self.clipped_actions = 0
        self._runner = None if self.field is None else self.field.runner(self.start_task - self._shift,
                                                                          self.control_dt)

    def before_step(self, action: np.ndarray, physics: ArmPhysics) -> None:
        """Check the action and write the commands; with ``FieldController.split`` (MuJoCo's
        computed torque, whole-arm clearance) it first runs ``mj_step1`` for M(q), the bias forces
        and the geoms' poses at this state (the ``mj_step`` that follows recomputes them,
        identically): ``ControlStep.begin`` and ``command``. The hooks of dm_control's generic step;
        ``sim.control.env.FieldEnvironment.step`` runs the same control step without them."""
        v = self.check_action(action)
        step = self.step
        if step.data is not physics.data.ptr:
            step.bind(physics.model.ptr, physics.data.ptr)
        step.begin()
        step.command(v)

    def after_step(self, physics: ArmPhysics) -> None:
        """Position kinematics at the new state, so ``ee_position`` (site_xpos) describes the
        observed joints, not those before the step (``mj_step`` integrates after computing it)."""
        mujoco.mj_kinematics(physics.model.ptr, physics.data.ptr)

    def check_action(self, action: np.ndarray) -> np.ndarray:
        """The action as float64, shape (d,), clipped to the spec's bounds; ``SimError`` for a
        wrong shape or a non-finite value (module docstring)."""
        # the fast path, on Python floats (numpy's reductions cost more here)
        if type(action) is np.ndarray and action.dtype == _F64 and action.shape == self._action_shape:
            lo, hi, vals = self._v_lo, self._v_hi, action.tolist()
            if len(vals) == 2:   # unpacked, chained comparisons (a NaN fails them)
                x, y = vals
                if lo <= x <= hi and lo <= y <= hi:
                    return action
            elif len(vals) == 3:
                x, y, z = vals
                if lo <= x <= hi and lo <= y <= hi and lo <= z <= hi:
                    return action
            else:
                total = sum(vals)        # NaN if any value is NaN (min / max may skip one)
                if total == total and lo <= min(vals) and max(vals) <= hi:
                    return action
        spec = self._action_spec
        try:
            v = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise SimError(f"action must be a numeric array of shape {spec.shape} ({spec.name}, "
                           f"task units/s), got {type(action).__name__}") from None
        if v.shape != spec.shape:
            raise SimError(f"action must have shape {spec.shape} ({spec.name}, task units/s), got {v.shape}")
        if not np.isfinite(v).all():
            raise SimError(f"action must be finite, got {v.tolist()}")
        if np.any(v < spec.minimum) or np.any(v > spec.maximum):
            self.clipped_actions += 1
            v = np.clip(v, spec.minimum, spec.maximum)
        return v

    def action_spec(self, physics: ArmPhysics) -> specs.BoundedArray:
        return self._action_spec

    def get_observation(self, physics: ArmPhysics) -> collections.OrderedDict:
        """The observations (``OrderedDict``, float64):

        - ``joint_positions`` (n,), ``joint_velocities`` (n,): arm joints in Pinocchio order;
        - ``ee_position`` (3,): the tool position in world (m, MuJoCo site), computed from the
          observed joints (``after_step``, or ``sim.control.env.FieldEnvironment.step``, runs the kinematics:
          equal to Pinocchio FK up to round-off);
        - ``task_position`` (d,): the same point in task coordinates, x = A^T (p - o) / s (a pose
          task: the chart point of the tool's pose, ``sim.scene.placement``);
        - ``goal`` (d,): the goal in task coordinates (after a ``GoalShift``);
        - ``joint_limit`` (n,): 1.0 where the joint is outside [q_min, q_max], else 0.0;
        - ``field_velocity`` (d,), only with a ``field``: the field's velocity at ``task_position``
          (goal-shifted), i.e. the action that ``sim.control.loop.execute`` would take.
        """
        self.bind(physics.data.ptr)
        return self.observe()

    def bind(self, data: mujoco.MjData) -> None:
        """Keep views of ``data``'s arrays that ``observe`` and ``reward_now`` read (each attribute
        access of ``MjData`` builds a new view); cheap when ``data`` is already bound.

        Parameters
        ----------
        data : mujoco.MjData
            The raw MuJoCo data of the physics (``physics.data.ptr``).
        """
        if data is self._data:
            return
        self._data = data
        self._qpos, self._qvel = data.qpos, data.qvel
        self._qpos_arm, self._qvel_arm = contiguous(data.qpos, self._qadr), contiguous(data.qvel, self._dadr)
        # readers of fresh copies of the arm's q and qdot: a slice view's copy, else fancy indexing
        self._read_q = self._qpos_arm.copy if self._qpos_arm is not None else functools.partial(
            data.qpos.__getitem__, self._qadr)
        self._read_qdot = self._qvel_arm.copy if self._qvel_arm is not None else functools.partial(
            data.qvel.__getitem__, self._dadr)
        site = self._site
        self._site_pos = data.site_xpos[site]
        self._site_rot = data.site_xmat[site].reshape(3, 3)
        if not self._pose and self._observe is None:
            from sim.control._control_kernel import observe  # here: ``import sim`` does not import numba

            self._observe = observe

    def observe(self) -> collections.OrderedDict:
        """``get_observation`` of the bound data (``bind``), as fresh arrays (a later step does not
        change them); MuJoCo's kinematics must describe the current joints.

        Returns
        -------
        collections.OrderedDict
            ``OBSERVATION_KEYS`` (plus ``field_velocity`` with a field) to float64 arrays.
        """
        return self.outputs()[1]

    def reward_now(self) -> float:
        """``get_reward`` of the bound data (``bind``), from the tool site (see ``_goal_reward``).

        Returns
        -------
        float
            The reward in [0, 1] (NaN for a non-finite tool position).
        """
        px, py, pz = self._site_pos.tolist()
        return self._goal_reward(px, py, pz)

    def outputs(self) -> tuple[float, collections.OrderedDict]:
        """``reward_now()`` and ``observe()`` in one pass (what a control step returns). A position
        task computes both in one compiled call (``sim.control._control_kernel.observe``) that writes the
        observed values into one fresh array, shape (3 n + 3 + 2 d,); the observation's arrays are
        its slices (no two observations share memory). A pose task computes them in Python.

        Returns
        -------
        reward : float
        observation : collections.OrderedDict
        """
        assert self._data is not None, "bind(data) first"
        if self._observe is not None:   # a position task: one compiled pass into one fresh row
            row = np.empty(self._obs_size)
            reward = self._observe(self._qpos, self._qvel, self._site_pos, self.goal_task, self.goal_world,
                                   self._obs_prm, row)
            s_q, s_qdot, s_p, s_x, s_goal, s_limit = self._obs_slices
            obs = collections.OrderedDict()   # item by item: cheaper than from keywords or pairs
            obs["joint_positions"] = row[s_q]
            obs["joint_velocities"] = row[s_qdot]
            obs["ee_position"] = row[s_p]
            obs["task_position"] = x = row[s_x]
            obs["goal"] = row[s_goal]
            obs["joint_limit"] = row[s_limit]
            if self._runner is not None:
                obs["field_velocity"] = np.array(self._runner(x - self._shift, self._data.time), dtype=np.float64)
            return reward, obs
        q, qdot, p = self._read_q(), self._read_qdot(), self._site_pos.copy()
        px, py, pz = p.tolist()
        if self._pose:
            x = self.controller.chart_point(p, self._site_rot)
        else:   # x = A^T (p - o) / s on Python floats (numpy's call overhead dominates at d <= 3)
            ox, oy, oz = self._origin_l
            dx, dy, dz = px - ox, py - oy, pz - oz
            a0, a1, a2, b0, b1, b2, c0, c1, c2 = self._At_s_l
            if self._d3:
                x = np.array([a0 * dx + a1 * dy + a2 * dz, b0 * dx + b1 * dy + b2 * dz, c0 * dx + c1 * dy + c2 * dz])
            else:
                x = np.array([a0 * dx + a1 * dy + a2 * dz, b0 * dx + b1 * dy + b2 * dz])
        ql = q.tolist()
        if all(map(operator.le, self._q_min_l, ql)) and all(map(operator.le, ql, self._q_max_l)):
            limit = np.zeros(self._n)   # the common case, checked on Python floats (a NaN fails it)
        else:
            limit = np.logical_or(q < self._q_min, q > self._q_max).astype(np.float64)
        obs = collections.OrderedDict()   # item by item: cheaper than from keywords or pairs
        obs["joint_positions"] = q
        obs["joint_velocities"] = qdot
        obs["ee_position"] = p
        obs["task_position"] = x
        obs["goal"] = self.goal_task.copy()
        obs["joint_limit"] = limit
        if self._runner is not None:
            obs["field_velocity"] = np.array(self._runner(x - self._shift, self._data.time), dtype=np.float64)
        return self._goal_reward(px, py, pz), obs

    def _goal_reward(self, px: float, py: float, pz: float) -> float:
        """The reward of the tool at world point (px, py, pz), m: 1 within ``GOAL_TOLERANCE_M`` of
        the (shifted) goal, else exp(-((dist - tol) / margin)^2 scale^2 / 2), 0.1 at
        ``REWARD_MARGIN_M`` beyond the tolerance (``dm_control.utils.rewards.tolerance`` with its
        Gaussian sigmoid, on Python floats)."""
        gx, gy, gz = self.goal_world.tolist()
        dist = math.sqrt((px - gx) ** 2 + (py - gy) ** 2 + (pz - gz) ** 2)
        if dist <= GOAL_TOLERANCE_M:
            return 1.0
        return math.exp(-0.5 * ((dist - GOAL_TOLERANCE_M) / REWARD_MARGIN_M * _REWARD_SCALE) ** 2)

    def observation_spec(self, physics: ArmPhysics) -> collections.OrderedDict:
        n, d = self.robot.n, self.placement.dim
        out = collections.OrderedDict(
            joint_positions=specs.Array((n,), np.float64, "joint_positions"),
            joint_velocities=specs.Array((n,), np.float64, "joint_velocities"),
            ee_position=specs.Array((3,), np.float64, "ee_position"),
            task_position=specs.Array((d,), np.float64, "task_position"),
            goal=specs.Array((d,), np.float64, "goal"),
            joint_limit=specs.BoundedArray((n,), np.float64, 0.0, 1.0, "joint_limit"))
        if self.field is not None:
            out["field_velocity"] = specs.Array((d,), np.float64, "field_velocity")
        return out

    def get_reward(self, physics: ArmPhysics) -> float:
        """The reward at the current state (``reward_now``)."""
        self.bind(physics.data.ptr)
        return self.reward_now()

    # ---------------------------------------------------------------- restorable state
    def get_state(self, physics: ArmPhysics) -> np.ndarray:
        """Everything a replay depends on, shape (S + n + 1,): MuJoCo's ``mjSTATE_INTEGRATION``
        state (S values: time, qpos, qvel, act, warm start, ctrl, applied forces, ...), the
        controller's previous joint-velocity reference (n,) and the control-step index.

        ``physics.get_state()`` holds the MuJoCo state only: the computed-torque controller also
        remembers its previous joint-velocity reference, and the task its control-step index (push
        and noise schedule), so restoring the physics alone replays differently. With this state a
        replay is exact for the ``dls`` IK (stateless). Not included: the Environment's own step
        counter (its time limit counts from its last reset), the random start generator, and any
        state of the ``pink`` IK's QP solver."""
        m, d = physics.model.ptr, physics.data.ptr
        sim_state = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_INTEGRATION))
        mujoco.mj_getState(m, d, sim_state, mujoco.mjtState.mjSTATE_INTEGRATION)
        # the controller's only memory: qdot_ref of the last step (computed torque's qddot_ref)
        return np.concatenate([sim_state, self.controller.get_state(), [float(self.step.k)]])

    def set_state(self, physics: ArmPhysics, state: np.ndarray) -> None:
        """Restore a ``get_state`` vector; raises ``SimError`` if its size does not match."""
        m, d = physics.model.ptr, physics.data.ptr
        size = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_INTEGRATION)
        state = np.asarray(state, dtype=np.float64)
        n = self.robot.n
        if state.shape != (size + n + 1,):
            raise SimError(f"state must have shape ({size + n + 1},) (from get_state), got {state.shape}")
        mujoco.mj_setState(m, d, state[:size], mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(m, d)
        self.controller.set_state(state[size:size + n])
        self.step.k = int(round(state[-1]))

    def set_mocap_path(self, path: np.ndarray) -> None:
        """Move the mocap bodies (moving obstacles) along ``path``, shape (K+1, nmocap, 3), m, one row
        per control step (``sim.scene.obstacles.mocap_path``), from the next episode on. Each row is
        written when its step's command is (after ``mj_step1``), so with MuJoCo's computed torque
        the collision of step k still sees step k-1's positions."""
        path = np.asarray(path, dtype=np.float64)
        if path.shape != (self.n_steps + 1, self._nmocap, 3) or not np.isfinite(path).all():
            raise SimError(f"mocap path must be finite with shape ({self.n_steps + 1}, {self._nmocap}, 3), "
                           f"got {path.shape}")
        self.schedule.mocap_pos = path
