"""The LASA report's metric definitions: swept area by lobes, DTW per sample, the
std-normalised closest-point distance, the 35 x 35 spurious-attractor grid, each demo on its own
clock. ``similaritymeasures`` (a test-only dependency, in the dev extra) is the cross-check.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.linalg import expm

import lfd
from lfd import metrics as M
from lfd.bench import protocol as P
from lfd.bench import report as R
from lfd.bench.fields import FieldModel
from lfd.bench.lasa import LABELS, METRICS, LasaSuite, spurious_grid
from lfd.bench.spaces import POSITIONS
from lfd.bench.summary import per_unit, summarize
from lfd.demos import lasa

sm = pytest.importorskip("similaritymeasures")


def zigzag(n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """A straight line y = 0 and a curve zig-zagging +-1 around it, both sampled at x = 0..n-1."""
    x = np.arange(float(n))
    return np.stack([x, np.zeros(n)], 1), np.stack([x, (-1.0) ** np.arange(n)], 1)


def shoelace_areas(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The old definition, |signed area| of each quadrilateral (a difference of lobes when crossed)."""
    q = np.stack([a[:-1], a[1:], b[1:], b[:-1]], axis=1)
    x, y = q[..., 0], q[..., 1]
    return np.abs(np.sum(x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y, axis=1)) / 2


def test_zigzag_swept_area_is_the_sum_of_the_lobes() -> None:
    line, zz = zigzag()
    assert shoelace_areas(zz, line).sum() == pytest.approx(0.0, abs=1e-12)   # the old under-count
    assert M.swept_area(zz, line) == pytest.approx(49.5, rel=1e-12)          # 99 bow-ties of 2 x 0.25
    assert M.swept_area(line, zz) == pytest.approx(49.5, rel=1e-12)
    assert sm.area_between_two_curves(zz, line) == pytest.approx(99.0, rel=1e-9)


def test_crossing_rungs_count_both_lobes() -> None:
    a = np.array([[0.0, 0.0], [2.0, 0.0]])
    b = np.array([[2.0, 1.0], [0.0, 1.0]])      # b runs the other way: the rungs cross at (1, 0.5)
    assert M.swept_area(a, b) == pytest.approx(1.0, rel=1e-12)   # two triangles, base 2, height 0.5
    assert shoelace_areas(a, b).sum() == pytest.approx(0.0, abs=1e-12)


def test_swept_area_agrees_with_similaritymeasures_where_nothing_crosses() -> None:
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 3.0, 200)
    a = np.stack([t, np.sin(t)], 1)
    b = a + np.array([0.0, 0.3]) + 0.05 * rng.uniform(size=(200, 2)) * np.array([0.0, 1.0])
    assert M.swept_area(a, b) == pytest.approx(sm.area_between_two_curves(a, b), rel=1e-9)


@pytest.mark.parametrize("shape, i", [("heee", 5), ("BendedLine", 1), ("Angle", 3)])
def test_swept_area_on_lasa_pairs_never_under_counts(shape: str, i: int) -> None:
    """Demo i against demo 0 of a shape. heee 5 and BendedLine 1 are the pairs with the lowest ratio
    to similaritymeasures over all 30 shapes x 6 pairs (0.576, 0.578; median 0.996, max 1.000)."""
    d = lasa(shape)
    a, b = d.x[i], d.x[0]
    ours, theirs = M.swept_area(a, b), sm.area_between_two_curves(a, b)
    assert ours >= shoelace_areas(a, b).sum() - 1e-9                 # never below the old definition
    assert ours <= theirs * (1 + 1e-9)                                # lobes <= re-ordered quadrilaterals
    assert ours >= 0.55 * theirs
    per_quad = M._quad_areas(a[:-1], a[1:], b[1:], b[:-1])
    assert np.all(per_quad >= shoelace_areas(a, b) - 1e-9)


@pytest.mark.parametrize("shape", ["Angle", "heee"])
def test_dtw_and_frechet_match_similaritymeasures(shape: str) -> None:
    d = lasa(shape)
    a, b = d.x[2, ::4], d.x[5, ::4]           # 250 samples each: similaritymeasures loops in Python
    ref_dtw = sm.dtw(a, b)[0]
    assert M.dtw(a, b) == pytest.approx(ref_dtw, rel=1e-9)
    assert M.dtw(d.x[2], d.x[5], step=4) == pytest.approx(ref_dtw, rel=1e-9)
    assert M.dtw_per_sample(a, b) == pytest.approx(ref_dtw / len(b), rel=1e-9)
    assert M.frechet(a, b) == pytest.approx(sm.frechet_dist(a, b), rel=1e-9)


def test_chamfer_std_is_chamfer_on_standardised_data() -> None:
    d = lasa("Sine")
    a, b = d.x[1], d.x[4]
    std = d.x.reshape(-1, 2).std(axis=0)
    value = M.chamfer_dtwd_std(a, b, std)
    assert value == pytest.approx(M.chamfer_dtwd(a / std, b / std), rel=1e-12)
    k = np.array([3.0, 0.5])                 # units do not matter: scale the data and its std alike
    assert M.chamfer_dtwd_std(a * k, b * k, std * k) == pytest.approx(value, rel=1e-9)
    assert M.chamfer_dtwd_std(a, b) == pytest.approx(M.chamfer_dtwd(a / b.std(0), b / b.std(0)), rel=1e-12)
    with pytest.raises(ValueError, match="std"):
        M.chamfer_dtwd_std(a, b, np.array([1.0, 0.0]))


def test_grid_starts_cover_the_demo_box() -> None:
    d = lasa("Angle")
    g = P.grid_starts(d, P.LasaProtocol())
    lo, hi = d.bounds()
    assert g.shape == (35 * 35, 2)
    np.testing.assert_allclose(g.min(0), lo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g.max(0), hi, rtol=0, atol=1e-12)
    assert len(np.unique(g[:, 0])) == 35 and len(np.unique(g[:, 1])) == 35
    final = np.array([[0.0, 0.0], [0.5, 0.0], [3.0, 0.0], [np.nan, 0.0]])
    assert M.spurious_attractor_fraction(final, np.zeros(2), 1.0) == pytest.approx(0.5)


class Linear(torch.nn.Module):
    """f_n(x) = A x, a stable spiral sink; with ``dead`` set, f_n = 0 where x_1 < -0.5 (a half-plane
    of spurious equilibria, away from the goal at 0)."""

    def __init__(self, dead: bool = False) -> None:
        super().__init__()
        self.A = torch.nn.Parameter(torch.tensor([[-1.5, -2.0], [2.0, -1.5]], dtype=torch.float64))
        self.dead = dead

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        v = x @ self.A.T
        return v * (x[:, :1] >= -0.5) if self.dead else v


def linear_model(demos: lfd.DemoSet, dead: bool = False) -> FieldModel:
    norm = lfd.Normalization.from_points(demos.x, demos.goal)
    return FieldModel(lfd.VelocityField(Linear(dead), norm, "node", {}), POSITIONS)


def test_each_demo_is_rolled_out_on_its_own_clock() -> None:
    d = lasa("Angle")
    durations = d.t[:, -1] - d.t[:, 0]
    assert np.ptp(durations) > 0.5                   # Angle: 2.45 to 3.22 s
    model = linear_model(d)
    y, _ = model.reproduce(d.x, d.t)
    A, s, g = model.field.module.A.numpy(), model.field.norm.scale, d.goal
    for i in (int(np.argmin(durations)), int(np.argmax(durations))):
        xn0 = (d.x[i, 0] - g) / s
        exact = np.stack([expm(A * (tk - d.t[i, 0])) @ xn0 for tk in d.t[i, ::111]]) * s + g
        np.testing.assert_allclose(y[i, ::111], exact, atol=1e-4)      # mm; dopri5 at tol 1e-6


def test_score_reports_every_definition_and_the_grid_counts_spurious_starts() -> None:
    d = lasa("Angle").subset([0, 1])
    ys, vs = linear_model(d).reproduce(d.x, d.t)
    per = LasaSuite(P.LasaProtocol()).score(ys, vs, d, [0, 1], d.goal)
    assert set(per) == set(METRICS) and ys.shape == d.x.shape
    assert {"dtw", "dtw_per_sample", "chamfer_dtwd", "chamfer_dtwd_std", "frechet", "rmse",
            "swept_area"} <= set(per)
    for m in METRICS:
        assert all(np.isfinite(v) and v >= 0 for v in per[m]), m
    assert per["dtw_per_sample"][0] == pytest.approx(M.dtw(ys[0], d.x[0]) / d.n_samples, rel=1e-12)
    protocol = P.LasaProtocol(spurious_grid=9)
    assert spurious_grid(linear_model(d), d, protocol) == 0.0
    starts = P.grid_starts(d, protocol)
    dead = (starts[:, 0] - d.goal[0]) / linear_model(d).field.norm.scale < -0.5
    assert 0 < dead.mean() < 1
    frac = spurious_grid(linear_model(d, dead=True), d, protocol)
    # starts in the dead half-plane never move; the others spiral in, some crossing into it
    assert frac >= dead.mean() - 1e-12 and frac < 1.0


def test_report_carries_every_definition_and_the_grid() -> None:
    suite = LasaSuite(P.LasaProtocol())

    def record(learner: str, shape: str, spurious: float | None) -> dict:
        conv = {"rate": 1.0, "demo": 1.0, "ring": 1.0, "box": 1.0, "n_demo": 7, "n_ring": 56, "n_box": 64,
                "spurious_grid": spurious, "n_grid": 0 if spurious is None else 1225}
        return {"learner": learner, "shape": shape, "seed": 0, "split": "in-sample", "fold": None,
                "metrics": {m: 1.0 + i for i, m in enumerate(METRICS)}, "convergence": conv, "train_time_s": 1.0,
                "step_time_us": 10.0, "cell_s": 2.0, "integrators": {}}

    records = [record("node", "Angle", 0.1), record("node", "Sine", 0.15), record("dmp", "Angle", None)]
    summary = summarize(suite, records, ["node", "dmp"])
    assert summary["node"]["in-sample"]["spurious"]["mean"] == pytest.approx(0.125)
    assert summary["dmp"]["in-sample"]["spurious"] is None and summary["dmp"]["held-out"] is None
    table = R.summary_table(suite, summary, "in-sample")
    for m in ("dtw", "dtw_per_sample", "chamfer_dtwd_std", "frechet", "rmse", "swept_area"):
        assert LABELS[m] in table
    assert "spurious (35×35 grid)" in table and "12.5% / 12.5%" in table
    rows = R.unit_table(suite, per_unit(suite, records, "node", "in-sample"), ["Angle", "Sine"], "in-sample")
    assert "| Angle |" in rows and "10.0%" in rows and "15.0%" in rows
    assert "| — |" in R.unit_table(suite, per_unit(suite, records, "dmp", "in-sample"), ["Angle"], "in-sample")
