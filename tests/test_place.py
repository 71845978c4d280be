"""A placement with real objects (``sim.scene.place``, ``--task place``): the bottle held by a weld that
the run's release opens, the success predicate read from the physics state, the held load fed forward,
and the learned placement on the Panda, its spot moved by ``--target``."""

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
from sim.run.tasks import plan_place, plan_task
from sim.scene import place


@pytest.fixture(scope="module")
def bottles() -> lfd.DemoSet:
    return lfd.load_demos("robottasks:bottle2shelf")


@pytest.fixture(scope="module")
def scene(bottles: lfd.DemoSet) -> tuple[object, mujoco.MjModel, np.ndarray, np.ndarray, np.ndarray]:
    """The robot in the scene, its model, the bottle's axis, the spot and the arm's qpos with the
    tool at the demos' mean end (the bottle upright above its spot)."""
    task = plan_place(bottles, None)
    robot = place.build(load_robot("panda", actuation="torque", table=True), task.axis, task.spot)
    q, err, _ = solve_pose_ik(robot, bottles.goal[:3], quaternion_matrices(bottles.goal_q), q0=robot.q_home)
    assert err < 1e-4
    qpos = robot.mj_model.qpos0.copy()
    qpos[robot.mj_qpos_adr] = q
    return robot, robot.mj_model, task.axis, task.spot, qpos


def test_the_bottle_is_real_held_at_the_tool_and_upright_at_the_demos_end(scene: tuple) -> None:
    robot, model, axis, spot, qpos = scene
    s = place.PlaceScene()
    assert model.body("place_bottle").mass[0] == pytest.approx(s.mass) and 0.2 <= s.mass <= 1.0
    assert 0.05 <= 2 * s.radius <= 0.09 and 0.15 <= s.body_height + s.neck_height <= 0.35
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    place.hold_bottle(robot, axis, model, data)
    mujoco.mj_forward(model, data)
    assert data.eq_active[model.equality(place.GRIP).id] == 1
    assert np.abs(data.efc_pos[:6]).max() < 1e-9          # the weld is satisfied where the bottle is put
    bottle = model.body("place_bottle").id
    assert data.xmat[bottle].reshape(3, 3)[2, 2] == pytest.approx(1.0, abs=1e-9)        # upright
    assert data.xpos[bottle] == pytest.approx(spot, abs=1e-9)                          # its bottom on the spot
    g = model.geom("place_shelf_board").id      # the shelf is an object: it never touches the arm's bit
    assert model.geom_contype[g] & 1 == 0 and model.geom_conaffinity[g] & 1 == 0
    top = model.geom_pos[g][2] + model.geom_size[g][2] + model.body("place_shelf").pos[2]
    assert top == pytest.approx(spot[2] - s.drop)


def _drop(model: mujoco.MjModel, robot: object, axis: np.ndarray, qpos: np.ndarray, turn_deg: float,
          shift: np.ndarray, seconds: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """The bottle let go at the arm's pose turned by ``turn_deg`` about x and moved by ``shift``,
    simulated ``seconds``: the recorded times and states (the arm's joints frozen at ``qpos``)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    place.hold_bottle(robot, axis, model, data)   # type: ignore[arg-type]
    a = int(model.joint("place_bottle").qposadr[0])
    data.qpos[a:a + 3] += shift
    turn = np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, np.array([1.0, 0.0, 0.0]), np.radians(turn_deg))
    mujoco.mju_mulQuat(data.qpos[a + 3:a + 7], turn, data.qpos[a + 3:a + 7].copy())
    data.eq_active[:] = 0
    ts, states = [], []
    for k in range(int(seconds / model.opt.timestep)):
        data.qpos[robot.mj_qpos_adr] = qpos[robot.mj_qpos_adr]   # type: ignore[attr-defined]
        data.qvel[:7] = 0.0
        mujoco.mj_step(model, data)
        if k % 10 == 0:
            ts.append(data.time)
            states.append(data.qpos.copy())
    return np.array(ts), np.array(states)


def test_a_bottle_let_go_above_its_spot_stands_and_each_failure_is_named(scene: tuple) -> None:
    """Physics, not bookkeeping: let go 5 mm above its spot the bottle lands and stands; turned by 40
    deg it falls over ('toppled'); 4 cm aside it stands off its spot ('missed the spot'); a bottle
    knocked out of the hand before the release is a 'collision'."""
    robot, model, axis, spot, qpos = scene
    t, states = _drop(model, robot, axis, qpos, 0.0, np.zeros(3))
    out = place.outcome(model, robot, t, states, 0.0, axis, spot)
    assert out["success"] and out["on_shelf"] and out["tilt_deg"] < 1.0 and out["off_spot_m"] < 0.005, out
    t, states = _drop(model, robot, axis, qpos, 40.0, np.zeros(3))
    out = place.outcome(model, robot, t, states, 0.0, axis, spot)
    assert (out["success"], out["cause"]) == (False, "toppled") and out["tilt_deg"] > 45, out
    t, states = _drop(model, robot, axis, qpos, 0.0, np.array([0.04, 0.0, 0.0]))
    out = place.outcome(model, robot, t, states, 0.0, axis, spot)
    assert (out["cause"], out["on_shelf"]) == ("missed the spot", True) and out["off_spot_m"] == pytest.approx(
        0.04, abs=0.005), out
    out = place.outcome(model, robot, t, states, 0.5, axis, spot)   # released only at 0.5 s: it moved in the hand
    assert out["cause"] == "collision" and out["slip_m"] > place.SLIP_M, out
    held = np.repeat(qpos[None], 3, axis=0)      # the bottle never let go: it hangs above the shelf
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    place.hold_bottle(robot, axis, model, data)
    held[:] = data.qpos
    out = place.outcome(model, robot, np.array([0.0, 1.0, 2.0]), held, 0.5, axis, spot)
    assert (out["cause"], out["on_shelf"], out["tilt_deg"]) == ("not released", False, pytest.approx(0.0, abs=1e-6))


def test_a_placement_refuses_what_it_cannot_do(bottles: lfd.DemoSet) -> None:
    with pytest.raises(ConfigError, match="needs demos of poses"):
        plan_place(lfd.load_demos("spiral"), None)
    with pytest.raises(ConfigError, match="inside the arm's base"):
        plan_place(bottles, (0.05, 0.0))
    with pytest.raises(ConfigError, match="shelf's top at -0.100 m"):
        plan_place(bottles, (0.4, -0.4, -0.1))
    with pytest.raises(ConfigError, match="shelf's top at 1.500 m"):
        plan_place(bottles, (0.4, -0.4, 1.5))
    with pytest.raises(ConfigError, match="unknown task 'jar'"):
        plan_task("jar", bottles, None)
    moved = plan_place(bottles, (0.42, -0.40, 0.2))   # the goal follows the spot, in 3-D
    assert moved.goal - moved.spot == pytest.approx(plan_place(bottles, None).goal - moved.nominal)
    assert moved.spot[2] == pytest.approx(0.2 + place.PlaceScene().drop)


@pytest.mark.usefixtures("one_thread")
def test_the_learned_placement_stands_the_bottle_on_its_moved_spot_and_carries_it_tracked(tmp_path: Path) -> None:
    """The tracking learner's placement on the Panda from the RoboTasks9 demos (the job's default demos
    for the task), its spot moved 3 cm by --target and pushed mid-motion: the bottle stands on its
    spot, and the tool carried its 0.45 kg within 2 mm and 1 deg (the load fed forward)."""
    job = sim.ArmJob(robot="panda", demos="robottasks:bottle2shelf", learners=("tracking",), task="place",
                     target=(0.40, -0.41), scenarios=("none", "push"), videos=False, plots=False, quiet=True,
                     out=str(tmp_path))
    runs = sim.run_job(job).results
    assert len(runs) == 2
    page = (tmp_path / "index.html").read_text()     # the page says the task's success first
    assert page.index("place: 2 of 2 runs succeeded") < page.index("Every run: headline metrics")
    for r in runs:
        task = r.metrics["task"]
        assert task["success"] and task["task"] == "place" and (task["in_target"], task["total"]) == (1, 1), task
        assert task["spot_m"][:2] == pytest.approx([0.40, -0.41]) and task["off_spot_m"] < place.SPOT_M
        assert r.metrics["tracking_rmse_m"] < 0.002 and r.metrics["tracking_rmse_deg"] < 1.0


@pytest.mark.usefixtures("one_thread")
def test_the_task_benchmark_runs_in_parallel_and_gives_the_same_records_on_ray(tmp_path: Path) -> None:
    """Two seeded placement episodes on a pool of two workers, then the same on Ray: the same outcomes
    and the same measured numbers; the report and the page count them, and the page shows the video
    of a success (no failure to film)."""
    from sim.studies import task_bench

    args = ["--task", "place", "--episodes", "2", "--learners", "tracking", "--split", "in-sample", "--workers", "2"]
    assert task_bench.main([*args, "--out", str(tmp_path / "local"), "--report", str(tmp_path / "local.md")]) == 0
    local = [json.loads((tmp_path / "local" / "tracking" / f"{k}.json").read_text()) for k in range(2)]
    assert [r["episode"] for r in local] == [0, 1] and [r["pushed"] for r in local] == [False, True]
    assert "| in-sample | tracking | all | 2 / 2 |" in (tmp_path / "local.md").read_text()
    page = (tmp_path / "local" / "index.html").read_text()      # the page, success first, and its one video
    assert page.index("in-sample: tracking 2 of 2") < page.index("tracking_in_sample_0.mp4")
    assert (tmp_path / "local" / "videos" / "tracking_in_sample_0.mp4").stat().st_size > 10_000
    pytest.importorskip("ray")
    assert task_bench.main([*args, "--no-videos", "--executor", "ray", "--out", str(tmp_path / "ray"),
                            "--report", str(tmp_path / "ray.md")]) == 0
    for k, rec in enumerate(local):
        other = json.loads((tmp_path / "ray" / "tracking" / f"{k}.json").read_text())
        assert (other["success"], other["cause"], other["target_m"]) == (rec["success"], rec["cause"], rec["target_m"])
        assert other["off_spot_m"] == pytest.approx(rec["off_spot_m"], abs=1e-9)
        assert other["goal_error_m"] == pytest.approx(rec["goal_error_m"], abs=1e-9)


def test_the_release_and_the_judging_follow_the_run_at_its_speed(tmp_path: Path) -> None:
    """At --speed 2 the grip opens when the faster motion ends (half the demos' time), within the run."""
    from sim.run.plan import plan_job

    base = dict(demos="robottasks:bottle2shelf", learners=("tracking",), task="place", scenarios=("none",),
                videos=False, plots=False, quiet=True, out=str(tmp_path))
    plan = plan_job(sim.ArmJob(speed=2.0, **base))   # type: ignore[arg-type]
    assert plan.task is not None and plan.task.motion_end_s == pytest.approx(16.65 / 2, abs=0.02)
    (release,) = plan.exp.events
    assert release.start_s == pytest.approx(plan.task.motion_end_s) and release.start_s < plan.exp.duration_s - 1
    run = sim.run_job(sim.ArmJob(speed=2.0, **base)).results[0]   # type: ignore[arg-type]
    assert run.metrics["task"]["success"], run.metrics["task"]
