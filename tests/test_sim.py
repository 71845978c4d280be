"""Mechanics of sim/: placement, perturbations, the dm_control task, divergence, video, the demo CLI.

The fields here are hand-made linear sinks (no training), so these tests are fast and test the
machinery, not the learners; tests/test_arm_regression.py runs the learned fields.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from known_fields import sink_field

import lfd
import sim  # noqa: F401  (sets MUJOCO_GL first)
from robots import load_robot
from sim.control.task import OBSERVATION_KEYS
from sim.errors import PlacementError, RenderError, SimulationError
from sim.run import experiment as sim_experiment
from sim.scene.perturbations import compile_schedule

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def demos() -> lfd.DemoSet:
    return lfd.spiral(n_demos=2, n_samples=60, duration=1.0)


@pytest.fixture(scope="module")
def planar():
    return load_robot("planar", actuation="torque")


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda", actuation="torque")


# ---------------------------------------------------------------- placement
def test_placement_round_trip_and_default_size(panda, demos):
    pl = sim.Placement.auto(panda, demos.x)
    x = demos.x[0]
    np.testing.assert_allclose(pl.to_task(pl.to_world(x)), x, atol=1e-12)
    np.testing.assert_allclose(pl.velocity_to_world(x) + pl.origin, pl.to_world(x), atol=1e-12)
    span = np.ptp(pl.to_world(demos.x.reshape(-1, 2)), axis=0).max()
    assert 0.10 <= span <= 0.15, span          # the default spiral is 10-15 cm across on the Panda
    assert abs(pl.normal @ np.array([0, 0, 1.0])) == pytest.approx(1.0)   # horizontal plane
    vert = sim.Placement.auto(panda, demos.x, plane="vertical")
    assert abs(vert.normal[2]) < 1e-12 and abs(vert.axes[:, 1] @ np.array([0, 0, 1.0])) == pytest.approx(1.0)
    pl.check_reachable(panda, demos.x)


def test_placement_rejects_unreachable(panda, planar, demos):
    far = sim.Placement.auto(panda, demos.x, size_m=2.5)
    with pytest.raises(PlacementError, match="unreachable"):
        far.check_reachable(panda, demos.x)
    with pytest.raises(PlacementError, match="moves in a plane"):
        sim.Placement.auto(planar, lfd.spiral3d(n_demos=1, n_samples=20).x)
    with pytest.raises(PlacementError, match="unreachable"):
        sim.Experiment(planar, demos, size_m=3.0)


def test_3d_field_on_the_panda_uses_the_full_position(panda):
    demos3 = lfd.spiral3d(n_demos=2, n_samples=60, duration=1.5)
    exp = sim.Experiment(panda, demos3, settle_s=0.5)
    assert exp.placement.dim == 3 and np.allclose(exp.placement.rotation, np.eye(3))
    r = exp.run(sink_field(demos3), "none")
    assert np.ptp(r.trace.ee[:, 2]) > 0.03                # it moves in height too
    assert r.metrics["tracking_rmse_m"] < 0.003
    assert np.linalg.norm(r.trace.ee[-1] - r.reference[-1]) < 0.001    # where the field's flow ends
    assert r.metrics["joint_limit_violations"] == 0


# ---------------------------------------------------------------- perturbations
def test_perturbations_are_deterministic(panda, demos):
    pl = sim.Placement.auto(panda, demos.x)
    bodies = {"panda_hand": 10}
    perts = (sim.StartOffset(seed=3), sim.GoalShift(seed=4), sim.Push(seed=5, start_s=0.1, duration_s=0.2),
             sim.JointVelocityNoise(std_rad_s=0.01, seed=6))
    a = compile_schedule(perts, pl, bodies, "panda_hand", 7, 100, 0.002)
    b = compile_schedule(perts, pl, bodies, "panda_hand", 7, 100, 0.002)
    for name in ("start_offset_task", "goal_offset_task", "push_force", "qvel_noise"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.push_steps == (50, 150) and a.push_body == 10
    assert np.linalg.norm(a.push_force[:3]) == pytest.approx(20.0)
    assert abs(a.push_force[:3] @ pl.normal) < 1e-9                      # in the task plane
    assert np.linalg.norm(pl.to_world(a.start_offset_task) - pl.origin) == pytest.approx(0.02)
    c = compile_schedule((sim.StartOffset(seed=4), sim.JointVelocityNoise(seed=7)), pl, bodies, "panda_hand",
                         7, 100, 0.002)
    assert not np.allclose(a.start_offset_task, c.start_offset_task)
    assert not np.allclose(a.qvel_noise, c.qvel_noise)


def test_perturbed_rollouts_repeat_exactly(planar, demos):
    exp = sim.Experiment(planar, demos, settle_s=0.0)
    field = sink_field(demos)
    perts = (sim.StartOffset(seed=1), sim.Push(start_s=0.2, duration_s=0.1, seed=2), sim.JointVelocityNoise(seed=3))
    a = exp.simulate(field, perts)
    b = exp.simulate(field, perts)
    np.testing.assert_array_equal(a.ee, b.ee)
    c = exp.simulate(field, ())
    assert np.abs(a.ee - c.ee).max() > 1e-3


# ---------------------------------------------------------------- dm_control environment
def test_the_robot_is_the_one_source_of_the_actuation(planar, demos):
    """load_robot checks the actuation once; the robot carries it to the controller and the experiment."""
    from sim.errors import SimError

    servo = load_robot("planar", actuation="position")
    assert (servo.actuation, planar.actuation) == ("position", "torque")
    for robot in (servo, planar):
        exp = sim.Experiment(robot, demos, settle_s=0.1)
        assert exp.describe()["actuation"] == robot.actuation
        assert sim.make_environment(robot, demos=demos).task.controller.actuation == robot.actuation
    assert sim.make_environment("planar", demos=demos, actuation="position").task.controller.actuation == "position"
    with pytest.raises(SimError, match="loaded with actuation='position', not 'torque'"):
        sim.make_environment(servo, demos=demos, actuation="torque")
    with pytest.raises(TypeError):
        sim.Experiment(planar, demos, actuation="torque")  # type: ignore[call-arg]


def test_run_length_is_time_factor_times_the_demo_plus_settling(planar, demos):
    from sim.errors import SimError

    demo_s = float(demos.t[0, -1] - demos.t[0, 0])
    assert abs(sim.Experiment(planar, demos, settle_s=0.5, time_factor=3.0).duration_s - (3 * demo_s + 0.5)) < 1e-12
    assert abs(sim.Experiment(planar, demos, settle_s=0.5).duration_s - (demo_s + 0.5)) < 1e-12
    for bad in (0.5, float("nan"), 1e9):
        with pytest.raises(SimError, match="time_factor must be in"):
            sim.Experiment(planar, demos, time_factor=bad)


def test_environment_reset_and_step(panda, demos):
    pl = sim.Placement.auto(panda, demos.x)
    env = sim.make_environment(sim.RunSetup.resolve(panda, demos, placement=pl), duration_s=0.02)
    ts = env.reset()
    assert tuple(ts.observation) == OBSERVATION_KEYS
    shapes = {k: v.shape for k, v in ts.observation.items()}
    assert shapes == {"joint_positions": (7,), "joint_velocities": (7,), "ee_position": (3,),
                      "task_position": (2,), "goal": (2,), "joint_limit": (7,)}
    np.testing.assert_allclose(ts.observation["ee_position"], pl.to_world(demos.x[0, 0]), atol=1e-5)
    spec = env.action_spec()
    assert spec.shape == (2,) and spec.name == "ee_velocity"
    assert set(env.observation_spec()) == set(OBSERVATION_KEYS)
    v = np.array([0.5, 0.0])                      # task units / s along task x
    steps = 0
    while not ts.last():
        ts = env.step(v)
        steps += 1
        assert {k: x.shape for k, x in ts.observation.items()} == shapes
        assert 0.0 <= ts.reward <= 1.0
    assert steps == 10
    moved = pl.to_task(ts.observation["ee_position"]) - demos.x[0, 0]
    assert moved[0] > 0 and abs(moved[1]) < 0.5 * moved[0]


# ---------------------------------------------------------------- divergence
def test_divergence_raises_simulation_error(planar, demos):
    exp = sim.Experiment(planar, demos, settle_s=0.0)
    with pytest.raises(SimulationError, match="diverged"):
        exp.simulate(sink_field(demos), (sim.JointVelocityNoise(std_rad_s=1e12, seed=0),))
    nan_field = sink_field(demos)
    with torch.no_grad():
        nan_field.module.A.fill_(float("nan"))
    with pytest.raises(SimulationError, match="diverged"):
        exp.simulate(nan_field)


def test_demo_cli_writes_nothing_when_the_simulation_diverges(tmp_path, monkeypatch):
    import sim.run.job
    from sim.run import cli

    model = tmp_path / "sink.pt"
    demos = lfd.spiral(n_demos=2, n_samples=60, duration=1.0)
    sink_field(demos).save(model)
    monkeypatch.setattr(lfd, "load", lambda path: sink_field(lfd.load_demos("spiral")))
    diverging = lambda name, seed=0, pose=False: (sim.JointVelocityNoise(std_rad_s=1e12),)  # noqa: E731
    monkeypatch.setattr(sim.run.job, "scenario", diverging)
    monkeypatch.setattr(sim_experiment, "scenario", diverging)
    out = tmp_path / "out"
    rc = cli.main(["--robot", "planar", "--model", str(model), "--perturb", "none", "--out", str(out), "--quiet"])
    assert rc == 2
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["--robot", "nope"], "unknown robot"),
    (["--robot", "panda", "--ee-frame", "bogus", "--model", "x.pt"], "frame"),
    (["--model", "/no/such/model.pt"], "no such model"),
    (["--demos", "lasa:Nope"], "unknown LASA shape"),
])
def test_demo_cli_bad_input_is_one_line_exit_2(argv, message, capsys):
    from sim.run import cli

    assert cli.main(argv + ["--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


# ---------------------------------------------------------------- video
def test_headless_video_has_expected_frames_and_motion(planar, demos, tmp_path):
    import imageio_ffmpeg

    exp = sim.Experiment(planar, demos, settle_s=0.0)
    result = exp.run(sink_field(demos), "push", perturbations=(sim.Push(start_s=0.3, duration_s=0.2),))
    path = tmp_path / "run.mp4"
    n = exp.render(result, path, width=160, height=120, fps=30.0)
    expected = int(np.floor(exp.duration_s * 30.0 + 1e-9)) + 1
    assert n == expected == len(result.trace.frame_t)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert tuple(meta["size"]) == (160, 120)
    frames = np.stack([np.frombuffer(f, np.uint8).reshape(120, 160, 3) for f in reader])
    assert len(frames) == expected
    diffs = np.abs(np.diff(frames.astype(np.int16), axis=0)).mean(axis=(1, 2, 3))
    assert (diffs > 0.05).mean() > 0.8           # the arm moves: most consecutive frames differ
    assert frames.std() > 10                     # not a blank image


# ---------------------------------------------------------------- GL back-end choice
def test_gl_backend_respects_the_user_and_falls_back_to_osmesa(monkeypatch):
    from sim.media import gl

    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert gl.select_backend() == "osmesa" and os.environ["MUJOCO_GL"] == "osmesa"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr(gl, "library_found", lambda b: b == "osmesa")
    assert gl.select_backend() == "osmesa"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr(gl, "library_found", lambda b: True)
    assert gl.select_backend() == "egl"


def test_render_error_is_one_clear_line(monkeypatch):
    from sim.media.render import open_gl_context

    monkeypatch.setenv("MUJOCO_GL", "wgl")
    with pytest.raises(RenderError, match="MUJOCO_GL=wgl cannot render offscreen"):
        open_gl_context(16, 16)


# ---------------------------------------------------------------- model cache
def test_model_cache_trains_once_and_keys_on_seed_and_options(tmp_path, demos):
    from lfd.cache import cached_field

    opts = {"layers": 2, "hidden": 8, "iterations": 5}
    f1, path, trained = cached_field("contraction", demos, 0, opts, tmp_path, progress=False)
    assert trained and path.is_file() and path.parent == tmp_path
    f2, path2, trained2 = cached_field("contraction", demos, 0, opts, tmp_path, progress=False)
    assert not trained2 and path2 == path
    x = demos.x[0, :5]
    np.testing.assert_array_equal(f1(x), f2(x))
    assert cached_field("contraction", demos, 1, opts, tmp_path, progress=False)[1] != path
    assert cached_field("contraction", demos, 0, {**opts, "hidden": 4}, tmp_path, progress=False)[1] != path
    path.write_bytes(b"not a model")
    f3, _, trained3 = cached_field("contraction", demos, 0, opts, tmp_path, progress=False)
    assert trained3
    np.testing.assert_allclose(f1(x), f3(x), rtol=1e-8)     # same seed, same model (to rounding)
