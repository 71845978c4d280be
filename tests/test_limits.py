"""The robot's motion limits as data (``robots.limits``) and every run's report against them."""

from __future__ import annotations

import math

import numpy as np
import pytest

import lfd
import sim
from robots import load_robot
from robots.limits import PANDA, Limits, limits_of


def test_the_panda_limits_are_the_published_ones_and_its_model_agrees() -> None:
    assert PANDA.dq_max.tolist() == [2.175] * 4 + [2.61] * 3
    assert PANDA.ddq_max.tolist() == [15, 7.5, 10, 12.5, 15, 20, 20]
    assert PANDA.dddq_max.tolist() == [7500, 3750, 5000, 6250, 7500, 10000, 10000]
    assert PANDA.dtau_max.tolist() == [1000] * 7
    assert PANDA.tool_translation == (1.7, 13.0, 6500.0) and PANDA.tool_rotation == (2.5, 25.0, 12500.0)
    assert PANDA.assumed == () and "frankaemika.github.io" in PANDA.source
    robot = load_robot("panda")
    assert limits_of(robot) is PANDA
    np.testing.assert_allclose(robot.q_min, PANDA.q_min, atol=1e-4)
    np.testing.assert_allclose(robot.q_max, PANDA.q_max, atol=1e-4)
    np.testing.assert_allclose(robot.v_max, PANDA.dq_max, atol=1e-9)


def test_a_robot_without_published_limits_says_what_is_assumed() -> None:
    robot = load_robot("planar")
    lim = limits_of(robot)
    assert lim.n == robot.n and np.array_equal(lim.dq_max, robot.v_max)
    assert {"joint acceleration", "joint jerk", "tool translation"} <= set(lim.assumed)
    assert np.isinf(lim.ddq_max).all() and "model file" in lim.source


def test_a_smooth_stream_peaks_where_its_derivatives_do() -> None:
    """q = A sin(w t) on every joint at 1 kHz: peaks A w, A w^2, A w^3 (to the finite differences' 1%)
    as fractions of each limit, the worst joint named, nothing over."""
    t = np.arange(0.0, 2.0, 1e-3)
    amp, w = 0.3, 4.0
    q = (PANDA.q_max + PANDA.q_min) / 2 + amp * np.sin(w * t)[:, None]
    report = PANDA.check(t, q)
    joint = report["joint"]
    assert joint["velocity"]["peak"] == pytest.approx(amp * w / 2.175, rel=1e-2)
    assert joint["acceleration"]["peak"] == pytest.approx(amp * w**2 / 7.5, rel=1e-2)
    assert joint["acceleration"]["joint"] == 1                                   # the lowest limit
    assert joint["jerk"]["peak"] == pytest.approx(amp * w**3 / 3750, rel=1e-2)
    assert report["violations"] == 0 and report["rate_hz"] == pytest.approx(1000.0)


def test_a_velocity_step_breaks_the_acceleration_and_jerk_limits() -> None:
    """A 0.5 rad/s step in one sample, as the command franka-sim aborts: 500 rad/s^2 and 5e5 rad/s^3 at
    1 kHz, over every joint's limit; the tool's path through it is checked too."""
    t = np.arange(0.0, 0.1, 1e-3)
    dq = np.zeros((len(t), 7))
    dq[50:, 0] = 0.5
    q = (PANDA.q_max + PANDA.q_min) / 2 + np.cumsum(dq, axis=0) * 1e-3
    tool = np.zeros((len(t), 3))
    tool[:, 0] = np.cumsum(np.where(t >= 0.05, 0.1, 0.0)) * 1e-3
    report = PANDA.check(t, q, dq, tool)
    assert report["joint"]["acceleration"]["peak"] == pytest.approx(500 / 15)
    assert report["joint"]["acceleration"]["over"] == 1 and report["joint"]["jerk"]["over"] == 2
    assert report["joint"]["velocity"]["over"] == report["joint"]["position"]["over"] == 0
    assert report["tool"]["acceleration"]["peak"] == pytest.approx(100 / 13, rel=1e-9)
    assert report["violations"] == 1 + 2 + report["tool"]["acceleration"]["over"] + report["tool"]["jerk"]["over"]


@pytest.mark.parametrize("bad", [dict(dq_max=[math.nan] * 7), dict(ddq_max=[1.0] * 6),
                                 dict(q_min=[3.0] * 7), dict(tool_translation=(1.0, 0.0, 1.0))])
def test_bad_limits_are_refused(bad: dict) -> None:
    values = dict(name="x", source="test", q_min=PANDA.q_min, q_max=PANDA.q_max, dq_max=PANDA.dq_max,
                  ddq_max=PANDA.ddq_max, dddq_max=PANDA.dddq_max, tau_max=PANDA.tau_max,
                  dtau_max=PANDA.dtau_max, tool_translation=PANDA.tool_translation,
                  tool_rotation=PANDA.tool_rotation)
    values.update(bad)
    with pytest.raises(ValueError):
        Limits(**values)  # type: ignore[arg-type]


@pytest.mark.usefixtures("one_thread")
def test_every_run_reports_its_motion_against_the_limits_and_only_its_start_breaks_them() -> None:
    """The default spiral on the Panda, pushed: position and velocity stay within the limits; the
    acceleration and jerk limits are broken only in the first 20 ms, where the arm at rest is asked
    for the field's start speed at once (no limiter yet), never after."""
    robot = load_robot("panda")
    demos = lfd.spiral()
    exp = sim.Experiment(robot, demos)
    run = exp.run(lfd.train("tracking", demos, seed=0), "push")
    report = run.metrics["motion_limits"]
    assert report["joint"]["position"]["peak"] < 1 and report["joint"]["velocity"]["peak"] < 1
    assert report["tool"]["velocity"]["peak"] < 1
    tr = run.trace
    later = tr.t >= 0.02
    after = PANDA.check(tr.t[later], tr.q[later], tr.qdot[later], tr.ee[later])
    assert after["violations"] == 0, after
    assert report["violations"] >= after["violations"]


def test_the_tool_rotation_is_checked_from_its_orientations() -> None:
    """A tool turning about z at 1 rad/s, then at 2 rad/s from one sample to the next (1 kHz): angular
    velocity 2 / 2.5 of the limit, the step 1000 rad/s^2 against 25; nothing over before the step."""
    t = np.arange(0.0, 0.2, 1e-3)
    rate = np.where(t < 0.1, 1.0, 2.0)
    angle = np.concatenate([[0.0], np.cumsum(rate[:-1]) * 1e-3])
    c, s = np.cos(angle), np.sin(angle)
    rot = np.zeros((len(t), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    q = np.tile((PANDA.q_max + PANDA.q_min) / 2, (len(t), 1))
    report = PANDA.check(t, q, tool_rotation=rot)["tool_rotation"]
    assert report["velocity"]["peak"] == pytest.approx(2.0 / 2.5, rel=1e-9)
    assert report["acceleration"]["peak"] == pytest.approx(1000.0 / 25.0, rel=1e-6)
    assert report["acceleration"]["over"] == 1 and report["jerk"]["over"] == 2
    early = PANDA.check(t[:100], q[:100], tool_rotation=rot[:100])
    assert early["violations"] == 0
