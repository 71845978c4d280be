"""The DMP baseline as a field the arm runs (``lfd.bench.dmp_field``): its rollout tracked, a push
pulled back at its stated gain, its goal moved, poses in the chart, and the job's ``--learner dmp``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lfd
import sim
from lfd.bench.dmp_field import GAIN, dmp_field
from lfd.errors import ConfigError
from lfd.field import FieldKind, StateSpace


@pytest.fixture(scope="module")
def spiral() -> lfd.DemoSet:
    return lfd.load_demos("spiral")


def test_from_its_start_the_field_follows_the_dmps_rollout_to_the_goal(spiral: lfd.DemoSet) -> None:
    f = dmp_field(spiral)
    assert (f.kind, f.space, f.dim, f.learner) == (FieldKind.TIME_VARYING, StateSpace.POSITION, 2, "dmp")
    t = np.arange(0.0, f.duration + 2.0, 0.002)
    x, phase = f.trajectory(f.start, t)
    y, _ = f.reference(f.start)
    assert phase is None
    assert np.abs(x[: len(y)] - y).max() < 1e-4 * np.abs(y).max()          # on the rollout
    assert np.linalg.norm(x[-1] - spiral.goal) < 1e-3 * np.ptp(spiral.x)    # at the goal


def test_a_push_is_pulled_back_at_the_stated_gain(spiral: lfd.DemoSet) -> None:
    """From the rollout's point at t1 moved by delta, the error after tau decays as exp(-k tau)."""
    f = dmp_field(spiral)
    y, _ = f.reference(f.start)
    t1, delta = 1.0, np.array([0.3, -0.2]) * np.ptp(spiral.x)
    k1 = int(round(t1 / 0.002))
    t = np.arange(t1, t1 + 0.3 + 1e-9, 0.001)
    fn = f.command(f.start)
    x = y[k1] + delta
    for a, b in zip(t[:-1], t[1:]):          # RK4 from the pushed state, on the field's clock
        h = b - a
        k_1 = fn(x, a)
        k_2 = fn(x + h / 2 * k_1, a + h / 2)
        k_3 = fn(x + h / 2 * k_2, a + h / 2)
        k_4 = fn(x + h * k_3, b)
        x = x + h / 6 * (k_1 + 2 * k_2 + 2 * k_3 + k_4)
    err = x - y[int(round(t[-1] / 0.002))]
    assert np.linalg.norm(err) == pytest.approx(np.linalg.norm(delta) * np.exp(-GAIN * 0.3), rel=0.02)


def test_the_goal_moves_and_bad_goals_are_one_line(spiral: lfd.DemoSet) -> None:
    f = dmp_field(spiral)
    g = f.toward(spiral.goal + [0.1, -0.05])
    assert g.goal == pytest.approx(spiral.goal + [0.1, -0.05])
    x, _ = g.trajectory(g.start, np.arange(0.0, g.duration + 2.0, 0.01))
    assert np.linalg.norm(x[-1] - g.goal) < 1e-3
    with pytest.raises(ConfigError, match="^the DMP baseline's goal is 2 values, got 3 values$"):
        f.toward(np.zeros(3))
    pose = dmp_field(lfd.load_demos("robottasks:pouring"))
    assert (pose.space, pose.dim) == (StateSpace.POSE, 6) and pose.chart is not None
    moved = pose.toward(pose.goal[:3] + 0.02)
    assert moved.goal[:3] == pytest.approx(pose.goal[:3] + 0.02) and moved.goal[3:] == pytest.approx(pose.goal[3:])
    with pytest.raises(ConfigError, match="orientation goal is the demos'"):
        pose.toward(np.zeros(7))


def test_the_arm_runs_the_dmp_baseline_and_brings_a_push_back(tmp_path: Path) -> None:
    runs = sim.run_job(sim.ArmJob(robot="panda", learners=("dmp",), scenarios=("none", "push"), videos=False,
                                  plots=False, quiet=True, out=str(tmp_path))).results
    none, push = runs
    assert none.metrics["tracking_rmse_m"] < 0.002 and none.metrics["final_goal_error_m"] < 1e-3
    assert push.metrics["recovery_time_s"] < 0.5 and push.metrics["final_goal_error_m"] < 1e-3
