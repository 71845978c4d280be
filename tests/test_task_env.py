"""Tasks with objects as dm_env environments (``sim.run.task_env.make_task_environment``): dm_env's own conformance
tests on the pour, the placement and the lid, the reward read from the task's predicate, the episode ended on
success, and a failed task rewarded nothing."""

from __future__ import annotations

import unittest

import numpy as np
import pytest
from dm_env import test_utils

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from lfd.errors import ConfigError
from sim.run.task_env import make_task_environment
from sim.scene import lid, place, pour

EPISODE_S = 0.1   # 50 control steps at 500 Hz


class _Conformance(test_utils.EnvironmentTestMixin):
    """dm_env's mixin, with an action sequence that runs past the end of an episode."""

    task = ""

    def make_object_under_test(self):
        return make_task_environment(self.task, duration_s=EPISODE_S)

    def make_action_sequence(self):
        spec = self.environment.action_spec()
        rng = np.random.default_rng(0)
        for _ in range(int(round(EPISODE_S * 500)) + 10):
            yield rng.uniform(0.1 * spec.minimum, 0.1 * spec.maximum, size=spec.shape).astype(spec.dtype)


class TestPourConformance(_Conformance, unittest.TestCase):
    task = "pour"


class TestPlaceConformance(_Conformance, unittest.TestCase):
    task = "place"


class TestLidConformance(_Conformance, unittest.TestCase):
    task = "lid"


def _episode(env) -> tuple[list[float], object]:
    ts = env.reset()
    rewards = []
    while not ts.last():
        ts = env.step(ts.observation["field_velocity"])
        rewards.append(ts.reward)
    return rewards, ts


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("task", ["pour", "place", "lid"])
def test_the_learned_task_ends_its_episode_on_success_with_the_predicates_reward(task: str) -> None:
    """The tracking learner's motion from the task's RoboTasks9 demos, its object moved by ``target``:
    the reward is 0 until the predicate holds, then 1 on the last step (discount 0), before the time
    limit; and in that last state the objects are where the task needs them (checked here from the
    state by hand, not by the predicate's code)."""
    demos = lfd.load_demos({"pour": "robottasks:pouring", "place": "robottasks:bottle2shelf",
                            "lid": "robottasks:openbox"}[task])
    target = {"pour": (0.45, -0.30), "place": (0.40, -0.42), "lid": None}[task]
    env = make_task_environment(task, lfd.train("tracking", demos, seed=0), target=target)
    rewards, ts = _episode(env)
    assert rewards[-1] == 1.0 and ts.discount == 0.0 and not any(rewards[:-1])
    assert env.physics.data.time < env.task.setup.duration_s - 0.1          # ended on success, not by time
    model, data = env.physics.model.ptr, env.physics.data.ptr
    if task == "pour":
        bowl = data.xpos[model.body("pour_bowl").id]
        assert bowl[:2] == pytest.approx(target)
        balls = np.array([data.xpos[model.body(f"pour_ball{i}").id] for i in range(12)])
        inside = (np.hypot(*(balls - bowl)[:, :2].T) < 0.07) & (balls[:, 2] < 0.06)
        assert inside.sum() >= pour.SUCCESS_BALLS
    elif task == "lid":
        assert lid.lid_angle_deg(model, data.qpos) >= lid.OPEN_DEG
    else:
        b = model.body("place_bottle").id
        assert np.degrees(np.arccos(data.xmat[b][8])) < place.UPRIGHT_DEG
        assert np.hypot(*(data.xpos[b][:2] - np.array(target))) < place.SPOT_M
        assert data.eq_active[model.equality(place.GRIP).id] == 0                # let go


@pytest.mark.usefixtures("one_thread")
def test_a_placement_that_never_reaches_its_shelf_earns_nothing_and_runs_to_its_time_limit() -> None:
    """Zero actions: the arm holds the bottle where it starts; the grip opens at the motion's end and
    the bottle falls onto the table, not its shelf: reward 0 on every step, the episode ends by time."""
    env = make_task_environment("place", duration_s=17.5)
    ts, rewards = env.reset(), []
    while not ts.last():
        ts = env.step(np.zeros(env.action_spec().shape))
        rewards.append(ts.reward)
    assert not any(rewards) and ts.discount == 1.0 and len(rewards) == 17.5 * 500
    b = env.physics.model.ptr.body("place_bottle").id
    assert env.physics.data.ptr.xpos[b][2] < 0.1              # on the table, far below the shelf's top


def test_an_unknown_task_is_one_clear_error() -> None:
    with pytest.raises(ConfigError, match=r"^unknown task 'jar'; known: pour, place, lid$"):
        make_task_environment("jar")
