"""Opening a box's lid (``sim.scene.lid``, ``--task lid``): the hinge fitted to the demos, the handle the
hand holds, the predicate read from the physics state, and the learned opening on the Panda."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

import lfd
import sim
from lfd.errors import ConfigError
from lfd.rotations import quaternion_matrices
from robots import load_robot, solve_pose_ik
from sim.run.tasks import plan_lid
from sim.scene import lid


def test_the_hinge_is_fitted_to_a_swing_far_beyond_the_demos() -> None:
    """A tool path on a circle (radius 0.3 m, 100 deg, about an axis tilted 20 deg, with 1 mm of noise)
    gives back its hinge to 2 mm and its axis to 0.5 deg, oriented the way the path turns."""
    rng = np.random.default_rng(0)
    axis = np.array([np.cos(np.radians(20)), 0.0, np.sin(np.radians(20))])
    x = np.cross(axis, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    hinge = np.array([0.5, -0.3, 0.15])
    a = np.radians(np.linspace(0.0, 100.0, 300))
    path = hinge + 0.3 * (np.outer(np.cos(a), x) + np.outer(np.sin(a), y)) + rng.normal(0, 0.001, (300, 3))
    h, ax, r = lid.fit_hinge(path)
    assert np.linalg.norm(h - hinge) < 0.002 and abs(r - 0.3) < 0.002
    assert np.degrees(np.arccos(np.clip(ax @ axis, -1, 1))) < 0.5
    h2, ax2, _ = lid.fit_hinge(path[::-1])     # the other way round: the axis flips
    assert ax2 @ axis < -0.99 and np.linalg.norm(h2 - hinge) < 0.002


def test_the_handle_is_held_where_the_hand_is_and_the_predicate_reads_the_angle() -> None:
    """At the demos' start and end poses the lid and its handle are put at the hand (the grip satisfied),
    nearly closed and about 90 deg open; frames of a lid left closed are 'not opened', of a handle slid
    out of the hand 'lost the lid'."""
    demos = lfd.load_demos("robottasks:openbox")
    task = plan_lid(demos, None)
    robot = task.with_scene(load_robot("panda", actuation="torque", table=True))
    model = robot.mj_model

    frames = []
    for k, want in ((0, (0.0, 10.0)), (-1, (80.0, 100.0))):
        q, err, _ = solve_pose_ik(robot, demos.x[0, k], quaternion_matrices(demos.q[0, k]), q0=robot.q_home)
        assert err < 1e-3
        data = mujoco.MjData(model)
        data.qpos[robot.mj_qpos_adr] = q
        lid.hold_lid(model, data)
        mujoco.mj_forward(model, data)
        assert np.abs(data.efc_pos[:3]).max() < 1e-9                 # the grip holds the handle at the hand
        assert want[0] < lid.lid_angle_deg(model, data.qpos) < want[1]
        frames.append(data.qpos.copy())
    t = np.array([0.0, 1.0, 2.0])
    shut = np.array([frames[0]] * 3)
    assert lid.outcome(model, t, shut, 1.0)["cause"] == "not opened"
    out = lid.outcome(model, t, np.array([frames[0], frames[1], frames[1]]), 1.0)
    assert out["success"] and out["angle_deg"] > lid.OPEN_DEG and out["stretch_m"] < 1e-6
    slid = frames[1].copy()
    slid[int(model.joint("lid_handle_along").qposadr[0])] = lid.LidScene().slide
    out = lid.outcome(model, t, np.array([frames[0], slid, slid]), 1.0)
    assert out["cause"] == "lost the lid" and out["slid_out"]


def test_a_lid_task_refuses_what_it_cannot_do() -> None:
    with pytest.raises(ConfigError, match="box stays where it was recorded"):
        plan_lid(lfd.load_demos("robottasks:openbox"), (0.4, -0.4))
    with pytest.raises(ConfigError, match="needs demos of poses"):
        plan_lid(lfd.load_demos("spiral3d"), None)
    t = np.linspace(0.0, 2.0, 50)
    line = np.stack([np.column_stack([0.4 + 0 * t, -0.15 * t + 0.01 * k, 0.3 + 0.001 * t ** 2]) for k in range(3)])
    upright = np.tile([1.0, 0.0, 0.0, 0.0], (3, 50, 1))
    with pytest.raises(ConfigError, match="do not swing a lid open: they turn -?[0-9]+ deg"):   # a slide, no swing
        plan_lid(lfd.DemoSet(np.stack([t] * 3), line, q=upright, name="a slide"), None)



@pytest.mark.usefixtures("one_thread")
def test_the_learned_opening_swings_the_lid_open_pushed_or_not(tmp_path: Path) -> None:
    job = sim.ArmJob(robot="panda", learners=("tracking",), task="lid", scenarios=("none", "push"),
                     videos=False, plots=False, quiet=True, out=str(tmp_path))
    assert job.demo_spec == "robottasks:openbox"                  # a task's own demos by default
    runs = sim.run_job(job).results
    for r in runs:
        task = r.metrics["task"]
        assert task["success"] and task["angle_deg"] > 80 and task["stretch_m"] < 0.005, task
        assert r.metrics["final_goal_error_m"] < 1e-3
