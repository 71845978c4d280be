"""A learned motion run S times faster or slower (``lfd.retime.at_speed``, ``--speed``): the same paths in
1/S of the time, for every kind of field, and on the arm."""

from __future__ import annotations

import numpy as np
import pytest

import lfd
import sim
from lfd.errors import ConfigError
from lfd.field import FieldKind
from lfd.goal import shift_goal
from lfd.retime import at_speed


@pytest.fixture(scope="module")
def fields(spiral: lfd.DemoSet) -> dict[str, lfd.VelocityField]:
    return {"contraction": lfd.train("contraction", spiral, seed=0, iterations=60),
            "tracking": lfd.train("tracking", spiral, seed=0)}


@pytest.mark.parametrize("learner", ["contraction", "tracking"])
@pytest.mark.parametrize("speed", [0.5, 2.0])
def test_the_retimed_field_runs_the_same_trajectory_in_one_sth_of_the_time(
        fields: dict[str, lfd.VelocityField], spiral: lfd.DemoSet, learner: str, speed: float) -> None:
    """x_S(t) = x(S t), the phase too; its commands are S times the field's at S t, and its runner's
    phase advances S times as far per control period."""
    f = fields[learner]
    g = at_speed(f, speed)
    assert g.kind is f.kind and g.dim == f.dim and g.learner == f.learner
    t = np.linspace(0.0, 3.0, 151)
    x0 = spiral.x[0, 0]
    xs, ss = g.trajectory(x0, t)
    x1, s1 = f.trajectory(x0, speed * t)
    np.testing.assert_allclose(xs, x1, rtol=0, atol=1e-12)
    assert (ss is None) == (s1 is None) and (ss is None or np.allclose(ss, s1, rtol=0, atol=1e-12))
    fast, slow = g.runner(x0, 0.002), f.runner(x0, speed * 0.002)
    for k in range(5):
        x = x0 + 0.01 * k
        np.testing.assert_allclose(fast(x, 0.002 * k), speed * slow(x, speed * 0.002 * k), rtol=1e-12, atol=0)
    if f.kind is FieldKind.PHASED:
        assert fast.phases() is not None and fast.duration == pytest.approx(f.duration / speed)


def test_a_moving_goal_moves_at_the_motion_s_speed(fields: dict[str, lfd.VelocityField], spiral: lfd.DemoSet) -> None:
    """A time-varying field re-timed: f_S(x, t) = S f(x, S t), so a goal shifted at 2 s shifts at 1 s
    when the motion runs twice as fast."""
    moving = shift_goal(fields["contraction"], 2.0, np.array([0.02, 0.0]))
    fast = at_speed(moving, 2.0)
    assert fast.kind is FieldKind.TIME_VARYING
    x = spiral.x[0, 10]
    np.testing.assert_allclose(fast(x, 1.3), 2.0 * moving(x, 2.6), rtol=1e-12, atol=0)
    np.testing.assert_allclose(fast.goal_at(5.0), moving.goal_at(5.0))


def test_speed_one_is_the_field_itself_and_absurd_speeds_are_refused(fields: dict[str, lfd.VelocityField]) -> None:
    f = fields["contraction"]
    assert at_speed(f, 1.0) is f
    for bad in (0.0, -1.0, float("nan"), float("inf"), 1e6):
        with pytest.raises(ConfigError, match="the speed must be a factor between 0.05 and 20"):
            at_speed(f, bad)


@pytest.mark.usefixtures("one_thread")
def test_the_arm_job_at_twice_the_speed_arrives_in_half_the_time(tmp_path) -> None:
    """The tracking learner on the Panda at S = 1 and 2: the tool comes within 2 mm of the goal at
    half the time (5%), the run lasts half as long before the settling time, the goal is reached,
    and the path against the demo (sampled at its re-timed times) stays close."""
    runs = {}
    for speed in (1.0, 2.0):
        job = sim.ArmJob(robot="panda", learners=("tracking",), scenarios=("none",), videos=False, plots=False,
                         out=str(tmp_path / f"s{speed}"), quiet=True, speed=speed)
        runs[speed] = sim.run_job(job).results[0]
    arrive = {}
    for speed, r in runs.items():
        d = np.linalg.norm(r.trace.ee - r.trace.goal_world, axis=1)
        arrive[speed] = float(r.trace.t[np.flatnonzero(d > 0.002)[-1] + 1])
        assert r.metrics["final_goal_error_m"] < 1e-4
    assert arrive[2.0] == pytest.approx(arrive[1.0] / 2, rel=0.05)
    assert runs[2.0].trace.t[-1] - 1.5 == pytest.approx((runs[1.0].trace.t[-1] - 1.5) / 2, abs=0.003)
    assert runs[2.0].metrics["imitation_dtw_m"] < 1.5 * runs[1.0].metrics["imitation_dtw_m"]
