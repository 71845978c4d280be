"""Via-points (``lfd.via``, ``--via``): the tracking learner's reference conditioned to pass through a point
no demo passed through, the start and the goal kept, from any start; an autonomous field through a
moving goal; and on the arm, through the limiter."""

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


@pytest.fixture(scope="module")
def contraction(spiral: lfd.DemoSet) -> lfd.VelocityField:
    return lfd.train("contraction", spiral, seed=0)


def test_an_autonomous_field_passes_through_the_points_by_a_moving_goal(
        contraction: lfd.VelocityField, spiral: lfd.DemoSet) -> None:
    """From the start it was conditioned on, the goal contraction's motion passes through two points
    0.3 units off its path (at phases 0.3 and 0.7) to 1e-6; it starts at rest where the field does, and
    from the motion's end on it is the field itself (the same rollout, the same goal)."""
    x0, T = spiral.x[0, 0], float(spiral.t[0, -1])
    t = np.linspace(0.0, T, 1001)
    path = contraction.trajectory(x0, t)[0]
    points = []
    for k in (300, 700):
        tangent = path[k + 1] - path[k - 1]
        points.append(path[k] + 0.3 * np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent))
    via = through(contraction, points, [0.3, 0.7], start=x0, duration=T)
    fine = np.linspace(0.0, 1.5 * T, 15001)
    x = via.trajectory(x0, fine)[0]
    for p in points:
        assert np.linalg.norm(x - p, axis=1).min() < 1e-6
    np.testing.assert_allclose(via(x0, 0.0), contraction(x0), atol=1e-12)
    plain = contraction.trajectory(x0, fine)[0]
    assert np.linalg.norm(x[-1] - plain[-1]) < 1e-6
    np.testing.assert_allclose(via(plain[-1], 1.2 * T), contraction(plain[-1]), atol=1e-12)


def test_an_autonomous_field_needs_its_start_and_duration(contraction: lfd.VelocityField) -> None:
    with pytest.raises(ConfigError, match="need its start and the motion's duration"):
        through(contraction, [[0.0, 0.0]], [0.5])
    with pytest.raises(ConfigError, match="2 finite coordinates"):
        through(contraction, [[0.0, 0.0]], [0.5], start=np.array([np.nan, 0.0]), duration=5.0)


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


@pytest.mark.usefixtures("one_thread")
def test_the_goal_contraction_passes_a_via_point_on_the_arm_within_the_limits(
        contraction: lfd.VelocityField, tmp_path) -> None:
    """At 1 kHz through the limiter: a point 3 cm off the goal contraction's path, mid-motion, passed
    within 2 mm, the goal kept as without it, no command over the Panda's limits, and the path away
    from the detour (phases outside [0.3, 0.7]) within 1.5x of the plain run's DTW to the demo."""
    base = dict(robot="panda", learners=("contraction",), scenarios=("none",), videos=False, plots=False, quiet=True,
                control_hz=1000.0, limiter=True)
    plan = plan_job(sim.ArmJob(out=str(tmp_path / "probe"), **base))   # type: ignore[arg-type]
    exp, field = plan.exp, plan.fields["contraction"]
    T = float(exp.setup.demo_t[-1])
    path = field.trajectory(exp.start, np.linspace(0.0, T, 1001))[0]
    tangent = path[501] - path[499]
    v = path[500] + 0.03 / exp.placement.scale * np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent)
    plain = sim.run_job(sim.ArmJob(out=str(tmp_path / "plain"), **base)).results[0]   # type: ignore[arg-type]
    job = sim.ArmJob(out=str(tmp_path / "via"), via=(f"{float(v[0])!r},{float(v[1])!r}@0.5",), **base)  # type: ignore[arg-type]
    run = sim.run_job(job).results[0]
    assert np.linalg.norm(run.trace.ee - exp.placement.to_world(v[None])[0], axis=1).min() < 0.002
    assert run.metrics["final_goal_error_m"] < plain.metrics["final_goal_error_m"] + 1e-4
    assert run.metrics["command_limits"]["violations"] == 0
    demo, t = exp.setup.task_demos.x[0], exp.setup.task_demos.t[0]

    def outside(r: object) -> float:
        xs = exp.placement.to_task(r.trace.ee[r.trace.steps_at(t)])   # type: ignore[attr-defined]
        return sum(lfd.metrics.dtw(xs[m], demo[m]) / np.count_nonzero(m) for m in (t < 0.3 * T, t > 0.7 * T))
    assert outside(run) < 1.5 * outside(plain)
