"""A pose field on the Panda, where the demos were recorded: tool tracking, orientation metrics, the
turned start and goal, the push, and the video's tool frames."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lfd
from lfd.demos import DemoSet, robottasks
from robots import load_robot
from sim.run.experiment import Experiment
from sim.run.pipeline import ArmJob, run_job
from sim.scene.perturbations import GoalShift, StartOffset

pytestmark = pytest.mark.usefixtures("one_thread")   # torch rollouts: one thread (conftest.py)


@pytest.fixture(scope="module")
def pouring() -> DemoSet:
    d = robottasks("pouring")
    return DemoSet(d.t[:3], d.x[:3], name="robottasks:pouring[:3]", q=d.q[:3])


@pytest.fixture(scope="module")
def experiment(pouring: DemoSet) -> tuple[Experiment, lfd.VelocityField]:
    return Experiment(load_robot("panda", actuation="torque"), pouring), lfd.train("tracking", pouring)


def test_tracking_on_the_panda_where_recorded(experiment) -> None:
    exp, field = experiment
    assert exp.placement.pose and np.array_equal(exp.placement.origin, np.zeros(3))      # no placement, no scale
    r = exp.run(field, "none")
    m = r.metrics
    assert m["tracking_rmse_m"] <= 2e-3 and m["tracking_rmse_deg"] <= 1.0
    assert m["final_goal_error_m"] <= 2e-3 and m["final_goal_error_deg"] <= 1.0
    assert m["joint_limit_violations"] == 0
    # the tool really turns: the recorded pour turns the hand by more than 60 degrees
    from lfd.pose import geodesic_angle

    assert float(np.degrees(geodesic_angle(r.trace.ee_rot[0], r.trace.ee_rot[-1]))) > 60.0
    assert 0.0 < m["imitation_orientation_error_deg"] < 20.0
    push = exp.run(field, "push")
    assert push.metrics["recovery_time_s"] is not None and push.metrics["recovery_time_s"] <= 0.5
    assert push.metrics["max_deviation_m"] > 2e-3                                      # the push did push


def test_turned_start_and_goal_are_reached(experiment) -> None:
    exp, field = experiment
    from lfd.pose import geodesic_angle

    off = exp.run(field, "offset", (StartOffset(distance_m=0.05, angle_deg=30.0, seed=3),))
    start_rot = exp.placement.rotation_to_world(exp.task_demos.x[0, 0])
    assert abs(float(np.degrees(geodesic_angle(off.trace.ee_rot[0], start_rot))) - 30.0) < 0.5
    assert abs(float(np.linalg.norm(off.trace.ee[0] - exp.setup.demo_world[0])) - 0.05) < 1e-3
    assert off.metrics["final_goal_error_m"] <= 1e-3 and off.metrics["final_goal_error_deg"] <= 1.0
    goal = exp.run(field, "goal", (GoalShift(distance_m=0.02, angle_deg=15.0, seed=4),))
    nominal = exp.placement.rotation_to_world(np.asarray(field.goal))
    reached = goal.trace.ee_rot[-1]
    assert abs(float(np.degrees(geodesic_angle(nominal, reached))) - 15.0) < 1.0          # the goal turned
    assert goal.metrics["final_goal_error_deg"] <= 1.0 and goal.metrics["final_goal_error_m"] <= 2e-3


def test_pose_job_writes_orientation_metrics_and_video(tmp_path) -> None:
    import imageio_ffmpeg

    demos = tmp_path / "pouring.npz"
    d = robottasks("pouring")
    lfd.demos.save_file(DemoSet(d.t[:2, ::4] / 3, d.x[:2, ::4], q=d.q[:2, ::4]), demos)   # a faster pour
    out = tmp_path / "out"
    job = ArmJob(demos=str(demos), learners=("tracking",), scenarios=("none",), out=str(out), quiet=True,
                 size=(320, 240))
    rep = run_job(job)
    m = json.loads((out / "metrics.json").read_text())["runs"][0]["metrics"]
    for key in ("final_goal_error_deg", "tracking_rmse_deg", "imitation_orientation_error_deg"):
        assert np.isfinite(m[key])
    assert rep.n_videos == 1
    video = next(out.glob("*.mp4"))
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8).reshape(meta["size"][1], meta["size"][0], 3) for f in reader]
    # the live tool frame: pure red, green and blue axis pixels are drawn in every frame
    for f in (frames[0], frames[-1]):
        assert np.count_nonzero((f[..., 0] > 180) & (f[..., 1] < 80) & (f[..., 2] < 80)) > 5
        assert np.count_nonzero((f[..., 2] > 180) & (f[..., 0] < 90) & (f[..., 1] < 130)) > 5


def test_dm_env_steps_a_pose_field(pouring: DemoSet) -> None:
    import sim

    auto = lfd.train("contraction", pouring, iterations=5)
    env = sim.make_environment("panda", demos=pouring, learner_field=auto, duration_s=1.0)
    ts = env.reset()
    assert ts.observation["task_position"].shape == (6,) and ts.observation["field_velocity"].shape == (6,)
    z0 = ts.observation["task_position"].copy()
    for _ in range(250):
        v = ts.observation["field_velocity"]
        ts = env.step(v)
    # the arm moved the way the field points, turning included (not only the position part)
    moved = ts.observation["task_position"] - z0
    assert float(np.linalg.norm(moved[3:])) > 1e-3
    predicted = auto.rollout(z0[None], np.linspace(0.0, 0.5, 51))[0, -1] - z0
    cos = float(np.dot(moved[3:], predicted[3:])) / float(np.linalg.norm(moved[3:]) * np.linalg.norm(predicted[3:]))
    assert cos > 0.9
