"""The closed-loop task as a dm_control ``control.Environment``: a Physics and a Task kept apart.

* Physics: the robot's MuJoCo scene (``robot.mjcf_xml``), ``ArmPhysics``.
* Task (``FieldTrackingTask``): starts the arm at rest with the tool on the start point,
  takes as action the tool velocity v, shape (d,), in TASK coordinates (user units per second,
  the same units as the learned field's output), and turns it into actuator commands through
  ``sim.controller.FieldController``; applies the run's perturbations (``sim.perturbations``).
* Observations (``OrderedDict``): ``joint_positions`` (n,), ``joint_velocities`` (n,) of the arm
  joints in Pinocchio order, ``ee_position`` (3,) the tool position in world (m, MuJoCo site).
* Reward: 1 within 5 mm of the (shifted) goal, falling off as a Gaussian over 5 cm
  (``dm_control.utils.rewards.tolerance``).

The fast loop (``sim.rollout``) uses these same Physics and Task objects but calls
``mujoco.mj_step`` on ``physics.model.ptr`` / ``physics.data.ptr`` directly: ``Environment.step``
(with its observation dicts, reward and wrapped-array access) measured 1.4-1.8x the lean loop's
cost per control step (scripts/bench_loop.py).
"""

from __future__ import annotations

import collections
from typing import Sequence

import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.rl import control
from dm_control.utils import rewards
from dm_env import specs

from robots import Kinematics, RobotModel, solve_position_ik
from sim.controller import FieldController, Gains
from sim.errors import PlacementError, SimError
from sim.perturbations import Perturbation, Schedule, compile_schedule
from sim.placement import IK_TOLERANCE_M, Placement

OBSERVATION_KEYS: tuple[str, ...] = ("joint_positions", "joint_velocities", "ee_position")
GOAL_TOLERANCE_M = 0.005


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

    @classmethod
    def from_robot(cls, robot: RobotModel) -> "ArmPhysics":
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


class FieldTrackingTask(control.Task):
    """Drive the tool with a task-space velocity action; see the module docstring.

    start, goal : arrays, shape (d,) -- demo start and field goal, task coordinates, before
    perturbation offsets. ``q_start``, ``start_task`` and ``goal_task`` hold the actual values.
    """

    def __init__(self, robot: RobotModel, placement: Placement, start: np.ndarray, goal: np.ndarray,
                 control_dt: float, duration_s: float, ik: str = "dls", actuation: str | None = None,
                 perturbations: Sequence[Perturbation] = (), rotation_ref: np.ndarray | None = None,
                 gains: Gains = Gains(), feedforward: bool = True,
                 mj_model: mujoco.MjModel | None = None) -> None:
        model = robot.mj_model if mj_model is None else mj_model
        self.robot, self.placement, self.control_dt = robot, placement, float(control_dt)
        self.n_steps = int(round(duration_s / control_dt))
        bodies = {model.body(i).name: i for i in range(model.nbody)}
        self.schedule: Schedule = compile_schedule(
            perturbations, placement, bodies, tool_body(robot, model), robot.n, self.n_steps, control_dt)
        self.perturbations = tuple(perturbations)
        self.start_task = np.asarray(start, dtype=np.float64) + self.schedule.start_offset_task
        self.goal_task = np.asarray(goal, dtype=np.float64) + self.schedule.goal_offset_task
        self.goal_world = placement.to_world(self.goal_task)
        if rotation_ref is None and not robot.planar:
            kin = Kinematics(robot)
            kin.update(robot.q_home)
            rotation_ref = kin.ee_rotation().copy()
        self.rotation_ref = rotation_ref
        p0 = placement.to_world(self.start_task)
        q0, err = solve_position_ik(robot, p0, rotation_ref, q0=robot.q_home)
        if not err <= IK_TOLERANCE_M:
            raise PlacementError(f"start point {np.round(p0, 3).tolist()} m is out of reach of "
                                 f"'{robot.name}' (missed by {err * 1e3:.1f} mm)")
        self.q_start = q0
        self.controller = FieldController(robot, placement, control_dt, ik=ik, actuation=actuation,
                                          rotation_ref=rotation_ref, gains=gains, feedforward=feedforward,
                                          mj_model=model)
        self.step_index = 0
        self._qadr, self._dadr = robot.mj_qpos_adr, robot.mj_dof_adr
        self._acts = robot.mj_actuator_ids
        v_max = 2.0 / placement.scale  # 2 m/s in task units: far above any demo speed
        self._action_spec = specs.BoundedArray((placement.dim,), np.float64, -v_max, v_max, name="ee_velocity")

    # ---------------------------------------------------------------- dm_control Task API
    def initialize_episode(self, physics: ArmPhysics) -> None:
        data = physics.data.ptr
        data.qpos[self._qadr] = self.q_start
        data.qvel[:] = 0.0
        data.xfrc_applied[:] = 0.0
        data.ctrl[self._acts] = self.q_start if self.controller.actuation == "position" else 0.0
        self.controller.reset(self.q_start)
        self.step_index = 0

    def before_step(self, action: np.ndarray, physics: ArmPhysics) -> None:
        data = physics.data.ptr
        q = data.qpos[self._qadr]
        self.controller.measure(q)
        self.apply(data, q, data.qvel[self._dadr], np.asarray(action, dtype=np.float64))

    def action_spec(self, physics: ArmPhysics) -> specs.BoundedArray:
        return self._action_spec

    def get_observation(self, physics: ArmPhysics) -> collections.OrderedDict:
        return collections.OrderedDict(
            joint_positions=physics.joint_positions(),
            joint_velocities=physics.joint_velocities(),
            ee_position=physics.ee_position())

    def observation_spec(self, physics: ArmPhysics) -> collections.OrderedDict:
        n = self.robot.n
        return collections.OrderedDict(
            joint_positions=specs.Array((n,), np.float64, "joint_positions"),
            joint_velocities=specs.Array((n,), np.float64, "joint_velocities"),
            ee_position=specs.Array((3,), np.float64, "ee_position"))

    def get_reward(self, physics: ArmPhysics) -> float:
        dist = float(np.linalg.norm(physics.ee_position() - self.goal_world))
        return float(rewards.tolerance(dist, bounds=(0.0, GOAL_TOLERANCE_M), margin=0.05))

    # ---------------------------------------------------------------- shared with the fast loop
    def apply(self, data: mujoco.MjData, q: np.ndarray, qdot: np.ndarray, v: np.ndarray) -> None:
        """Write the actuator commands for task velocity v, shape (d,), at the measured q, qdot
        (``controller.measure(q)`` already called), and this control step's perturbations."""
        k = self.step_index
        data.ctrl[self._acts] = self.controller.command(q, qdot, v)
        s = self.schedule
        if s.push_body >= 0:
            k0, k1 = s.push_steps
            if k0 <= k < k1:
                data.xfrc_applied[s.push_body] = s.push_force
            elif k == k1:
                data.xfrc_applied[s.push_body] = 0.0
        if s.qvel_noise is not None and k < len(s.qvel_noise):
            data.qvel[self._dadr] += s.qvel_noise[k]
        self.step_index = k + 1


def make_environment(robot: RobotModel, placement: Placement, start: np.ndarray, goal: np.ndarray, *,
                     control_hz: float = 500.0, duration_s: float = 6.0, ik: str = "dls",
                     actuation: str | None = None, perturbations: Sequence[Perturbation] = (),
                     rotation_ref: np.ndarray | None = None, gains: Gains = Gains(),
                     feedforward: bool = True, physics: ArmPhysics | None = None) -> control.Environment:
    """A dm_control Environment of ``robot`` following task velocities; ``actuation`` (position or
    torque) must be the one the robot was loaded with (None: whichever that was).

    The control step is 1 / control_hz s, an integer number of MuJoCo steps; an episode lasts
    ``duration_s``. The Task sets the actuators itself, so the Environment has
    ``legacy_step=False`` (a plain ``mj_step`` per physics step). Pass ``physics`` (built by
    ``ArmPhysics.from_robot(robot)``) to reuse one compiled model across environments.
    """
    physics = ArmPhysics.from_robot(robot) if physics is None else physics
    timestep = physics.model.opt.timestep
    if not control_hz > 0:
        raise SimError(f"control rate must be positive, got {control_hz}")
    n_sub = (1.0 / control_hz) / timestep
    if n_sub < 1 - 1e-9 or abs(n_sub - round(n_sub)) > 1e-6:
        raise SimError(f"control rate {control_hz:g} Hz must divide the physics rate {1 / timestep:g} Hz")
    control_dt = round(n_sub) * timestep
    task = FieldTrackingTask(robot, placement, start, goal, control_dt, duration_s, ik=ik,
                             actuation=actuation, perturbations=perturbations, rotation_ref=rotation_ref,
                             gains=gains, feedforward=feedforward, mj_model=physics.model.ptr)
    return control.Environment(physics, task, time_limit=duration_s, control_timestep=control_dt,
                               legacy_step=False)
