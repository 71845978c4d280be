"""The goal is an input on the arm: the job's ``--goal``, ``RunSetup.resolve(goal=...)`` and the dm_env task."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from robots import load_robot
from sim.run.cli import main as demo_arm


def _goal_pose(demos: lfd.DemoSet, offset_m: np.ndarray, turn_deg: float, axis: np.ndarray) -> np.ndarray:
    """The demos' mean end pose moved by offset_m (3,) and turned by turn_deg about the world axis."""
    assert demos.goal_q is not None
    turn = Rotation.from_rotvec(np.radians(turn_deg) * axis / np.linalg.norm(axis))
    q = (turn * Rotation.from_quat(demos.goal_q, scalar_first=True)).as_quat(scalar_first=True)
    return np.concatenate([demos.goal + offset_m, q])


def test_pour_runs_to_a_goal_no_demo_reached(tmp_path):
    """The pour on the Panda to a goal 10 cm and 30 degrees from the demos' mean end: there within
    2 mm and 1 degree, the tool on its field's path within 2 mm and 1 degree, no joint limit hit."""
    demos = lfd.load_demos("robottasks:pouring")
    goal = _goal_pose(demos, np.array([0.0, 0.10, 0.0]), 30.0, np.array([0.0, 0.0, 1.0]))
    out = tmp_path / "pour"
    code = demo_arm(["--demos", "robottasks:pouring", "--learner", "tracking", "--perturb", "none", "--no-video",
                     "--no-plots", "--quiet", "--out", str(out), "--goal", ",".join(f"{v:.9f}" for v in goal)])
    assert code == 0
    report = json.loads((out / "metrics.json").read_text())
    assert report["settings"]["goal"] == pytest.approx(list(goal), abs=1e-8)
    m = report["runs"][0]["metrics"]
    assert m["final_goal_error_m"] < 2e-3 and m["final_goal_error_deg"] < 1.0
    assert m["tracking_rmse_m"] < 2e-3 and m["tracking_rmse_deg"] < 1.0
    assert m["joint_limit_violations"] == 0


@pytest.mark.parametrize("learner", ["contraction", "tracking"])
def test_a_position_field_runs_to_the_jobs_goal(tmp_path, learner):
    demos = lfd.load_demos("spiral")
    goal = demos.goal + np.array([0.25, -0.15])
    out = tmp_path / learner
    assert demo_arm(["--robot", "planar", "--learner", learner, "--perturb", "none", "--no-video", "--no-plots",
                     "--quiet", "--out", str(out), "--goal", f"{goal[0]},{goal[1]}"]) == 0
    m = json.loads((out / "metrics.json").read_text())["runs"][0]["metrics"]
    assert m["final_goal_error_m"] < 2e-3


@pytest.mark.parametrize("flag, message", [
    ("1,2,3,4", "--goal: expected X,Y[,Z] or X,Y,Z,QW,QX,QY,QZ"),
    ("0.1,0.2,0.3", "--goal needs 2 coordinates"),
    ("40,40", "out of the arm's reach"),
])
def test_a_bad_goal_is_one_line_and_exit_2(tmp_path, capsys, flag, message):
    code = demo_arm(["--robot", "planar", "--learner", "tracking", "--perturb", "none", "--no-video", "--quiet",
                     "--out", str(tmp_path / "bad"), f"--goal={flag}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err
    assert not (tmp_path / "bad").exists()


def test_dm_env_goal_is_in_the_observation_and_set_at_reset():
    """make_environment(goal=...) and task.set_goal: the goal observation, and the field's velocity
    followed as the action ends at that goal."""
    demos = lfd.load_demos("spiral")
    field = lfd.train("tracking", demos)
    robot = load_robot("planar")
    first = demos.goal + np.array([0.2, 0.1])
    env = sim.make_environment(robot, demos, learner_field=field, goal=first, duration_s=7.0)
    ts = env.reset()
    np.testing.assert_allclose(ts.observation["goal"], first, atol=1e-12)
    second = demos.goal + np.array([-0.15, 0.2])
    for goal in (first, second):
        while not ts.last():
            ts = env.step(ts.observation["field_velocity"])
        assert np.linalg.norm(ts.observation["task_position"] - goal) < 0.01
        env.task.set_goal(second)
        ts = env.reset()
        np.testing.assert_allclose(ts.observation["goal"], second, atol=1e-12)
    with pytest.raises(sim.SimError, match="finite task coordinates"):
        env.task.set_goal(np.array([np.nan, 0.0]))
