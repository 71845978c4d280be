"""Via-points (``lfd.via``, ``--via``): the tracking learner's reference conditioned to pass through a point
no demo passed through, the start and the goal kept, from any start; and on the arm."""

from __future__ import annotations

import numpy as np
import pytest

import lfd
import sim
from lfd.errors import ConfigError
from lfd.via import parse_via, through
from sim.run.plan import plan_job


@pytest.fixture(scope="module")
def tracking(spiral: lfd.DemoSet) -> lfd.VelocityField:
    return lfd.train("tracking", spiral, seed=0)


def _off_path(field: lfd.VelocityField, x0: np.ndarray, s: float, distance: float) -> np.ndarray:
    """The reference point at phase s moved ``distance`` along its normal (2-D)."""
    r = field.reference(np.array([s - 1e-3, s, s + 1e-3]), x0)
    tangent = r[2] - r[0]
    normal = np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent)
    return r[1] + distance * normal


@pytest.mark.parametrize("phases", [[0.5], [0.3, 0.7]])
def test_the_reference_passes_through_the_points_and_keeps_its_start_and_goal(
        tracking: lfd.VelocityField, spiral: lfd.DemoSet, phases: list[float]) -> None:
    x0 = spiral.x[2, 0]
    points = [_off_path(tracking, x0, s, 0.2 * spiral.extent) for s in phases]
    via = through(tracking, points, phases)
    ends = np.array([0.0, 1.0])
    for start in (None, x0, x0 + 0.05 * spiral.extent):      # the mean reference and two conditioned ones
        np.testing.assert_allclose(via.reference(np.array(phases), start), points, rtol=0, atol=1e-9)
        np.testing.assert_allclose(via.reference(ends, start), tracking.reference(ends, start), rtol=0, atol=1e-12)
    assert np.abs(via.module.dref[[0, -1]] - tracking.module.dref[[0, -1]]).max() < 1e-12   # slopes at the ends
    assert not np.allclose(tracking.reference(np.array(phases), x0), points, atol=1e-3)      # the original is not moved
    x, _ = via.trajectory(x0, np.linspace(0.0, 1.5 * spiral.t[0, -1], 3001))
    for p in points:
        assert np.linalg.norm(x - p, axis=1).min() < 1e-3 * spiral.extent
    assert np.linalg.norm(x[-1] - spiral.goal) < 1e-6


def test_a_point_without_a_phase_takes_that_of_the_nearest_reference_point(tracking: lfd.VelocityField,
                                                                           spiral: lfd.DemoSet) -> None:
    p = _off_path(tracking, None, 0.6, 0.02 * spiral.extent)  # type: ignore[arg-type]
    via = through(tracking, [p])
    knots = np.linspace(0.0, 1.0, via.module.ref.shape[0])       # the phases the nearest point is taken on
    near = int(np.argmin(np.linalg.norm(tracking.reference(knots) - p, axis=1)))
    np.testing.assert_allclose(via.reference(knots[[near]])[0], p, rtol=0, atol=1e-9)


@pytest.mark.parametrize("points, phases, message", [
    ([[0.1, 0.2, 0.3]], [0.5], "via-points must be 2 finite coordinates each"),
    ([[np.nan, 0.0]], [0.5], "via-points must be 2 finite coordinates each"),
    ([[0.1, 0.2]], [0.99], "a via-point's phase must lie in [0.05, 0.95]"),
    ([[0.1, 0.2], [0.2, 0.1]], [0.5, 0.51], "two via-points lie closer than 0.02 in phase"),
])
def test_bad_via_points_are_refused(tracking: lfd.VelocityField, points: list, phases: list, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        through(tracking, points, phases)
    assert message in str(e.value)


def test_only_the_tracking_learner_takes_via_points(spiral: lfd.DemoSet) -> None:
    contraction = lfd.train("contraction", spiral, seed=0, iterations=5)
    with pytest.raises(ConfigError, match="via-points condition the tracking learner's reference"):
        through(contraction, [[0.0, 0.0]], [0.5])


def test_parse_via() -> None:
    point, s = parse_via("0.1,-0.2@0.4", 2)
    assert point.tolist() == [0.1, -0.2] and s == 0.4
    assert parse_via("1,2,3", 3)[1] is None
    for text, dim, message in (("1,2", 3, "expected 3 finite task coordinates"), ("a,b", 2, "expected X,Y[,Z]"),
                               ("1,2@1", 2, "the phase must lie in [0.05, 0.95]")):
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
            parse_via(text, dim)


@pytest.mark.usefixtures("one_thread")
def test_the_arm_passes_a_via_point_3_cm_off_the_path_and_still_reaches_its_goal(
        tracking: lfd.VelocityField, spiral: lfd.DemoSet, tmp_path) -> None:
    base = dict(robot="panda", learners=("tracking",), scenarios=("none",), videos=False, plots=False, quiet=True)
    plain = sim.run_job(sim.ArmJob(out=str(tmp_path / "plain"), **base))   # type: ignore[arg-type]
    placement = plan_job(sim.ArmJob(out=str(tmp_path / "probe"), **base)).exp.placement  # type: ignore[arg-type]
    v = _off_path(tracking, spiral.x[0, 0], 0.5, 0.03 / placement.scale)
    job = sim.ArmJob(out=str(tmp_path / "via"), via=(f"{float(v[0])!r},{float(v[1])!r}@0.5",), **base)  # type: ignore[arg-type]
    run = sim.run_job(job).results[0]
    v_world = placement.to_world(v[None])[0]
    assert np.linalg.norm(run.trace.ee - v_world, axis=1).min() < 0.002
    assert run.metrics["final_goal_error_m"] < 0.001
    assert np.linalg.norm(plain.results[0].trace.ee - v_world, axis=1).min() > 0.005
