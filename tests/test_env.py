"""The dm_env / dm_control task: dm_env's own conformance tests on three arms, fresh
kinematics in the observation, checked actions, random initial states, the joint-limit flag, the
restorable state, the one-call constructor, agreement with ``sim.control.loop.execute``, and gymnasium through
shimmy (an optional extra; skipped when it is absent).

The fields are hand-made linear sinks (no training), so the tests are fast.
"""

from __future__ import annotations

import functools
import importlib.metadata
import unittest
from pathlib import Path

import numpy as np
import pytest
from dm_env import test_utils
from known_fields import sink_field

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from robots import Kinematics, RobotModel, load_robot
from sim.control.loop import execute
from sim.control.task import OBSERVATION_KEYS

EPISODE_S = 0.1                   # 50 control steps at 500 Hz
FK_TOL_M = 1e-9                   # observation vs forward kinematics of the observed joints
# sim.control.loop.execute vs a plain dm_env loop: the paths differ only in the FK that feeds the field (Pinocchio
# in execute, the MuJoCo site in the observation; they agree to round-off) and in float rounding, which
# this contracting closed loop does not amplify: over 1 s they agree to round-off on all three arms, while
# an observation from a stale site (kinematics not rerun after the step) is off by tenths of a mm. 1e-9 m
# leaves orders of magnitude for other CPUs and BLAS builds and is still far below the stale error.
EXECUTE_TOL_M = 1e-9


@functools.cache
def demos() -> lfd.DemoSet:
    return lfd.spiral(n_demos=2, n_samples=60, duration=1.0)


@functools.cache
def robot(name: str) -> RobotModel:
    if name == "ur5":   # a URDF arm from example-robot-data, loaded from its file like any user URDF
        root = Path(importlib.metadata.distribution("example-robot-data").locate_file(
            "cmeel.prefix/share/example-robot-data/robots"))
        return load_robot(str(root / "ur_description" / "urdf" / "ur5_joint_limited_robot.urdf"),
                          ee_frame="tool0", actuation="torque")
    return load_robot(name, actuation="torque")


def environment(name: str, **kwargs):
    return sim.make_environment(robot(name), demos=demos(), duration_s=kwargs.pop("duration_s", EPISODE_S),
                                **kwargs)


# ---------------------------------------------------------------- dm_env's conformance tests
class _Conformance(test_utils.EnvironmentTestMixin):
    """dm_env's mixin, with an action sequence that runs past the end of an episode."""

    robot_name = ""

    def make_object_under_test(self):
        return environment(self.robot_name, learner_field=sink_field(demos()))

    def make_action_sequence(self):
        spec = self.environment.action_spec()
        rng = np.random.default_rng(0)
        for _ in range(int(round(EPISODE_S * 500)) + 10):
            yield rng.uniform(0.1 * spec.minimum, 0.1 * spec.maximum, size=spec.shape).astype(spec.dtype)


class TestPlanarConformance(_Conformance, unittest.TestCase):
    robot_name = "planar"


class TestPandaConformance(_Conformance, unittest.TestCase):
    robot_name = "panda"


class TestURDFArmConformance(_Conformance, unittest.TestCase):
    robot_name = "ur5"


# ---------------------------------------------------------------- observations
@pytest.mark.parametrize("name", ["planar", "panda", "ur5"])
def test_ee_position_is_the_forward_kinematics_of_the_observed_joints(name: str) -> None:
    env = environment(name)
    kin = Kinematics(robot(name))
    placement = env.task.placement
    spec = env.action_spec()
    rng = np.random.default_rng(1)
    ts = env.reset()
    worst, moved = 0.0, 0.0
    while not ts.last():
        ts = env.step(rng.uniform(0.2 * spec.minimum, 0.2 * spec.maximum, size=spec.shape))
        o = ts.observation
        kin.update(o["joint_positions"])
        worst = max(worst, float(np.abs(o["ee_position"] - kin.ee_position()).max()))
        np.testing.assert_allclose(o["task_position"], placement.to_task(o["ee_position"]), rtol=0, atol=1e-12)
        moved = max(moved, float(np.linalg.norm(o["ee_position"] - env.task.placement.to_world(env.task.start_task))))
    assert worst <= FK_TOL_M, worst        # round-off; a stale site (kinematics not rerun) is off by tenths of a mm
    assert moved > 1e-3                    # the arm did move, so a stale site would have shown


def test_goal_and_joint_limit_flag_in_the_observation() -> None:
    d = demos()
    env = environment("panda", perturbations=(sim.GoalShift(distance_m=0.02, seed=3),))
    ts = env.reset()
    o = ts.observation
    assert tuple(o)[:6] == OBSERVATION_KEYS
    shift = env.task.placement.to_world(o["goal"]) - env.task.placement.to_world(d.goal)
    assert np.linalg.norm(shift) == pytest.approx(0.02, rel=1e-9)
    np.testing.assert_allclose(o["task_position"], d.x[0, 0], atol=1e-4 / env.task.placement.scale)
    assert not o["joint_limit"].any()
    r = robot("panda")
    qpos = env.physics.data.qpos
    qpos[r.mj_qpos_adr[3]] = r.q_max[3] + 0.01     # elbow 0.01 rad past its upper limit
    qpos[r.mj_qpos_adr[5]] = r.q_min[5] - 0.01
    flags = env.task.get_observation(env.physics)["joint_limit"]
    np.testing.assert_array_equal(flags, [0, 0, 0, 1, 0, 1, 0])


# ---------------------------------------------------------------- actions
def test_actions_are_checked_against_the_spec() -> None:
    a, b = environment("panda"), environment("panda")
    spec = a.action_spec()
    a.reset()
    b.reset()
    with pytest.raises(sim.SimError, match=r"action must have shape \(2,\).*got \(3, 2\)"):
        a.step(np.zeros((3, 2)))
    with pytest.raises(sim.SimError, match="finite"):
        a.step(np.array([np.nan, 0.0]))
    with pytest.raises(sim.SimError, match="numeric"):
        a.step("fast")
    big = 100 * spec.maximum * np.array([1.0, -0.5])    # 100x the bound: clipped, as the spec says
    ta = a.step(big)
    tb = b.step(np.clip(big, spec.minimum, spec.maximum))
    assert a.task.clipped_actions == 1 and b.task.clipped_actions == 0
    for key in ta.observation:
        np.testing.assert_allclose(ta.observation[key], tb.observation[key], rtol=0, atol=1e-12)


# ---------------------------------------------------------------- initial states
def test_seeded_random_initial_states() -> None:
    radius = 0.15                                     # task units (the spiral spans ~2)
    a = environment("panda", start_radius=radius, seed=7)
    b = environment("panda", start_radius=radius, seed=7)
    c = environment("panda", start_radius=radius, seed=8)
    x0 = demos().x[0, 0]
    starts_a = [a.reset().observation["task_position"] for _ in range(3)]
    starts_b = [b.reset().observation["task_position"] for _ in range(3)]
    start_c = c.reset().observation["task_position"]
    tol = 1e-4 / a.task.placement.scale               # IK tolerance, 0.1 mm, in task units
    for xa, xb in zip(starts_a, starts_b):
        np.testing.assert_allclose(xa, xb, rtol=0, atol=1e-12)       # same seed, same sequence
        assert np.linalg.norm(xa - x0) <= radius + tol
    assert np.linalg.norm(starts_a[0] - starts_a[1]) > 1e-3          # a new start each episode
    assert np.linalg.norm(start_c - starts_a[0]) > 1e-3
    fixed = environment("panda")
    s1, s2 = fixed.reset().observation["task_position"], fixed.reset().observation["task_position"]
    np.testing.assert_allclose(s1, s2, rtol=0, atol=1e-12)
    with pytest.raises(sim.SimError, match="start radius"):
        environment("panda", start_radius=-1.0)


# ---------------------------------------------------------------- restorable state
def test_task_state_restores_the_controller_too() -> None:
    """Panda, computed torque, a push during the replayed window: get_state / set_state replay
    exactly; restoring the physics alone does not (the controller's memory and the push)."""
    field = sink_field(demos())
    # 5 s episode: the Environment's own step counter is not part of the state (module docstring of
    # sim.control.task), so the three 0.9 s replays below must fit in one episode without reaching its end
    env = environment("panda", duration_s=5.0, learner_field=field,
                      perturbations=(sim.Push(force_n=20.0, duration_s=0.2, start_s=0.15, seed=1),))
    task, physics = env.task, env.physics

    def run(n: int) -> np.ndarray:
        out = []
        for _ in range(n):
            ts = env.step(ts_obs[0]["field_velocity"])
            ts_obs[0] = ts.observation
            out.append(ts.observation["ee_position"])
        return np.array(out)

    ts_obs = [env.reset().observation]
    run(50)                                           # t = 0.1 s
    saved, saved_obs = task.get_state(physics), dict(ts_obs[0])
    physics_only = physics.get_state()
    first = run(450)
    task.set_state(physics, saved)
    ts_obs[0] = saved_obs
    again = run(450)
    assert np.abs(again - first).max() <= 1e-12       # in practice a bit-identical replay
    # physics only: the controller keeps the reference of step 500 and the schedule its step index
    physics.set_state(physics_only)
    ts_obs[0] = saved_obs
    wrong = run(450)
    assert np.abs(wrong - first).max() > 1e-4         # millimetres off in practice (less without the push)
    with pytest.raises(sim.SimError, match="state must have shape"):
        task.set_state(physics, saved[:-1])


# ---------------------------------------------------------------- one call, and sim.control.loop.execute
def test_make_environment_in_one_call() -> None:
    env = sim.make_environment("panda", demos="spiral", learner_field=None, seed=0)
    ts = env.reset()
    assert tuple(ts.observation) == OBSERVATION_KEYS
    assert env.task.controller.actuation == "torque" and env.task.robot.name == "panda"
    spiral = lfd.load_demos("spiral")
    np.testing.assert_allclose(ts.observation["goal"], spiral.goal, atol=1e-12)
    assert env.task.n_steps == int(round((spiral.t[0, -1] - spiral.t[0, 0] + 1.5) * 500))
    field = sink_field(demos())
    env = sim.make_environment(robot("planar"), demos=demos(), learner_field=field, duration_s=EPISODE_S)
    o = env.reset().observation
    np.testing.assert_allclose(o["field_velocity"], field(o["task_position"]), rtol=1e-12, atol=1e-12)
    with pytest.raises(sim.SimError, match="needs demos"):
        sim.make_environment(robot("planar"))
    with pytest.raises(lfd.DemoError):
        sim.make_environment("planar", demos="lasa:NoSuchShape")


@pytest.mark.parametrize("name", ["planar", "panda"])
def test_execute_and_a_plain_dm_env_loop_agree(name: str) -> None:
    field = sink_field(demos())
    env = environment(name, duration_s=1.0)
    ro = execute(env, field.runner(env.task.start_task, env.task.control_dt))
    f = field.single_point_evaluator()
    ts = env.reset()
    ee = [ts.observation["ee_position"]]
    while not ts.last():
        ts = env.step(f(ts.observation["task_position"]))
        ee.append(ts.observation["ee_position"])
    ee = np.array(ee)
    assert ee.shape == ro.ee.shape
    assert np.abs(ee - ro.ee).max() <= EXECUTE_TOL_M
    assert np.linalg.norm(ro.ee[-1] - ro.ee[0]) > 0.01      # it went somewhere


# ---------------------------------------------------------------- gymnasium (optional extra "gym")
@pytest.mark.filterwarnings("ignore:.*(Box action spaces|Box observation space).*:UserWarning")
def test_gymnasium_through_shimmy() -> None:
    shimmy = pytest.importorskip("shimmy")
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    env = shimmy.DmControlCompatibilityV0(environment("planar", learner_field=sink_field(demos())))
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert set(obs) == set(OBSERVATION_KEYS) | {"field_velocity"}
    assert isinstance(env.action_space, gymnasium.spaces.Box) and env.action_space.shape == (2,)
    obs, reward, terminated, truncated, _ = env.step(obs["field_velocity"].astype(np.float32))
    assert 0.0 <= reward <= 1.0 and not terminated


# ---------------------------------------------------------------- the lean step (sim.control.env.FieldEnvironment)
# lean step vs sim.control.loop.execute, and vs dm_control's generic step: round-off (see EXECUTE_TOL_M)
LEAN_TOL = 1e-9


def _env_rollout(env, f) -> tuple[np.ndarray, np.ndarray, list]:
    """Tool positions (K+1, 3), joints (K+1, n) and the time steps of one episode of ``env`` with policy f(x)."""
    ts = env.reset()
    steps = [ts]
    while not ts.last():
        ts = env.step(f(ts.observation["task_position"]))
        steps.append(ts)
    return (np.array([s.observation["ee_position"] for s in steps]),
            np.array([s.observation["joint_positions"] for s in steps]), steps)


@pytest.mark.parametrize("name,actuation,perts", [
    ("planar", "torque", ()),
    ("panda", "torque", (sim.Push(force_n=20.0, duration_s=0.2, start_s=0.1, seed=1),
                         sim.JointVelocityNoise(std_rad_s=0.01, seed=2))),
    ("panda", "position", (sim.Push(force_n=20.0, duration_s=0.2, start_s=0.1, seed=1),)),
], ids=["planar", "panda-push-noise", "panda-servo-push"])
def test_lean_step_rollout_equals_the_lean_loop(name: str, actuation: str, perts: tuple) -> None:
    """The environment's own step (MuJoCo's tool site, mj_step1 / mj_step2, the task's perturbations)
    and ``sim.control.loop.execute`` run the same physics and control: the same tool path and joints."""
    from sim.control.env import FieldEnvironment

    field = sink_field(demos())
    env = sim.make_environment(load_robot(name, actuation=actuation), demos=demos(), duration_s=0.6,
                               perturbations=perts)
    assert isinstance(env, FieldEnvironment) and env.lean
    ro = execute(env, field.runner(env.task.start_task, env.task.control_dt))
    ee, q, steps = _env_rollout(env, field.single_point_evaluator())
    assert ee.shape == ro.ee.shape and len(steps) == env.task.n_steps + 1
    assert np.allclose(ee, ro.ee, rtol=0, atol=LEAN_TOL), np.abs(ee - ro.ee).max()
    assert np.allclose(q, ro.q, rtol=0, atol=1e3 * LEAN_TOL), np.abs(q - ro.q).max()
    assert np.linalg.norm(ro.ee[-1] - ro.ee[0]) > 0.01      # it went somewhere


@pytest.mark.parametrize("name", ["planar", "panda"])
def test_lean_step_equals_dm_controls_generic_step(name: str) -> None:
    """Step for step, the lean ``step`` returns what ``control.Environment.step`` (task hooks,
    ``Physics.step``) returns for the same actions: step types, discounts, rewards, observations."""
    from dm_control.rl import control

    field = sink_field(demos())
    lean, generic = (environment(name, duration_s=0.2, learner_field=field) for _ in range(2))
    a, b = lean.reset(), generic.reset()
    n = 0
    while True:
        assert a.step_type == b.step_type and a.discount == b.discount
        assert (a.reward is None) == (b.reward is None)
        if a.reward is not None:
            assert a.reward == pytest.approx(b.reward, rel=0, abs=1e-12)
        assert list(a.observation) == list(b.observation)
        for key in a.observation:
            x, y = a.observation[key], b.observation[key]
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape
            assert np.allclose(x, y, rtol=0, atol=LEAN_TOL), (key, np.abs(x - y).max())
        if a.last():
            break
        v = a.observation["field_velocity"]
        a, b = lean.step(v), control.Environment.step(generic, v)
        n += 1
    assert n == lean.task.n_steps
    spec = lean.observation_spec()
    for key, value in a.observation.items():
        spec[key].validate(value)
    assert lean.step(v).first()                              # a step after LAST resets, as dm_control's does


def test_lean_step_keeps_earlier_observations_and_counts_like_dm_control() -> None:
    env = environment("panda", duration_s=0.05, learner_field=sink_field(demos()))
    ts = env.reset()
    kept, frozen = [ts.observation], [{k: v.copy() for k, v in ts.observation.items()}]
    while not ts.last():
        ts = env.step(ts.observation["field_velocity"])
        kept.append(ts.observation)
        frozen.append({k: v.copy() for k, v in ts.observation.items()})
    assert len(kept) == 26                                   # 25 steps of 2 ms, then LAST
    for obs, copy in zip(kept, frozen):                      # later steps did not write into earlier observations
        for key in obs:
            np.testing.assert_array_equal(obs[key], copy[key])
    for earlier, later in zip(kept[:-1], kept[1:]):          # fresh arrays every step, none shared
        for key in earlier:
            assert not np.shares_memory(earlier[key], later[key])
    assert np.abs(kept[-1]["ee_position"] - kept[0]["ee_position"]).max() > 1e-4   # and they did change
    kept[1]["joint_positions"][:] = 0.0                      # writing into an observation leaves the physics alone
    assert np.abs(env.physics.data.qpos[:7]).max() > 0.1


def test_lean_step_reward_and_physics_errors() -> None:
    from dm_control.rl import control
    from dm_control.utils import rewards

    env = environment("panda", duration_s=0.1)
    env.reset()
    task = env.task
    for dist in (0.0, 0.004, 0.0051, 0.02, 0.05, 0.3):      # the reward is dm_control's tolerance
        p = task.goal_world + dist * np.array([0.6, 0.0, 0.8])
        expected = rewards.tolerance(float(np.linalg.norm(p - task.goal_world)), bounds=(0.0, 0.005), margin=0.05)
        assert task._goal_reward(*p.tolist()) == pytest.approx(expected, rel=1e-12, abs=1e-15)
    env.step(np.zeros(2))
    env.physics.data.qvel[0] = 1e11                          # MuJoCo warns (bad qvel) and resets its state
    with pytest.raises(control.PhysicsError, match="mjWARN_BADQVEL"):
        env.step(np.zeros(2))
    env.reset()
    env.physics.data.qvel[0] = 1e11
    with env.physics.suppress_physics_errors():              # as dm_control: logged, not raised
        ts = env.step(np.zeros(2))
    assert ts.mid()


def test_a_task_that_overrides_a_hook_gets_dm_controls_step() -> None:
    from sim.control.env import FieldEnvironment
    from sim.control.task import FieldTrackingTask

    class Tagged(FieldTrackingTask):
        def get_observation(self, physics):
            obs = super().get_observation(physics)
            obs["tag"] = np.ones(1)
            return obs

    base = environment("planar")
    task = base.task
    task.__class__ = Tagged
    env = FieldEnvironment(base.physics, task, time_limit=EPISODE_S, control_timestep=task.control_dt)
    assert not env.lean
    ts = env.reset()
    ts = env.step(np.zeros(2))
    assert "tag" in ts.observation and ts.mid()
