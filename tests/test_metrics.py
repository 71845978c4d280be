"""Known answers of every metric in lfd.metrics."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.distance import cdist

from lfd.demos import DemoSet
from lfd.evaluation import converged_fraction, evaluate, reproduce
from lfd.field import VelocityField
from lfd.metrics import (
    PER_DEMO_METRICS,
    chamfer_dtwd,
    convergence_rate,
    cosine_error,
    dtw,
    final_goal_distance,
    frechet,
    resample,
    rmse,
    swept_area,
    velocity_rmse,
)
from lfd.normalization import Normalization


def line(n: int = 101, length: float = 2.0, c: float = 0.0) -> np.ndarray:
    """n samples of the segment from (0, c) to (length, c), shape (n, 2)."""
    return np.stack([np.linspace(0.0, length, n), np.full(n, c)], axis=1)


def curve(n: int = 200) -> np.ndarray:
    """A planar S-curve, shape (n, 2)."""
    s = np.linspace(0.0, 1.0, n)
    return np.stack([s * 3.0, np.sin(2 * np.pi * s)], axis=1)


def warping_recursion(c: np.ndarray, combine) -> float:  # type: ignore[no-untyped-def]
    """The textbook double loop, as a reference for the vectorised recursion."""
    n, m = c.shape
    D = np.full((n, m), np.inf)
    for i in range(n):
        for j in range(m):
            prev = 0.0 if i == j == 0 else min(
                D[i - 1, j - 1] if i and j else np.inf, D[i - 1, j] if i else np.inf,
                D[i, j - 1] if j else np.inf)
            D[i, j] = combine(c[i, j], prev) if (i or j) else c[0, 0]
    return float(D[-1, -1])


@pytest.mark.parametrize("metric", [rmse, dtw, chamfer_dtwd, frechet, swept_area])
def test_curve_against_itself_is_zero(metric) -> None:  # type: ignore[no-untyped-def]
    a = curve()
    assert metric(a, a.copy()) == pytest.approx(0.0, abs=1e-12)


def test_shifted_line_known_values() -> None:
    n, L, c = 101, 2.0, 0.3
    a, b = line(n, L), line(n, L, c)
    assert rmse(a, b) == pytest.approx(c, rel=1e-12)
    # every monotone path has >= n cells, each at distance >= c; the diagonal has exactly n at c
    assert dtw(a, b) == pytest.approx(n * c, rel=1e-12)
    assert frechet(a, b) == pytest.approx(c, rel=1e-12)
    assert chamfer_dtwd(a, b) == pytest.approx(2 * c, rel=1e-12)  # c from a to b plus c from b to a
    assert swept_area(a, b) == pytest.approx(L * c, rel=1e-12)


def test_dtw_step_keeps_every_kth_sample() -> None:
    a, b = line(1000, 2.0), line(1000, 2.0, 0.1)
    assert dtw(a, b, step=4) == pytest.approx(250 * 0.1, rel=1e-12)
    with pytest.raises(ValueError):
        dtw(a, b, step=0)


def test_swept_area_of_a_triangle() -> None:
    # between the x-axis and the chord from (0, c) to (L, 0): L c / 2, exactly, for any sampling
    L, c = 3.0, 0.8
    a = line(57, L)
    b = np.stack([a[:, 0], c * (1 - a[:, 0] / L)], axis=1)
    assert swept_area(a, b) == pytest.approx(L * c / 2, rel=1e-12)
    with pytest.raises(ValueError):
        swept_area(np.zeros((5, 3)), np.zeros((5, 3)))


def test_time_warped_copy_has_zero_dtw_but_positive_rmse() -> None:
    a = curve(100)
    counts = np.where(np.arange(100) < 50, 3, 1)  # the first half is slowed down three times
    b = a[np.repeat(np.arange(100), counts)]      # same path, every sample visited, 200 samples
    assert dtw(a, b) == 0.0
    assert frechet(a, b) == 0.0
    assert chamfer_dtwd(a, b) == 0.0
    assert rmse(a, b) > 0.1


def test_reversed_curve_separates_chamfer_from_dtw_and_frechet() -> None:
    L = 2.0
    a = line(201, L)
    r = a[::-1]
    assert chamfer_dtwd(a, r) == pytest.approx(0.0, abs=1e-12)
    # the coupling starts at (a_0, r_0), L apart, and no pair is farther apart than L
    assert frechet(a, r) == pytest.approx(L, rel=1e-12)
    assert dtw(a, r) > 50.0


@pytest.mark.parametrize("n,m", [(1, 1), (1, 7), (9, 1), (13, 21), (30, 17)])
def test_dp_matches_textbook_recursion(n: int, m: int) -> None:
    rng = np.random.default_rng(n * 100 + m)
    a, b = rng.normal(size=(n, 3)), rng.normal(size=(m, 3))
    c = cdist(a, b)
    assert dtw(a, b) == pytest.approx(warping_recursion(c, lambda x, y: x + y), rel=1e-12)
    assert frechet(a, b) == pytest.approx(warping_recursion(c, max), rel=1e-12)
    assert dtw(a, b) == pytest.approx(dtw(b, a), rel=1e-12)


def test_different_lengths_resample_in_sample_index() -> None:
    a, b = line(101), line(401)
    assert rmse(a, b) == pytest.approx(0.0, abs=1e-12)  # linear interpolation of a line is exact
    assert swept_area(a, b) == pytest.approx(0.0, abs=1e-12)
    assert resample(np.arange(5.0)[:, None], 9)[:, 0] == pytest.approx(np.arange(9) / 2)
    with pytest.raises(ValueError, match="dimension"):
        rmse(np.zeros((5, 2)), np.zeros((5, 3)))


def test_velocity_metrics() -> None:
    rng = np.random.default_rng(0)
    v = rng.normal(size=(50, 2))
    perp = np.stack([-v[:, 1], v[:, 0]], axis=1)
    assert velocity_rmse(v + np.array([0.0, 0.4]), v) == pytest.approx(0.4, rel=1e-12)
    assert velocity_rmse(v.reshape(5, 10, 2), v.reshape(5, 10, 2)) == 0.0
    assert cosine_error(3 * v, v) == pytest.approx(0.0, abs=1e-12)   # speed does not matter
    assert cosine_error(-v, v) == pytest.approx(2.0, rel=1e-12)
    assert cosine_error(perp, v) == pytest.approx(1.0, rel=1e-12)
    assert cosine_error(np.zeros_like(v), v) == pytest.approx(1.0, rel=1e-12)
    # demo samples at rest (e.g. at the goal) have no direction and are left out
    v_rest = np.concatenate([v, np.zeros((10, 2))])
    f_rest = np.concatenate([v, rng.normal(size=(10, 2))])
    assert cosine_error(f_rest, v_rest) == pytest.approx(0.0, abs=1e-12)
    assert np.isnan(cosine_error(v, np.zeros_like(v)))  # a demo at rest has no direction
    with pytest.raises(ValueError):
        velocity_rmse(v, v[:-1])


def test_goal_distance_and_convergence_rate() -> None:
    goal = np.array([1.0, 2.0])
    traj = np.stack([np.linspace(0, 1, 20), np.linspace(0, 2, 20)], axis=1) + [0.3, 0.4]
    assert final_goal_distance(traj, goal) == pytest.approx(0.5, rel=1e-12)
    batch = np.stack([traj, traj - [0.3, 0.4]])
    assert final_goal_distance(batch, goal) == pytest.approx([0.5, 0.0], abs=1e-12)
    finals = goal + np.array([[0.0, 0.05], [0.0, 0.2], [np.nan, 0.0], [0.08, 0.0]])
    assert convergence_rate(finals, goal, radius=0.1) == pytest.approx(0.5)


class CubicModule(torch.nn.Module):
    """dx1/dt = -x1 + x1^3, dx2/dt = -x2: the origin attracts exactly the strip |x1| < 1."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.stack([-x[:, 0] + x[:, 0] ** 3, -x[:, 1]], dim=1)


def test_converged_fraction_matches_the_basin() -> None:
    field = VelocityField(CubicModule(), Normalization(np.zeros(2), 1.0), "cubic", {})
    lo, hi, n, seed = np.array([-2.0, -1.0]), np.array([2.0, 1.0]), 300, 7
    frac = converged_fraction(field, lo, hi, n, horizon=12.0, radius=0.05, seed=seed, n_steps=600)
    x0 = np.random.default_rng(seed).uniform(lo, hi, size=(n, 2))
    inside = np.mean(np.abs(x0[:, 0]) < 1.0)
    assert 0.3 < inside < 0.7
    assert abs(frac - inside) <= 0.02  # only starts within ~1e-2 of |x1| = 1 are too slow
    again = converged_fraction(field, lo, hi, n, horizon=12.0, radius=0.05, seed=seed, n_steps=600)
    assert again == frac


def test_converged_fraction_of_stable_linear_field(spiral_field_2d: VelocityField,
                                                   make_linear_field) -> None:  # type: ignore[no-untyped-def]
    g = spiral_field_2d.goal
    assert converged_fraction(spiral_field_2d, g - 2, g + 2, 50, horizon=10.0, radius=1e-3) == 1.0
    unstable = make_linear_field(np.eye(2), g)
    assert converged_fraction(unstable, g - 2, g + 2, 50, horizon=10.0, radius=1e-3) == 0.0


def test_evaluate_reproduces_its_own_rollouts(spiral_field_2d: VelocityField) -> None:
    """Demos that ARE the field's rollouts score ~0 on every position metric."""
    g = spiral_field_2d.goal
    t = np.linspace(0.0, 8.0, 400)
    x0 = g + np.array([[1.0, 0.0], [0.0, 1.2], [-0.8, -0.5]])
    demos = DemoSet(t, spiral_field_2d.rollout(x0, t), name="own")
    result = evaluate(spiral_field_2d, demos, dtw_step=2)
    assert list(result["mean"]) == list(PER_DEMO_METRICS)
    assert len(result["per_demo"]) == 3
    for name in ("rmse", "dtw", "chamfer_dtwd", "frechet", "swept_area"):
        assert result["mean"][name] < 1e-9, name
    assert result["mean"]["final_goal_distance"] < 1e-3
    # smoothed finite-difference velocities against exact field values
    assert result["mean"]["velocity_rmse"] < 0.01
    assert result["mean"]["cosine_error"] < 1e-3


def test_evaluate_scores_a_wrong_field(spiral_field_2d: VelocityField,
                                       make_linear_field) -> None:  # type: ignore[no-untyped-def]
    g = spiral_field_2d.goal
    t = np.linspace(0.0, 8.0, 400)
    demos = DemoSet(t, spiral_field_2d.rollout(g + np.array([[1.0, 0.0]]), t), name="own")
    mirrored = make_linear_field(np.array([[-1.0, -3.0], [3.0, -1.0]]), g)  # turns the other way
    row = evaluate(mirrored, demos)["per_demo"][0]
    assert row["rmse"] > 0.2 and row["frechet"] > 0.5 and row["cosine_error"] > 0.5
    assert row["final_goal_distance"] < 1e-3  # it still reaches the goal
    with pytest.raises(ValueError, match="3-D"):
        evaluate(make_linear_field(-np.eye(3), np.zeros(3)), demos)


def test_reproduce_batches_without_changing_rollouts(spiral_field_2d: VelocityField) -> None:
    """Demos on different uniform grids (batched in sample units) and on non-uniform grids
    (one rollout per distinct grid) give the same rollouts as one field.rollout per demo."""
    g = spiral_field_2d.goal
    x0 = g + np.array([[1.0, 0.0], [0.0, 1.2], [-0.8, -0.5]])
    uniform = np.stack([np.linspace(0.0, T, 120) for T in (6.0, 7.0, 8.0)])
    warped = np.stack([8.0 * np.linspace(0.0, 1.0, 120) ** p for p in (1.2, 1.5, 1.5)])
    for t in (uniform, warped):
        demos = DemoSet(t, np.stack([spiral_field_2d.rollout(x, ti) for x, ti in zip(x0, t)]))
        expected = np.stack([spiral_field_2d.rollout(x[0], ti) for x, ti in zip(demos.x, t)])
        assert np.abs(reproduce(spiral_field_2d, demos) - expected).max() < 1e-12


def test_huge_warping_tables_are_refused_before_allocation() -> None:
    """DTW of two 10^6-sample curves once asked for 298 GiB; now a ValueError, and ``evaluate``
    subsamples (``dtw_step_for``) to stay under MAX_DTW_CELLS."""
    from lfd.metrics import MAX_DP_CELLS, MAX_DTW_CELLS, dtw_step_for

    n = int(MAX_DP_CELLS ** 0.5) + 1
    a = np.zeros((n, 2))
    with pytest.raises(ValueError, match="warping table is too large"):
        dtw(a, a)
    with pytest.raises(ValueError, match="warping table is too large"):
        frechet(a, a)
    assert dtw(a, a, step=dtw_step_for(n, n)) == pytest.approx(0.0, abs=1e-12)
    k = dtw_step_for(10**6, 10**6)
    assert (-(-10**6 // k)) ** 2 <= MAX_DTW_CELLS < (-(-10**6 // (k - 1))) ** 2
