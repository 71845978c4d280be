"""A pour with real objects (``sim.scene.pour``, ``--task pour``): the scene's sizes, the success
predicate read from the physics state, and the learned pour on the Panda, its bowl moved by ``--target``."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

import lfd
import sim
from lfd.errors import ConfigError
from lfd.rotations import quaternion_matrices
from robots import load_robot, solve_pose_ik
from sim.run.tasks import plan_pour
from sim.scene import pour


@pytest.fixture(scope="module")
def pouring() -> lfd.DemoSet:
    return lfd.load_demos("robottasks:pouring")


@pytest.fixture(scope="module")
def scene_model(pouring: lfd.DemoSet) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """The scene, the cup's axis and the arm's qpos with the tool at the demos' start (the cup upright)."""
    task = plan_pour(pouring, None)
    robot = pour.build(load_robot("panda", actuation="torque", table=True), task.axis, task.bowl)
    q, _, _ = solve_pose_ik(robot, pouring.x[0, 0], quaternion_matrices(pouring.q[0, 0]), q0=robot.q_home)
    qpos = robot.mj_model.qpos0.copy()
    qpos[robot.mj_qpos_adr] = q
    return robot.mj_model, task.axis, qpos


def test_the_objects_have_real_sizes_and_masses(scene_model: tuple[mujoco.MjModel, np.ndarray, np.ndarray]) -> None:
    model, _, _ = scene_model
    s = pour.PourScene()
    assert 2 * (s.cup_radius + s.wall) <= 0.08 and 2 * (s.bowl_radius + s.wall) <= 0.15   # openings, m
    balls = [model.body(f"pour_ball{i}") for i in range(12)]
    assert all(float(b.mass[0]) == pytest.approx(0.01) for b in balls)
    radii = {float(model.geom_size[int(model.body_geomadr[b.id]), 0]) for b in balls}
    assert radii == {0.01}
    assert model.body("pour_cup").mass[0] == pytest.approx(0.1)
    # the objects collide among themselves, never with the arm's collision bit
    for name in ("pour_cup_bottom", "pour_bowl_bottom", "pour_table"):
        g = model.geom(name).id
        assert model.geom_contype[g] & 1 == 0 and model.geom_conaffinity[g] & 1 == 0


def _frames(model: mujoco.MjModel, qpos: np.ndarray, balls_at: list[list[np.ndarray]]) -> np.ndarray:
    """Full states: the arm as in ``qpos``, the balls where given."""
    data = mujoco.MjData(model)
    frames = []
    for balls in balls_at:
        data.qpos[:] = qpos
        for i, p in enumerate(balls):
            a = int(model.joint(f"pour_ball{i}").qposadr[0])
            data.qpos[a:a + 3] = p
            data.qpos[a + 3:a + 7] = (1, 0, 0, 0)
        frames.append(data.qpos.copy())
    return np.array(frames)


def test_the_predicate_counts_the_balls_in_the_bowl_and_names_each_failure(
        scene_model: tuple[mujoco.MjModel, np.ndarray, np.ndarray]) -> None:
    """With the cup held upright at the demos' start it never tilts past the pour: balls that stay in
    the cup are 'not poured'; balls out of the cup before any pour are 'spilled early', in the bowl or not."""
    model, axis, qpos = scene_model
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    pour.place_balls(model, data)
    assert pour.tilt_deg(data.xmat[model.body("pour_cup").id].reshape(3, 3), np.array([0.0, 0.0, 1.0])) < 10
    in_cup = [data.qpos[int(model.joint(f"pour_ball{i}").qposadr[0]):][:3].copy() for i in range(12)]
    bowl = model.body("pour_bowl").pos.copy()
    in_bowl = [bowl + [0.03 * np.cos(k), 0.03 * np.sin(k), 0.02] for k in range(12)]
    t = np.array([0.0, 1.0, 2.0])
    out = pour.outcome(model, t, _frames(model, qpos, [in_cup] * 3), 1.0, axis)
    assert (out["cause"], out["in_cup_before_pour"], out["in_bowl"], out["poured_at_s"]) == ("not poured", 12, 0, None)
    out = pour.outcome(model, t, _frames(model, qpos, [in_bowl] * 3), 1.0, axis)
    assert (out["cause"], out["in_bowl"], out["success"]) == ("spilled early", 12, False)


@pytest.mark.usefixtures("one_thread")
def test_the_learned_pour_pours_and_follows_its_bowl(tmp_path: Path) -> None:
    """The tracking learner's pour, from the RoboTasks9 demos, unperturbed at the nominal bowl and
    with its bowl moved 5 cm by --target: at least 10 of 12 balls in the bowl, none spilled before
    the pour, and the tool tracked within 2 mm and 1 deg while it carries the cup and the balls."""
    base = dict(robot="panda", demos="robottasks:pouring", learners=("tracking",), task="pour", videos=False,
                plots=False, quiet=True)
    runs = sim.run_job(sim.ArmJob(out=str(tmp_path / "a"), scenarios=("none",), **base)).results   # type: ignore[arg-type]
    moved = sim.run_job(sim.ArmJob(out=str(tmp_path / "b"), scenarios=("none",), target=(0.40, -0.45),
                                   **base)).results   # type: ignore[arg-type]
    for r in (*runs, *moved):
        task = r.metrics["task"]
        assert task["success"] and task["in_bowl"] >= 10 and task["in_cup_before_pour"] == 12, task
        assert r.metrics["tracking_rmse_m"] < 0.002 and r.metrics["tracking_rmse_deg"] < 1.0
    assert moved[0].metrics["task"]["bowl_m"][:2] == pytest.approx([0.40, -0.45])


def test_a_pour_refuses_what_it_cannot_do(pouring: lfd.DemoSet) -> None:
    with pytest.raises(ConfigError, match="needs demos of poses"):
        plan_pour(lfd.load_demos("spiral"), None)
    with pytest.raises(ConfigError, match="inside the arm's base"):
        plan_pour(pouring, (0.05, 0.0))
    with pytest.raises(ConfigError, match="stands on the table"):
        plan_pour(pouring, (0.4, -0.4, 0.2))
    still = lfd.DemoSet(t=pouring.t, x=pouring.x, q=np.repeat(pouring.q[:, :1], pouring.q.shape[1], axis=1),
                        name="held upright")
    with pytest.raises(ConfigError, match="do not pour"):
        plan_pour(still, None)


def test_the_wilson_interval_and_a_resumed_benchmark(tmp_path: Path) -> None:
    """Wilson's interval against its closed form at k = 0, n and a value from the literature
    (8 of 10: [0.490, 0.943]); the benchmark reads back the episodes on file instead of running them."""
    from sim.studies import task_bench

    assert task_bench.wilson(0, 10)[0] == 0.0 and task_bench.wilson(10, 10)[1] == 1.0
    lo, hi = task_bench.wilson(8, 10)
    assert lo == pytest.approx(0.490, abs=1e-3) and hi == pytest.approx(0.943, abs=1e-3)
    (tmp_path / "runs" / "tracking").mkdir(parents=True)
    for k, rec in enumerate(({"pushed": False, "success": True, "cause": None, "in_bowl": 11},
                             {"pushed": True, "success": False, "cause": "missed the bowl", "in_bowl": 3})):
        # two episodes on file, one failed: nothing runs, the report counts them
        (tmp_path / "runs" / "tracking" / f"{k}.json").write_text(json.dumps(
            {"learner": "tracking", "episode": k, "target_m": [0.4, -0.3], "held_out": None, "goal_error_m": 0.001,
             **rec}))
    code = task_bench.main(["--episodes", "2", "--learners", "tracking", "--split", "in-sample", "--no-videos",
                            "--out", str(tmp_path / "runs"), "--report", str(tmp_path / "pour.md")])
    text = (tmp_path / "pour.md").read_text()
    assert code == 0 and "| in-sample | tracking | all | 1 / 2 |" in text and "missed the bowl 1" in text
    page = (tmp_path / "runs" / "index.html").read_text()
    assert "tracking, in-sample episode 1 (object at 0.400, -0.300 m; pushed): missed the bowl; 3 of 12 balls" in page


def test_a_held_out_job_trains_without_its_demo_and_starts_where_it_started(tmp_path: Path,
                                                                              pouring: lfd.DemoSet) -> None:
    """``--held-out 3``: the field is trained on the other eight demos (its chart is theirs), and the
    run starts at demo 3's recorded start pose."""
    from sim.run.plan import plan_job

    plan = plan_job(sim.ArmJob(demos="robottasks:pouring", learners=("tracking",), held_out=3, task="pour",
                               scenarios=("none",), videos=False, plots=False, quiet=True, out=str(tmp_path)))
    eight = pouring.subset([i for i in range(9) if i != 3])
    assert plan.fields["tracking"].chart.goal_rotation == pytest.approx(
        lfd.pose.PoseChart.of(eight).goal_rotation)
    start = plan.exp.placement.to_world(plan.exp.start[None])[0]
    assert start == pytest.approx(pouring.x[3, 0], abs=1e-9)
