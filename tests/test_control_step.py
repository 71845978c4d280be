"""The fast control step: computed torque from MuJoCo's own M(q) and bias forces (one
``mj_step`` split into ``mj_step1`` / ``mj_step2``) instead of a second inverse-dynamics pass with
Pinocchio's RNEA, and twist + DLS + command fused into one compiled call.

Both are checked against the old path, computed here side by side: the same closed-loop tool path
to TRACK_TOL_M (round-off in practice, on the Panda, spiral fields, with a push and with joint
noise), the same torques to TORQUE_TOL, and the fused call equal to the Python path (also where
it hands over to that path, near a joint limit).
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from known_fields import sink_field

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from lfd.demos import robottasks
from robots import RobotModel, load_robot
from sim.control.loop import execute
from sim.errors import SimError
from sim.scene.perturbations import JointVelocityNoise, Push

TRACK_TOL_M = 1e-9        # tool path, MuJoCo vs Pinocchio inverse dynamics (they agree to round-off)
TORQUE_TOL = 1e-9         # N m, M a + c from MuJoCo vs RNEA (they agree to round-off)
CTRL_TOL = 1e-10          # fused kernel vs the Python path, actuator command


@functools.cache
def _demos() -> lfd.DemoSet:
    return lfd.spiral(n_demos=2, n_samples=60, duration=1.0)


@functools.cache
def _robot(name: str, actuation: str = "torque") -> RobotModel:
    return load_robot(name, actuation=actuation)


def _field() -> lfd.VelocityField:
    d = _demos()
    return sink_field(d)


def _env(name: str, actuation: str = "torque", **kwargs):
    return sim.make_environment(_robot(name, actuation), demos=_demos(),
                                duration_s=kwargs.pop("duration_s", 1.0), **kwargs)


@pytest.mark.parametrize("name", ["planar", "panda"])
@pytest.mark.parametrize("perts", [(), (Push(force_n=20.0, duration_s=0.2, start_s=0.2, seed=1),),
                                   (JointVelocityNoise(std_rad_s=0.01, seed=2),)], ids=["none", "push", "noise"])
def test_mujoco_and_pinocchio_inverse_dynamics_track_alike(name: str, perts: tuple) -> None:
    field = _field()
    runs = {}
    for dynamics in ("mujoco", "pinocchio"):
        env = _env(name, perturbations=perts, dynamics=dynamics)
        assert env.task.controller.uses_mj_dynamics == (dynamics == "mujoco")
        runs[dynamics] = execute(env, field.runner(env.task.start_task, env.task.control_dt))
    a, b = runs["mujoco"], runs["pinocchio"]
    assert np.linalg.norm(a.ee[-1] - a.ee[0]) > 0.01                 # it moved
    assert np.abs(a.ee - b.ee).max() <= TRACK_TOL_M
    assert np.abs(a.q - b.q).max() <= 1e3 * TRACK_TOL_M
    assert a.ik_limit_hits == b.ik_limit_hits


def test_mujoco_torque_equals_rnea_on_random_states() -> None:
    robot = _robot("panda")
    m = robot.mj_model
    d = mujoco.MjData(m)
    pdata = robot.pin_model.createData()
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = robot.q_home + 0.3 * rng.normal(size=robot.n)
        v, a = rng.normal(size=robot.n), rng.normal(size=robot.n)
        d.qpos[robot.mj_qpos_adr], d.qvel[robot.mj_dof_adr] = q, v
        mujoco.mj_step1(m, d)
        full = np.zeros(m.nv)
        full[robot.mj_dof_adr] = a
        ma = np.zeros(m.nv)
        mujoco.mj_mulM(m, d, ma, full)
        tau = ma[robot.mj_dof_adr] + d.qfrc_bias[robot.mj_dof_adr]
        assert np.abs(tau - pin.rnea(robot.pin_model, pdata, q, v, a)).max() <= TORQUE_TOL


@pytest.mark.parametrize("name, actuation", [("panda", "torque"), ("panda", "position"), ("planar", "torque")])
def test_fused_command_equals_the_python_path(name: str, actuation: str) -> None:
    """The compiled twist + DLS + command against ``twist`` / ``solve_ik`` / ``actuate``, on states
    along a run and on one beside a joint limit (where the kernel hands over to Python)."""
    env = _env(name, actuation)
    env.reset()
    ctl, m, d = env.task.controller, env.physics.model.ptr, env.physics.data.ptr
    robot = _robot(name, actuation)
    acts, f = robot.mj_actuator_ids, _field().single_point_evaluator()
    rng = np.random.default_rng(1)
    states = [(robot.q_home + 0.2 * rng.normal(size=robot.n), 0.3 * rng.normal(size=robot.n)) for _ in range(10)]
    near = robot.q_max - 0.021                                            # beside the soft limit (margin 0.02)
    states.append((np.where(np.isfinite(near), near, robot.q_home), np.zeros(robot.n)))
    for q, qd in states:
        d.qpos[robot.mj_qpos_adr], d.qvel[robot.mj_dof_adr] = q, qd
        mujoco.mj_step1(m, d)
        prev = np.array(rng.normal(size=robot.n))
        v = f(ctl.to_task(ctl.measure(q)))
        ctl._qdot_prev = prev.copy()
        ctl.fast_command(m, d, q, v)
        fast, prev_fast = d.ctrl[acts].copy(), np.array(ctl._qdot_prev)
        ctl._qdot_prev = prev.copy()
        hits = ctl.ik.limit_hits
        slow = ctl.command(q, d.qvel[robot.mj_dof_adr].copy(), v, m, d)
        assert np.abs(fast - slow).max() <= CTRL_TOL * max(1.0, np.abs(slow).max())
        if actuation == "torque":
            np.testing.assert_allclose(prev_fast, ctl._qdot_prev, rtol=0, atol=1e-12)
        ctl.ik.limit_hits = hits
        # MuJoCo's site for the pose (execute's path after mj_step1) gives the same command
        ctl.bind(d)
        ctl._qdot_prev = prev.copy()
        ctl.measure_site(q)
        ctl.fast_command(m, d, q, v)
        assert np.abs(d.ctrl[acts] - slow).max() <= CTRL_TOL * max(1.0, np.abs(slow).max())


@pytest.mark.parametrize("actuation", ["torque", "position"])
def test_fused_pose_command_equals_the_python_path(actuation: str) -> None:
    """A pose task (Eqs. (P1), (P3)): the compiled chart point of ``to_task`` against the chart's
    own, and the kernel's twist + DLS + command against ``twist`` / ``solve_ik`` / ``actuate``, from
    Pinocchio's pose and from MuJoCo's site."""
    rec = robottasks("pouring")
    demos = lfd.DemoSet(rec.t[:2, ::4], rec.x[:2, ::4], q=rec.q[:2, ::4])
    field = lfd.train("tracking", demos)
    env = sim.make_environment(_robot("panda", actuation), demos=demos, learner_field=field, duration_s=0.5)
    env.reset()
    ctl, m, d = env.task.controller, env.physics.model.ptr, env.physics.data.ptr
    robot, chart = _robot("panda", actuation), env.task.placement.chart
    assert chart is not None and ctl._pose_point is not None and ctl._kernel is not None
    acts, f = robot.mj_actuator_ids, field.single_point_evaluator()
    rng = np.random.default_rng(3)
    q0 = d.qpos[robot.mj_qpos_adr].copy()
    for _ in range(10):
        q, qd = q0 + 0.1 * rng.normal(size=robot.n), 0.3 * rng.normal(size=robot.n)
        d.qpos[robot.mj_qpos_adr], d.qvel[robot.mj_dof_adr] = q, qd
        mujoco.mj_step1(m, d)
        p = ctl.measure(q)
        z = ctl.to_task(p)
        want = chart.point(ctl._At_s.dot(p - ctl._origin), ctl._rot_t.dot(ctl.measured_rotation()))
        np.testing.assert_allclose(z, want, rtol=0, atol=1e-12)
        v = f(z)
        prev = np.array(rng.normal(size=robot.n))
        ctl._qdot_prev = prev.copy()
        ctl.fast_command(m, d, q, v)
        fast = d.ctrl[acts].copy()
        ctl._qdot_prev = prev.copy()
        slow = ctl.command(q, d.qvel[robot.mj_dof_adr].copy(), v, m, d)
        assert np.abs(fast - slow).max() <= CTRL_TOL * max(1.0, np.abs(slow).max())
        ctl.bind(d)
        ctl._qdot_prev = prev.copy()
        np.testing.assert_allclose(ctl.to_task(ctl.measure_site(q)), z, rtol=0, atol=1e-12)
        ctl.fast_command(m, d, q, v)
        assert np.abs(d.ctrl[acts] - slow).max() <= CTRL_TOL * max(1.0, np.abs(slow).max())


def test_unknown_dynamics_is_a_sim_error() -> None:
    with pytest.raises(SimError, match="unknown inverse dynamics"):
        _env("planar", dynamics="featherstone")


def test_phase_lead_adds_the_command_difference_once_and_resets() -> None:
    """Gains.lead_s: v_k + (lead / dt)(v_k - v_{k-1}), nothing at a run's first step, none by default;
    the fused and the Python path both lead (each once)."""
    from sim.control.controller import FieldController, Gains

    robot, demos = _robot("panda"), _demos()
    placement = sim.Placement.auto(robot, demos.x)
    ctl = FieldController(robot, placement, 0.002, gains=Gains(lead_s=0.01))
    v1, v2 = np.array([0.1, -0.2]), np.array([0.3, 0.1])
    np.testing.assert_array_equal(ctl.lead(v1), v1)
    np.testing.assert_allclose(ctl.lead(v2), v2 + 5.0 * (v2 - v1), rtol=1e-15)
    ctl.reset(robot.q_home)
    np.testing.assert_array_equal(ctl.lead(v2), v2)
    plain = FieldController(robot, placement, 0.002)
    np.testing.assert_array_equal(plain.lead(v1), v1)
    np.testing.assert_array_equal(plain.lead(v2), v2)
    # on the arm: the python and the fused paths agree with the lead on (so each leads once)
    for fast in (True, False):
        env = _env("panda", gains=Gains(lead_s=0.01))
        if not fast:
            env.task.controller._fast_ok = False
        ro = execute(env, _field().runner(env.task.start_task, env.task.control_dt))
        if fast:
            ee_fast = ro.ee
    assert np.max(np.linalg.norm(ro.ee - ee_fast, axis=1)) < 1e-9
    with pytest.raises(SimError, match="lead_s"):
        FieldController(robot, placement, 0.002, gains=Gains(lead_s=-0.1))
