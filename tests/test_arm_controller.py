"""The controller a real arm runs (``robots.controller``), its limiter (``robots.limiter``) and the
simulation's joint-velocity stream through them (``sim.control.step``, ``--limiter``)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import lfd
from lfd.goal import shift_goal
from robots import load_robot
from robots.controller import ArmController
from robots.errors import RobotError
from robots.limiter import JointLimiter
from robots.limits import PANDA
from sim.control.controller import FieldController
from sim.run.experiment import Experiment
from sim.scene.perturbations import Push


def _stream_peaks(v: np.ndarray, dt: float) -> tuple[float, float, float]:
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    return (float((np.abs(v) / PANDA.dq_max).max()), float((np.abs(a) / PANDA.ddq_max).max()),
            float((np.abs(j) / PANDA.dddq_max).max()))


def test_the_limited_stream_stays_within_the_limits_for_any_target() -> None:
    """Targets where a limiter is most likely to fail: steps of 100x the velocity limit, sign flips
    every step, a NaN-free random walk, and a start at the velocity bound heading the other way: the
    stream's velocity, acceleration and jerk by differences at 1 kHz stay within 0.95 of each limit,
    and a reachable constant target is met exactly."""
    dt = 1e-3
    lim = JointLimiter(PANDA, dt)
    rng = np.random.default_rng(0)
    targets = np.concatenate([np.full((300, 7), 100.0), np.full((300, 7), -100.0),
                              np.where(np.arange(400)[:, None] % 2 == 0, 3.0, -3.0) * np.ones((1, 7)),
                              np.cumsum(rng.normal(0, 0.3, (1000, 7)), axis=0), np.full((800, 7), 0.3)])
    lim.reset(PANDA.dq_max * 0.95)
    v = np.array([lim(t) for t in targets])
    peaks = _stream_peaks(np.vstack([PANDA.dq_max * 0.95, v]), dt)
    assert max(peaks) <= 0.95 + 1e-9, peaks
    assert min(peaks) > 0.9   # it did use the limits
    np.testing.assert_allclose(v[-1], 0.3, atol=1e-12)
    assert not lim.acted


def test_a_limiter_needs_finite_limits_and_sane_options() -> None:
    planar = load_robot("planar")
    from robots.limits import limits_of
    with pytest.raises(RobotError, match="no finite joint acceleration and jerk limits"):
        JointLimiter(limits_of(planar), 1e-3)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(RobotError, match="fraction"):
            JointLimiter(PANDA, 1e-3, fraction=bad)
    with pytest.raises(RobotError, match="positive time"):
        JointLimiter(PANDA, -1.0)


def test_the_controller_imports_no_simulator() -> None:
    """In a process where importing MuJoCo or dm_control fails, the controller is built from the
    Panda's URDF with Pinocchio alone and runs a 1 kHz step."""
    code = textwrap.dedent("""
        import sys, importlib.metadata
        from pathlib import Path
        for name in ("mujoco", "dm_control", "dm_env", "sim"):
            sys.modules[name] = None   # any import of them raises ImportError
        import numpy as np
        from robots.controller import ArmController
        from robots.limits import PANDA
        from robots.pinocchio_arm import load_urdf_arm
        from robots.task_frame import TaskFrame
        share = Path(importlib.metadata.distribution("example-robot-data").locate_file(
            "cmeel.prefix/share/example-robot-data"))
        arm = load_urdf_arm(share / "robots/panda_description/urdf/panda.urdf", "panda_hand_tcp")
        ctl = ArmController(arm, TaskFrame(origin=np.zeros(3), axes=np.eye(3), scale=1.0), 1e-3, limits=PANDA)
        ctl.start(lambda x, t: -x)
        dq = ctl(np.array([0, -0.785, 0, -2.356, 0, 1.571, 0.785]), np.zeros(7), 0.0)
        assert dq.shape == (7,) and np.isfinite(dq).all()
        print("ok", [m for m in ("mujoco", "dm_control") if sys.modules.get(m) is not None])
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok []"


@pytest.fixture(scope="module")
def spiral_runs() -> dict[str, object]:
    """The default job's spiral with the tracking learner on the torque-driven Panda at 1 kHz through
    the limiter, unperturbed and pushed (20 N, 0.2 s); and the goal contraction's field with its goal
    jumping 10 cm in 0.1 s mid-run."""
    robot = load_robot("panda", actuation="torque")
    demos = lfd.load_demos("spiral")
    field = lfd.train("tracking", demos, seed=0)
    exp = Experiment(robot, demos, control_hz=1000.0, limiter=True)
    auto = lfd.train("contraction", demos, seed=0)   # a moving goal takes an autonomous field
    jump = shift_goal(auto, 2.0, np.array([0.1, 0.0, 0.0])[:auto.dim] / exp.placement.scale, blend=0.1)
    return {"exp": exp, "field": field,
            "none": exp.run(field, "none"),
            "push": exp.run(field, "push", perturbations=(
                Push(direction=(1.0, 0.0, 0.0), force_n=20.0, start_s=1.5, duration_s=0.2),)),
            "goal": exp.run(jump, "none")}


def test_a_limited_run_stays_within_the_panda_limits(spiral_runs: dict) -> None:
    """From rest, pushed, and with the goal jumping 10 cm in 0.1 s mid-run: no command over any joint limit at 1 kHz,
    the limiter acting at the start, and the run still reaching its goal."""
    for name in ("none", "push", "goal"):
        m = spiral_runs[name].metrics
        report = m["command_limits"]
        assert report["rate_hz"] == pytest.approx(1000.0)
        assert report["violations"] == 0, (name, report)
        assert 0.5 < report["joint"]["acceleration"]["peak"] <= 0.95 + 1e-9
        assert m["limiter_window_s"][0] == 0.0 and m["limiter_active_s"] > 0.01
        # the goal contraction is still settling 4.5 s after a jump, limiter or not (2.9 mm at 500 Hz unlimited)
        assert m["final_goal_error_m"] < (5e-3 if name == "goal" else 1e-3), name


def test_the_simulation_sends_what_the_controller_alone_computes(spiral_runs: dict) -> None:
    """Replay the pushed run's measured joints and times into a fresh controller outside the
    simulation: the same joint-velocity commands, step by step, to 1e-12 rad/s."""
    exp, field, run = spiral_runs["exp"], spiral_runs["field"], spiral_runs["push"]
    ro = run.trace
    env = exp.environment()
    fresh = env.task.arm
    assert isinstance(fresh, ArmController)
    runner = field.runner(ro.start_task, float(ro.t[1] - ro.t[0]))
    fresh.start(runner)
    out = np.array([fresh(q, dq, float(t)) for q, dq, t in zip(ro.q[:-1], ro.qdot[:-1], ro.t[:-1])])
    assert np.abs(out - ro.joint_command[:-1]).max() <= 1e-12


def test_the_controller_commands_what_the_simulation_controller_does() -> None:
    """Without its limiter, the controller's joint velocity equals the simulation's own
    (``FieldController``'s twist and IK) at random states, on a position and a pose task."""
    rng = np.random.default_rng(3)
    for spec, actuation in (("spiral", "torque"), ("robottasks:pouring", "position")):
        robot = load_robot("panda", actuation=actuation)
        demos = lfd.load_demos(spec)
        exp = Experiment(robot, demos)
        task = exp.environment().task
        placement, ref = exp.placement, task.rotation_ref
        frame = placement.task_frame(robot.planar, ref)
        arm = ArmController(robot, frame, task.control_dt)
        ctl = FieldController(robot, placement, task.control_dt, rotation_ref=ref)
        for _ in range(5):
            q = task.q_start + rng.normal(0, 0.05, robot.n)
            ctl.reset(q)
            x = arm.point(q)
            np.testing.assert_allclose(x, ctl.to_task(ctl.measure(q)), atol=1e-12)
            v = rng.normal(0, 0.5, placement.dim)
            np.testing.assert_allclose(arm.command(v), ctl.solve_ik(q, ctl.twist(v)), atol=1e-10)


def test_bad_controller_input_says_one_thing() -> None:
    robot = load_robot("panda")
    demos = lfd.load_demos("spiral")
    exp = Experiment(robot, demos)
    frame = exp.placement.task_frame(False)
    arm = ArmController(robot, frame, 1e-3, limits=PANDA)
    with pytest.raises(RobotError, match="start the controller"):
        arm(robot.q_home, np.zeros(7), 0.0)
    arm.start(lambda x, t: np.zeros(3))
    with pytest.raises(RobotError, match="7 finite numbers"):
        arm(np.full(7, np.nan), np.zeros(7), 0.0)
