"""Obstacles in the MuJoCo scene (sim.obstacles): geoms where the task says, contacts counted."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import lfd
from lfd.errors import ConfigError
from lfd.obstacles import Obstacle
from robots import load_robot
from robots.kinematics import Kinematics
from sim.obstacles import obstacle_contacts, obstacle_geom_ids, with_obstacles
from sim.placement import Placement


@pytest.fixture(scope="module")
def planar():
    return load_robot("planar", actuation="torque")


@pytest.fixture(scope="module")
def placed(planar):
    demos = lfd.spiral()
    return Placement.auto(planar, demos.x), demos


def _tool_path(robot, q: np.ndarray) -> np.ndarray:
    kin = Kinematics(robot)
    out = []
    for qk in q:
        kin.update(qk)
        out.append(kin.ee_position().copy())
    return np.array(out)


def test_geoms_are_placed_and_sized_from_task_units(planar, placed) -> None:
    placement, _ = placed
    obstacles = [Obstacle.sphere([0.2, -0.1], 0.15), Obstacle.box([-0.5, 0.4], [0.1, 0.2]),
                 Obstacle.capsule([0.5, 0.5], [0.7, 0.6], 0.05)]
    robot = with_obstacles(planar, obstacles, placement)
    ids = obstacle_geom_ids(robot.mj_model)
    assert len(ids) == 3 and robot.n == planar.n
    np.testing.assert_array_equal(robot.mj_qpos_adr, planar.mj_qpos_adr)
    data = mujoco.MjData(robot.mj_model)
    mujoco.mj_kinematics(robot.mj_model, data)
    s = placement.scale
    np.testing.assert_allclose(data.geom_xpos[ids[0]], placement.to_world([0.2, -0.1]), atol=1e-9)
    np.testing.assert_allclose(robot.mj_model.geom_size[ids[0], 0], 0.15 * s, rtol=1e-9)
    np.testing.assert_allclose(np.sort(robot.mj_model.geom_size[ids[1]]), np.sort([0.1 * s, 0.2 * s, 0.1 * s]),
                               rtol=1e-9)
    np.testing.assert_allclose(robot.mj_model.geom_size[ids[2], 0], 0.05 * s, rtol=1e-9)
    np.testing.assert_allclose(data.geom_xpos[ids[2]], placement.to_world([0.6, 0.55]), atol=1e-9)
    assert planar.mj_model.ngeom == robot.mj_model.ngeom - 3     # the input robot is unchanged
    with pytest.raises(ConfigError, match="3-D"):
        with_obstacles(planar, [Obstacle.sphere([0, 0, 0], 0.1)], placement)


def test_contacts_are_counted_where_the_tool_enters_and_clearance_elsewhere(planar, placed) -> None:
    placement, _ = placed
    q_home = np.asarray(planar.q_home)
    q = q_home + np.linspace(0, 0.3, 40)[:, None] * np.array([1.0, -0.5, 0.2])   # (40, 3)
    tool = placement.to_task(_tool_path(planar, q))                              # (40, 2)
    on_path = Obstacle.sphere(tool[20], 0.1)
    robot = with_obstacles(planar, [on_path], placement)
    t = np.arange(len(q)) * 0.01
    report = obstacle_contacts(robot, q, t)
    assert report.contacts > 0 and report.steps_in_contact >= 1
    assert report.first_contact_s is not None and report.first_contact_s <= t[20]
    assert report.min_clearance_m < 0 and report.pairs and all("obstacle_0" in p for p in report.pairs)

    far = Obstacle.sphere(tool[0] + np.array([5.0, 5.0]), 0.1)
    clear = obstacle_contacts(with_obstacles(planar, [far], placement), q, t)
    assert clear.contacts == 0 and clear.first_contact_s is None and clear.min_clearance_m > 0.01
    assert clear.to_dict()["pairs"] == []
    with pytest.raises(ConfigError, match="shape"):
        obstacle_contacts(robot, q[:, :2])


def test_demo_arm_obstacle_flag_reports_contacts_and_rejects_a_goal_inside(tmp_path, monkeypatch, capsys) -> None:
    import json
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import demo_arm
    from conftest import sink_field

    model = tmp_path / "sink.pt"
    sink_field(lfd.spiral(n_demos=2, n_samples=60, duration=1.0)).save(model)
    monkeypatch.setattr(lfd, "load", lambda path: sink_field(lfd.load_demos("spiral")))
    out = tmp_path / "out"
    base = ["--robot", "planar", "--model", str(model), "--perturb", "none", "--no-video", "--no-plots", "--quiet"]
    rc = demo_arm.main([*base, "--out", str(out), "--obstacle", "sphere:3,3,0.1"])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())["runs"][0]["metrics"]
    assert metrics["obstacle_contacts"] == 0 and metrics["obstacle_min_clearance_m"] > 0.01
    capsys.readouterr()
    bad = tmp_path / "bad"
    rc = demo_arm.main([*base, "--out", str(bad), "--obstacle", "sphere:0,0,0.3"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "goal lies inside" in err and len(err.splitlines()) == 1 and not bad.exists()
