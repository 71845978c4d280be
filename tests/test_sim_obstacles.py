"""Obstacles in the MuJoCo scene (sim.scene.obstacles), the contacts counted; a goal that moves mid-run."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import lfd
from lfd.errors import ConfigError
from lfd.obstacles import Obstacle
from robots import load_robot
from robots.kinematics import Kinematics
from sim.scene.obstacles import obstacle_contacts, obstacle_geom_ids, with_obstacles
from sim.scene.placement import Placement


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


@pytest.fixture
def demo_arm_sink(tmp_path, monkeypatch):
    """The arm job's command line (``sim.run.cli``, behind scripts/demo_arm.py) and the flags of a quick
    planar run of a sink field (no training)."""
    from known_fields import sink_field

    from sim.run import cli as demo_arm

    model = tmp_path / "sink.pt"
    sink_field(lfd.spiral(n_demos=2, n_samples=60, duration=1.0)).save(model)
    monkeypatch.setattr(lfd, "load", lambda path: sink_field(lfd.load_demos("spiral")))
    return demo_arm, ["--robot", "planar", "--model", str(model), "--perturb", "none", "--no-video", "--no-plots",
                      "--quiet"]


def test_demo_arm_obstacle_flag_reports_contacts_and_rejects_a_goal_inside(tmp_path, demo_arm_sink, capsys) -> None:
    import json

    demo_arm, base = demo_arm_sink
    out = tmp_path / "out"
    rc = demo_arm.main([*base, "--out", str(out), "--obstacle", "sphere:3,3,0.1"])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())["runs"][0]["metrics"]
    assert metrics["obstacle_contacts"] == 0 and metrics["obstacle_min_clearance_m"] > 0.01
    away = tmp_path / "away"   # the same sphere moving away from the arm: the scene moves it, so more clearance
    assert demo_arm.main([*base, "--out", str(away), "--obstacle", "sphere:3,3,0.1;velocity=0.3,0.3"]) == 0
    moving = json.loads((away / "metrics.json").read_text())["runs"][0]["metrics"]
    assert moving["obstacle_contacts"] == 0
    assert moving["obstacle_min_clearance_m"] > metrics["obstacle_min_clearance_m"] + 0.005, (moving, metrics)
    capsys.readouterr()
    bad = tmp_path / "bad"
    rc = demo_arm.main([*base, "--out", str(bad), "--obstacle", "sphere:0,0,0.3"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "goal lies inside" in err and len(err.splitlines()) == 1 and not bad.exists()


# ---- a goal that moves during the run (lfd.goal on the arm: the loop passes t to a time-varying field)

@pytest.fixture(scope="module")
def panda_goal_runs():
    """The Panda on the spiral with a sink field: unshifted, and with the goal moved by 20% of the
    demos' extent at t = 1 s (blended over 0.5 s)."""
    from known_fields import sink_field

    import sim
    from lfd.goal import shift_goal

    demos = lfd.spiral()
    field = sink_field(demos)
    extent = demos.extent
    dx = 0.2 * extent * np.array([0.6, -0.8])
    moved = shift_goal(field, 1.0, dx, blend=0.5)
    exp = sim.Experiment(load_robot("panda"), demos)
    return exp, field, moved, dx, exp.run(field, "none"), exp.run(moved, "none")


def test_goal_moved_mid_run_is_reached_on_the_panda_without_a_speed_spike(panda_goal_runs) -> None:
    exp, field, moved, dx, plain, shifted = panda_goal_runs
    ro, t = shifted.trace, shifted.trace.t
    scale = exp.placement.scale
    new_goal = exp.placement.to_world(field.goal + dx)
    np.testing.assert_allclose(ro.goal_world, new_goal, atol=1e-12)            # scored against the moved goal
    assert shifted.metrics["final_goal_error_m"] <= 5e-3
    assert np.linalg.norm(ro.ee[-1] - plain.trace.goal_world) > 0.5 * np.linalg.norm(dx) * scale
    before = t < 1.0                                                            # the run is the plain one until t = 1 s
    assert np.max(np.linalg.norm(ro.ee[before] - plain.trace.ee[before], axis=1)) < 1e-9
    assert np.max(np.linalg.norm(ro.ee[t > 1.2] - plain.trace.ee[t > 1.2], axis=1)) > 0.01
    robot = exp.robot
    peak = np.max(np.abs(ro.qdot) / robot.v_max)
    assert peak < 1.0 and ro.joint_limit_violations == 0
    # no spike: the blended shift changes the command by no more than the plain run does per step
    jump = np.max(np.linalg.norm(np.diff(ro.command, axis=0), axis=1))
    jump_plain = np.max(np.linalg.norm(np.diff(plain.trace.command, axis=0), axis=1))
    assert jump <= 2.0 * jump_plain


def test_the_loop_feeds_a_time_varying_field_its_time(panda_goal_runs) -> None:
    exp, _, moved, _, _, shifted = panda_goal_runs
    ro = shifted.trace
    np.testing.assert_allclose(exp.command(moved, ro), ro.command, rtol=1e-9, atol=1e-12)
    # the reference is the time-varying field's own rollout: the robot tracks it as closely as the plain run
    err = np.linalg.norm(ro.ee - shifted.reference, axis=1)
    assert err[-1] < 5e-3 and shifted.metrics["tracking_rmse_m"] < 2.0 * max(panda_goal_runs[4].metrics[
        "tracking_rmse_m"], 1e-3)


def test_the_moving_goal_is_recorded_and_drawn_where_it_is(panda_goal_runs, tmp_path) -> None:
    """RunResult.goal_path follows the shift (the plain run has none), and the video draws the goal
    where it is: its dot moves between the first and the last frame, and stays put without a shift."""
    import imageio_ffmpeg

    exp, field, _, _, plain, shifted = panda_goal_runs
    assert plain.goal_path is None
    path, t = shifted.goal_path, shifted.trace.t
    assert path is not None and path.shape == (len(t), 3)
    np.testing.assert_allclose(path[t < 1.0], np.broadcast_to(exp.placement.to_world(field.goal), path[t < 1.0].shape),
                               atol=1e-12)
    np.testing.assert_allclose(path[-1], shifted.trace.goal_world, atol=1e-12)

    def goal_centroids(result, name: str) -> np.ndarray:     # (2 frames, 2): goal-coloured pixels, legend excluded
        video = tmp_path / name
        exp.render(result, video, width=640, height=480, fps=10)
        reader = imageio_ffmpeg.read_frames(str(video))
        meta = next(reader)
        w, h = meta["size"]
        frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader]
        out = []
        for img in (frames[0], frames[-1]):
            r, g, b = (img[..., i].astype(int) for i in range(3))
            mask = (r > 200) & (g > 160) & (b < 90)          # the goal's gold (sim.media.overlay.GOAL_RGB)
            mask[:h // 3, :w // 3] = False                                     # the legend's goal dot
            v, u = np.nonzero(mask)
            assert len(u) > 5, "no goal dot in the frame"
            out.append([u.mean(), v.mean()])
        return np.array(out)

    moved = goal_centroids(shifted, "moving.mp4")
    still = goal_centroids(plain, "still.mp4")
    assert np.linalg.norm(moved[1] - moved[0]) > 5.0          # pixels: the dot went with the goal
    assert np.linalg.norm(still[1] - still[0]) < 1.0


def test_demo_arm_goal_shift_flag(tmp_path, demo_arm_sink, capsys) -> None:
    import json

    demo_arm, base = demo_arm_sink
    out = tmp_path / "out"
    assert demo_arm.main([*base, "--out", str(out), "--goal-shift", "1.5:0.3,-0.2"]) == 0
    report = json.loads((out / "metrics.json").read_text())
    assert report["settings"]["goal_motion"] == {"shift": "1.5:0.3,-0.2", "blend_s": 0.5}
    assert report["runs"][0]["metrics"]["final_goal_error_m"] < 5e-3
    capsys.readouterr()
    for flag, message in (("1.5:0.3", "bad goal shift"), ("99:0.3,0.2", "after the run ends"),
                          ("1:80,0", "leaves the arm's reach")):
        bad = tmp_path / "bad"
        rc = demo_arm.main([*base, "--out", str(bad), "--goal-shift", flag])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and message in err and len(err.splitlines()) == 1 and not bad.exists(), err
    # a shifted goal inside an obstacle is refused before any run, as the demos' own goal is
    rc = demo_arm.main([*base, "--out", str(bad), "--goal-shift", "1.5:0.3,-0.2", "--obstacle", "sphere:0.3,-0.2,0.1"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "moving goal comes inside" in err and len(err.splitlines()) == 1 and not bad.exists(), err


def test_moving_obstacle_moves_in_the_scene_and_is_avoided_on_the_panda() -> None:
    """A sphere (with a hand clearance) sweeps across the Panda's path at 1.2 units/s: the scene moves
    it (a mocap body), the avoiding field never lets the arm touch it, the bare field runs into it
    unless the whole-arm dampers hold the arm back, and a replay that froze the sphere at t = 0
    would count other contacts than those that happened."""
    from known_fields import sink_field

    import sim
    from lfd.obstacles import avoid

    demos = lfd.spiral()
    field = sink_field(demos)
    crossing = field.rollout(demos.x[0, 0], np.linspace(0.0, 0.5, 51))[-1]   # on the path at t = 0.5 s
    mover = Obstacle.sphere(crossing - np.array([0.6, 0.0]), 0.12, velocity=[1.2, 0.0], margin=0.3)
    exp = sim.Experiment(load_robot("panda"), demos, obstacles=[mover], clearance=None)   # the tool point only
    safe = exp.run(avoid(field, [mover]), "none").trace
    bare = exp.run(field, "none").trace
    guarded = sim.Experiment(load_robot("panda"), demos, obstacles=[mover])   # whole-arm dampers, the default
    held = guarded.run(field, "none").trace                                   # stop the bare field's arm short of it
    assert obstacle_contacts(guarded.robot, held.q, held.t, held.mocap_pos).contacts == 0
    assert safe.mocap_pos is not None and safe.mocap_pos.shape == (len(safe.t), 1, 3)
    shift = exp.placement.scale * exp.placement.axes @ np.array([1.2, 0.0])             # m per s
    np.testing.assert_allclose(safe.mocap_pos[:, 0], safe.t[:, None] * shift[None], atol=1e-12)
    assert safe.frame_mocap is not None and safe.frame_mocap.shape == (len(safe.frame_t), 1, 3)
    moving = obstacle_contacts(exp.robot, safe.q, safe.t, safe.mocap_pos)
    assert moving.contacts == 0 and moving.min_clearance_m > 0.002
    hits = obstacle_contacts(exp.robot, bare.q, bare.t, bare.mocap_pos).contacts
    assert hits > 0
    assert obstacle_contacts(exp.robot, bare.q, bare.t).contacts != hits     # a frozen sphere counts other contacts
    with pytest.raises(ConfigError, match="mocap positions"):
        obstacle_contacts(exp.robot, safe.q, safe.t, safe.mocap_pos[:-1])
