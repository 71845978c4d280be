"""The search for equilibria and closed orbits (``lfd.equilibria``) on fields whose answers are known:
a saddle and a spurious sink, a limit cycle, an escaping flow, a 6-D field (Sobol seeds), and the
learners' fields that have none (the tracking learner's autonomous view, a pose field's chart)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from equilibrium_fields import C, bistable_field, bistable_node, hopf_field
from known_fields import linear_field

import lfd
from lfd.equilibria import equilibria_summary, find_equilibria, search_box
from lfd.equilibria.orbits import recurrence
from lfd.equilibria.report import classify
from lfd.equilibria.roots import GRID_PER_AXIS, SOBOL_SEEDS
from lfd.errors import ConfigError

pytestmark = pytest.mark.usefixtures("one_thread")


def test_a_saddle_and_a_spurious_sink_are_found_exactly() -> None:
    lo, hi = np.array([-3.0, -1.0]), np.array([1.0, 1.0])
    r = find_equilibria(bistable_field(), lo, hi, duration=5.0)
    assert [e.type for e in r.equilibria] == ["attractor", "saddle"]
    sink, saddle = r.equilibria
    np.testing.assert_allclose(sink.location, [-2.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(saddle.location, [-1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(sink.eigenvalues, [[-2.0, 0.0], [-1.0, 0.0]], atol=1e-6)
    np.testing.assert_allclose(saddle.eigenvalues, [[-1.0, 0.0], [1.0, 0.0]], atol=1e-6)
    assert sink.in_box and saddle.in_box and sink.residual < 1e-8 and saddle.residual < 1e-8
    # the starts left of the saddle's stable manifold z_1 = -1 end at the sink, the others at the goal
    x1 = np.linspace(-3.0, 1.0, GRID_PER_AXIS[2])
    left = float(np.mean(x1 < -1.0))
    assert sink.basin == pytest.approx(left, abs=1e-9) and r.goal_fraction == pytest.approx(1 - left, abs=1e-9)
    assert saddle.basin == 0.0 and r.escaped_fraction == 0.0 and r.other_fraction == 0.0 and not r.orbits
    assert not r.clean and r.spurious_attractors == [sink] and r.failures() == ["1 spurious attractor"]
    assert r.method["seeds"] == "grid" and r.method["n_starts"] == GRID_PER_AXIS[2] ** 2
    text = r.summary()
    assert "attractor at (-2, " in text and "saddle at (-1, " in text and "eigenvalues -2, -1 /s" in text


def test_a_limit_cycle_is_found_with_its_period() -> None:
    r = find_equilibria(hopf_field(1.0), np.array([-3.0, -3.0]), np.array([3.0, 3.0]), duration=5.0)
    assert not r.equilibria and len(r.orbits) == 1 and not r.clean and r.failures() == ["1 closed orbit"]
    (orbit,) = r.orbits
    assert orbit.period == pytest.approx(2 * math.pi, rel=0.02)
    assert np.linalg.norm(orbit.point) == pytest.approx(2.0, abs=1e-3)
    assert orbit.size == pytest.approx(4.0, rel=0.01)                       # the circle's diameter
    path = np.asarray(orbit.path)
    np.testing.assert_allclose(np.linalg.norm(path, axis=1), 2.0, atol=1e-3)
    # inside the repelling circle r = 1 the starts go to the goal, outside it onto the cycle
    axis = np.linspace(-3.0, 3.0, GRID_PER_AXIS[2])
    inside = float(np.mean(np.hypot(*np.meshgrid(axis, axis)) < 1.0))
    assert r.goal_fraction == pytest.approx(inside, abs=1e-9) and orbit.basin == pytest.approx(1 - inside, abs=1e-9)


def test_a_contracting_field_is_clean_and_an_expanding_one_escapes() -> None:
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    sink = find_equilibria(linear_field(np.array([[-1.0, 2.0], [-2.0, -1.0]]), np.zeros(2)), lo, hi, 3.0)
    assert sink.clean and sink.goal_fraction == 1.0 and not sink.equilibria and not sink.failures()
    assert "no equilibrium or closed orbit besides the goal" in sink.summary()
    saddle = find_equilibria(linear_field(np.diag([-1.0, 1.0]), np.zeros(2)), lo, hi, 3.0)
    # only the starts on the stable axis x2 = 0 stay (a 16-point grid has none): every start escapes
    assert saddle.escaped_fraction == 1.0 and not saddle.clean and "escape" in saddle.failures()[0]


def test_six_dimensions_take_sobol_seeds() -> None:
    lo, hi = np.full(6, -3.0), np.full(6, 1.0)
    r = find_equilibria(bistable_field(6), lo, hi, duration=5.0)
    assert r.method["seeds"] == "sobol" and r.method["n_starts"] == SOBOL_SEEDS
    types = {e.type: e for e in r.equilibria}
    np.testing.assert_allclose(types["attractor"].location, [-2.0, 0, 0, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(types["saddle"].location, [-1.0, 0, 0, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(types["saddle"].eigenvalues)[:, 0], [-1] * 5 + [1], atol=1e-6)
    assert types["attractor"].basin == pytest.approx(0.5, abs=0.08)          # z_1 < -1: half the box


def test_a_node_with_hand_set_weights(spiral: lfd.DemoSet) -> None:
    field = bistable_node(spiral)
    s, g = field.norm.scale, field.goal
    r = find_equilibria(field, *search_box(field))
    sink, saddle = r.equilibria
    np.testing.assert_allclose(sink.location, g + s * np.array([-1.0, 0.0]), atol=1e-6)
    np.testing.assert_allclose(saddle.location, g + s * np.array([-0.5, 0.0]), atol=1e-6)
    slope = -4 / math.cosh(4) ** 2 - 4 + 4 * C / math.cosh(2) ** 2          # d f_1 / d u at u = -1
    np.testing.assert_allclose(sink.eigenvalues, [[-4.0, 0.0], [slope, 0.0]], atol=1e-6)
    # the benchmarks' summary: JSON-able counts, locations and basins
    summary = equilibria_summary(field, spiral)
    assert json.loads(json.dumps(summary)) == summary
    assert (summary["spurious_attractors"], summary["equilibria"], summary["closed_orbits"]) == (1, 2, 0)
    assert summary["clean"] is False and summary["points"][0]["type"] == "attractor"
    assert summary["points"][0]["basin"] == pytest.approx(sink.basin)
    assert summary["goal_fraction"] + summary["points"][0]["basin"] == pytest.approx(1.0)


def test_the_tracking_view_and_a_pose_field_have_none(spiral: lfd.DemoSet) -> None:
    field = lfd.train("tracking", spiral, seed=0)
    r = find_equilibria(field, *search_box(field), duration=float(spiral.t[0, -1]))
    assert r.clean and r.goal_fraction == 1.0 and not r.equilibria
    d = lfd.load_demos("robottasks:pouring")
    poses = lfd.DemoSet(d.t[:3, ::4], d.x[:3, ::4], name="pouring-small", q=d.q[:3, ::4])
    pose = lfd.train("tracking", poses, seed=0)
    s = equilibria_summary(pose, poses)
    assert s["clean"] and s["goal_fraction"] == 1.0 and s["equilibria"] == 0


def test_a_time_varying_field_and_bad_boxes_are_refused(spiral: lfd.DemoSet) -> None:
    from lfd.goal import shift_goal

    field = linear_field(-np.eye(2), np.zeros(2))
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    with pytest.raises(ConfigError, match="time_varying"):
        find_equilibria(shift_goal(field, 0.5, [0.1, 0.0]), lo, hi)
    with pytest.raises(ConfigError, match="2 lower and 2 upper"):
        find_equilibria(field, np.zeros(3), np.ones(3))
    with pytest.raises(ConfigError, match="max > min"):
        find_equilibria(field, hi, lo)
    with pytest.raises(ConfigError, match="duration"):
        find_equilibria(field, lo, hi, duration=-1.0)
    with pytest.raises(ConfigError, match="no box to search"):
        search_box(field)


def test_classify_and_recurrence() -> None:
    assert classify(np.array([-1.0, -2.0])) == "attractor"
    assert classify(np.array([1.0, 2.0])) == "repeller"
    assert classify(np.array([-1.0, 2.0])) == "saddle"
    assert classify(np.array([1j, -1j])) == "centre-like"
    assert classify(np.array([-1.0, 1e-9])) == "centre-like"
    t = np.linspace(0.0, 10.0, 1001)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    assert recurrence(circle, t, 0.01) == pytest.approx(2 * math.pi, abs=0.011)
    assert recurrence(np.stack([t, t], axis=1), t, 0.01) is None             # a straight line never returns
    spiral_in = circle * np.exp(-t)[:, None]
    assert recurrence(spiral_in, t, 1e-4) is None                            # a focus: never back within 5%
