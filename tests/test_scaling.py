"""The scaling curves' library parts (lfd.bench.scaling, sim.studies.scaling_control) and the options of their report
(``sim.studies.scaling``, scripts/scaling.py).

Cheap: no learner is trained and nothing is timed (the measurement itself is replaced where a test
needs one); the LASA shapes are read from the wheel's data.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_runs import run_main

import lfd
from lfd.bench import scaling
from lfd.bench.scaling import (
    STACK_SHAPES,
    Point,
    block_errors,
    cached_measure,
    curve_points,
    fit_exponent,
    resample_demos,
    stacked_lasa,
)
from sim.studies import scaling as study

# ---------------------------------------------------------------- stacking LASA shapes

@pytest.mark.parametrize("dim", [2, 4, 8])
def test_stacked_lasa_holds_the_shapes_coordinates_block_by_block(dim: int) -> None:
    demos = stacked_lasa(dim)
    assert demos.x.shape == (7, 1000, dim)
    assert demos.name == "lasa-stack:" + "+".join(STACK_SHAPES[:dim // 2])
    for k, shape in enumerate(STACK_SHAPES[:dim // 2]):
        source = lfd.lasa(shape)   # 7 demos of 1000 samples: resampling to 1000 keeps every sample
        np.testing.assert_allclose(demos.x[..., 2 * k:2 * k + 2], source.x, rtol=0, atol=1e-9 * source.extent)


def test_stacked_lasa_shares_one_clock_and_the_goal() -> None:
    demos = stacked_lasa(4, n_demos=3, n_samples=250)
    assert demos.x.shape == (3, 250, 4)
    np.testing.assert_array_equal(demos.t, np.broadcast_to(demos.t[0], demos.t.shape))
    assert demos.t[0, 0] == 0.0
    durations = [lfd.lasa(s).subset([0, 1, 2]).t for s in STACK_SHAPES[:2]]
    assert demos.t[0, -1] == pytest.approx(np.mean([t[:, -1] - t[:, 0] for t in durations]))
    ends = np.concatenate([lfd.lasa(s).x[:3, -1] for s in STACK_SHAPES[:2]], axis=1)
    np.testing.assert_array_equal(demos.x[:, -1], ends)


def test_stacked_lasa_uses_the_first_demos_of_each_shape() -> None:
    demos = stacked_lasa(2, n_demos=2)
    np.testing.assert_allclose(demos.x, lfd.lasa(STACK_SHAPES[0]).x[:2], atol=1e-9 * demos.extent)


@pytest.mark.parametrize("bad", [{"dim": 3}, {"dim": 0}, {"dim": 2 * len(STACK_SHAPES) + 2}, {"dim": 2, "n_demos": 8},
                                 {"dim": 2, "n_demos": 0}])
def test_stacked_lasa_refuses_impossible_sizes(bad: dict[str, int]) -> None:
    with pytest.raises(ValueError):
        stacked_lasa(**bad)


def test_the_shapes_are_sixteen_distinct_single_pattern_shapes() -> None:
    assert len(STACK_SHAPES) == 16 == len(set(STACK_SHAPES))
    assert not any(s.startswith("Multi_Models") for s in STACK_SHAPES)


def test_resample_keeps_the_ends_and_a_cubic_exactly() -> None:
    t = np.linspace(0.0, 2.0, 40)
    x = np.stack([t ** 3 - t, 2 * t ** 2 + 1], axis=1)
    x = x - x[-1]   # end at the origin, as demos must share a goal
    demos = lfd.DemoSet(t, x)
    t_out, x_out = resample_demos(demos, 97)
    assert t_out.shape == (1, 97) and x_out.shape == (1, 97, 2)
    np.testing.assert_array_equal(x_out[0, [0, -1]], x[[0, -1]])
    tt = t_out[0]
    expected = np.stack([tt ** 3 - tt, 2 * tt ** 2 + 1], axis=1) - (np.array([2.0 ** 3 - 2.0, 9.0]))
    np.testing.assert_allclose(x_out[0], expected, atol=1e-9)   # not-a-knot splines reproduce cubics


# ---------------------------------------------------------------- exponents and errors

def test_fit_exponent_of_a_power_law() -> None:
    x = np.array([2.0, 4.0, 8.0, 16.0, 32.0])
    b, c = fit_exponent(x, 3.0 * x ** 1.5)
    assert b == pytest.approx(1.5, abs=1e-12)
    assert c == pytest.approx(3.0, rel=1e-12)


def test_fit_exponent_leaves_out_points_without_a_logarithm() -> None:
    x = [0.0, 1.0, 2.0, 4.0, 8.0]
    y = [5.0, 2.0, 2.0 * 2 ** -0.5, 1.0, float("nan")]
    assert fit_exponent(x, y)[0] == pytest.approx(-0.5, abs=1e-12)
    assert np.isnan(fit_exponent([1.0, 1.0], [2.0, 3.0])[0])
    assert np.isnan(fit_exponent([1.0, 2.0], [0.0, -1.0])[0])


def test_block_errors_score_each_shape_alone() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 50, 4))
    assert block_errors(x, x) == (0.0, 0.0)
    y = x.copy()
    y[..., 0] += 1.0                   # block 0 off by 1 everywhere, block 1 exact
    rmse, dtw = block_errors(y, x)
    assert rmse == pytest.approx(0.5)  # (1 + 0) / 2 blocks
    assert 0.0 < dtw <= 0.5
    y[0, 3, 2] = np.inf
    assert block_errors(y, x) == (np.inf, np.inf)


# ---------------------------------------------------------------- points and the cache

def test_curve_points_vary_one_size_at_the_base_of_the_others() -> None:
    dims = curve_points("contraction", "dim")
    assert [(p.dim, p.n_demos, p.n_samples) for p in dims] == [(d, 7, 1000) for d in (2, 4, 8, 16, 32)]
    assert [p.n_demos for p in curve_points("node", "demos")] == list(range(1, 8))
    assert [p.n_samples for p in curve_points("dmp", "samples")] == [250, 500, 1000, 2000, 4000]
    base = {p for c in ("dim", "demos", "samples") for p in curve_points("tracking", c)}
    assert len(base) == 5 + 7 + 5 - 2   # (2, 7, 1000) is on all three curves
    p, q = curve_points("node", "dim", {"iterations": 5}, [2])[0], curve_points("node", "dim", None, [2])[0]
    assert p.stem == "node_d2_n7_t1000_iterations5" and q.stem == "node_d2_n7_t1000"
    assert p.key() != q.key()


def test_cached_measure_measures_once_then_reads_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, tuple[int, ...], int]] = []

    def fake(learner: str, demos: lfd.DemoSet, options: dict[str, Any], truth: lfd.DemoSet) -> dict[str, Any]:
        calls.append((learner, demos.x.shape, truth.n_samples))
        return {"train_cpu_s": 1.0, "rmse": 2.0}

    monkeypatch.setattr(scaling, "measure", fake)
    point = Point("dmp", 4, 3, 250)
    rec, new = cached_measure(point, tmp_path)
    assert new and calls == [("dmp", (3, 250, 4), 1000)]   # scored against the 1000-sample demos
    assert rec["train_cpu_s"] == 1.0 and rec["dim"] == 4 and rec["key"] == point.key()
    again, new = cached_measure(point, tmp_path)
    assert not new and len(calls) == 1 and again["rmse"] == 2.0
    (tmp_path / f"{point.stem}.json").write_text("{ torn")   # a broken file is measured again
    _, new = cached_measure(point, tmp_path)
    assert new and len(calls) == 2


# ---------------------------------------------------------------- obstacles off the path

def test_off_path_spheres_lie_beyond_the_demos_and_apart() -> None:
    from sim.studies.scaling_control import off_path_spheres

    demos = lfd.spiral()
    base = np.array([-6.0, 0.5])
    margin = 0.3
    spheres = off_path_spheres(demos, 16, base, margin=margin)
    assert len(spheres) == 16 and off_path_spheres(demos, 0, base) == []
    pts = demos.x.reshape(-1, 2)
    for s in spheres:
        clearance = np.linalg.norm(pts - s.center, axis=1).min() - (s.radius + margin)
        assert clearance > 0.5 * demos.extent * 0.05
        assert np.dot(s.center - pts.mean(0), pts.mean(0) - base) > 0   # on the far side from the base
    centres = np.array([s.center for s in spheres])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.eye(16) * 1e9
    assert gaps.min() > 2 * (spheres[0].radius + margin)              # grown spheres never merge
    first = off_path_spheres(demos, 4, base, margin=margin)
    np.testing.assert_array_equal([s.center for s in first], centres[:4])   # a larger K adds spheres


# ---------------------------------------------------------------- the script's options

#: what the one line says -> the options that make the report command say it
BAD_OPTIONS: dict[str, list[str]] = {
    "unknown learner(s) gmm": ["--learners", "gmm"],
    "--repeats must be between 1 and 100": ["--repeats", "0"],
    "not a positive integer": ["--iterations", "node=abc"],
    "tracking learner has no iterations": ["--iterations", "tracking=5"],
    "leave nothing to do": ["--skip-learners", "--skip-control"],
    "unrecognized arguments": ["--bogus"],
}


@pytest.mark.parametrize("text, argv", BAD_OPTIONS.items())
def test_bad_options_give_one_line_and_exit_2(text: str, argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_main(study.main, argv, capsys)
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("scaling: error: ") and text in err
