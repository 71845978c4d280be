"""The LASA suite: protocol, DMP baseline, resumable parallel runner, report, and the held-out split.

One in-sample ``--quick`` run (contraction and dmp, 3 shapes, 2 workers) is shared by the module; a
second run checks resume, a third (one cell, in-process) checks determinism. One run of both splits
on one shape checks the held-out split: a field per demo trained without it, run toward its own end.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bench_runs import bench_run, refused
from records import results

from lfd.bench import protocol as P
from lfd.bench.dmp import fit_dmp, make_config
from lfd.bench.lasa import METRICS, QUICK_UNITS, LasaSuite
from lfd.bench.runner import load_arrays
from lfd.cli import main
from lfd.demos import LASA_SHAPES, lasa
from lfd.errors import ConfigError
from lfd.io import finite_or_none
from lfd.metrics import rmse

# mm, contraction on Angle at --quick (60 evaluations): DTW, since Eq. (C5) fits paths, not timing
# (a bound with room above what it scores; the full benchmark's numbers: reports/lasa.md)
ANGLE_DTW_CONTRACTION_MAX = 600.0
ANGLE_RMSE_DMP_MAX = 3.5          # mm, the DMP fitted to Angle's mean demo (just above what it scores)
QUICK_CELLS = [f"{learner}__{shape}__seed0" for learner in ("contraction", "dmp") for shape in QUICK_UNITS]
# mm: a held-out reproduction's last sample from the end of the demo it was run toward (just above what
# each reaches on Angle at --quick; every LASA demo ends at the origin, so the own end and the training
# goal coincide there: tests/test_bench_robottasks.py tells them apart)
HELD_OUT_END_MM = {"contraction": 2.0, "dmp": 0.5}


# ---------------------------------------------------------------- protocol and baseline

def test_starts_are_seeded_per_shape_and_placed_as_documented() -> None:
    demos = lasa("Angle")
    proto = P.LasaProtocol()
    a, b = P.starts(demos, "Angle", proto), P.starts(demos, "Angle", proto)
    assert a.demo.shape == (7, 2) and a.ring.shape == (56, 2) and a.box.shape == (64, 2)
    assert np.array_equal(a.all, b.all)
    lo, hi = demos.bounds()
    r = np.linalg.norm(a.ring.reshape(7, 8, 2) - demos.x[:, None, 0], axis=-1)
    np.testing.assert_allclose(r, 0.1 * np.max(hi - lo), rtol=1e-12)
    blo, bhi = demos.bounds(0.5)
    assert (a.box >= blo).all() and (a.box <= bhi).all()
    assert np.all(bhi - blo > 1.49 * (hi - lo))
    other = P.starts(lasa("Sine"), "Sine", proto)
    assert not np.allclose(other.box - other.box.mean(0), a.box - a.box.mean(0))
    assert set(a.groups()) == {"demo", "ring", "box"} and a.groups()["box"] == slice(63, 127)


def test_protocol_and_option_errors_are_config_errors() -> None:
    suite = LasaSuite(P.LasaProtocol())
    assert suite.resolve_units("all") == list(LASA_SHAPES) and len(suite.resolve_units("all")) == 30
    assert suite.resolve_units("all", quick=True) == ["Angle", "Sine", "GShape"]
    assert suite.resolve_units("Sine,Angle,Sine") == ["Sine", "Angle"]
    refusals: list[tuple[Callable[[], Any], str]] = [
        (lambda: suite.resolve_units("Angle,Circle"), "Circle"), (lambda: P.LasaProtocol(dtw_step=0), "dtw_step"),
        (lambda: make_config(weights=5), "unknown option"), (lambda: make_config(n_weights_per_dim=0), "n_weights")]
    for call, message in refusals:
        with pytest.raises(ConfigError, match=message):
            call()
    assert P.stable_hash(P.LasaProtocol().to_dict()) != P.stable_hash(P.LasaProtocol(dtw_step=2).to_dict())
    cells = suite.cells(["dmp"], {"dmp": ["Angle"]}, [0], {"dmp": {}}, ["in-sample", "held-out"])
    assert [c.stem for c in cells] == ["dmp__Angle__seed0"] + [f"dmp__Angle__seed0__out{i}" for i in range(7)]
    assert len({c.hash for c in cells}) == 8
    assert finite_or_none({"a": [1.0, float("inf")], "b": float("nan")}) == {"a": [1.0, None], "b": None}


BAD_INPUT = [   # a command line after ``lfd bench``, and what its one line of error says
    ("lasa --shapes Circle", "Circle"),
    ("lasa --learner gp", "unknown learner"),
    ("lasa --split some", "unknown split"),
    ("lasa --option contraction.nope=1", "unknown option"),
    ("lasa --option rate=1", "LEARNER.KEY=VALUE"),
    ("robottasks --tasks nosuchtask", "nosuchtask"),
    ("robottasks --learner gp", "unknown learner"),
    ("robottasks --perturbed-starts -1", "perturbed_starts"),
    ("robottasks --option dmp.int_dt=0", "int_dt"),
    ("lasa --learner dmp --executor dask", "invalid choice"),
    ("lasa --learner dmp --executor ray --address nohost", "HOST:PORT"),
    ("lasa --learner dmp --executor ray --address 10.0.0.1:99999", "HOST:PORT"),
    ("lasa --learner dmp --address 10.0.0.1:6379", "needs --executor ray"),
    ("lasa --learner dmp --executor ray --address 127.0.0.1:1", "no Ray cluster reachable"),   # probed, no ray.init
    ("lasa --learner dmp --workers 100000", "--workers"),
]


REPORT_BAD_INPUT = [   # the same for the report commands, their outputs in {out}
    ("comparison --out {out} --node-iterations 0", "--node-iterations must be >= 1"),
    ("tradeoff --out {out}/t.md --shapes Angle,Circle", "unknown LASA shape(s) Circle"),
    ("tradeoff --out {out}/t.md --workers 0", "--workers must be >= 1"),
    ("obstacles --report {out}/o.md --cache {out}/cells --placements 0", "placements must be between 1 and 10000"),
    ("obstacles --report {out}/o.md --cache {out}/cells --learner node,dmp",
     "unknown learner(s) dmp; known: node, stable_node, contraction, contracting_node, tracking, all"),
]


@pytest.mark.parametrize("line, message", BAD_INPUT + REPORT_BAD_INPUT)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(line: str, message: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", *line.format(out=tmp_path / "out").split()]
    assert message in refused(argv, tmp_path, capsys, outputs="{out}" not in line)
    assert list(tmp_path.iterdir()) == []


def test_every_registered_learner_and_the_dmp_are_benchmarked_and_quick() -> None:
    """``all`` is the registry's learners and the DMP: a learner added to ``lfd.learners`` runs in
    every suite; --quick caps its iterations unless the suite names its quick options."""
    from lfd.commands.bench import resolve_learners
    from lfd.learners import LEARNERS

    assert resolve_learners("all") == [*LEARNERS, "dmp"] and resolve_learners("dmp,node") == ["node", "dmp"]
    suite = LasaSuite(P.LasaProtocol())
    assert suite.quick("contraction") == {"iterations": 60} and suite.quick("dmp") == {}
    for learner in LEARNERS:
        iterations = suite.config(learner, {}).get("iterations")
        assert iterations is None or suite.quick(learner)["iterations"] <= min(iterations, 200), learner


def test_dmp_reproduces_angle_and_stays_at_the_goal() -> None:
    demos = lasa("Angle")
    model = fit_dmp(demos)
    y, yd = model.reproduce(demos.x, demos.t)
    assert y.shape == yd.shape == demos.x.shape
    err = np.mean([rmse(a, b) for a, b in zip(y, demos.x)])
    assert err < ANGLE_RMSE_DMP_MAX
    # from far starts the DMP must reach the goal and stay there after its phase has decayed
    x0 = P.starts(demos, "Angle", P.LasaProtocol()).box[:8]
    t = np.linspace(0.0, 3 * model.duration, 600)
    traj = model.rollouts(x0, t)
    late = np.linalg.norm(traj[:, t > 1.5 * model.duration] - demos.goal, axis=-1)
    assert late.max() < 1.0


# ---------------------------------------------------------------- the quick run

# fewer perturbed starts and a coarser grid than the protocol's (the options of the command, checked here)
FEW_STARTS = ["--ring-points", "2", "--box-points", "16", "--spurious-grid", "12"]
QUICK_ARGV = ["bench", "lasa", "--learner", "contraction,dmp", "--quick", "--split", "in-sample", "--workers", "2",
              *FEW_STARTS]


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return bench_run(tmp_path_factory.mktemp("lasa"), QUICK_ARGV, "lasa.md")


def test_report_has_a_row_per_shape_mean_median_and_figures(quick: dict[str, Any]) -> None:
    md, d = quick["md"], quick["dir"]
    assert md.startswith("# LASA benchmark")
    for learner in ("contraction", "dmp"):
        section = md.split(f"## Per shape: {learner}")[1].split("## ")[0]
        rows = [line for line in section.splitlines() if line.startswith("| ")][1:]
        assert [r.split("|")[1].strip() for r in rows] == [*QUICK_UNITS, "**Mean**", "**Median**"]
        assert all(len(r.split("|")) == len(rows[0].split("|")) for r in rows)
        assert f"![LASA {learner}](figures/lasa_{learner}.png)" in section
        fig = d / "figures" / f"lasa_{learner}.png"
        assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and fig.stat().st_size > 20_000
    summary = md.split("## Summary")[1].split("## ")[0]
    for learner in ("contraction", "dmp"):
        assert re.search(rf"^\| {learner} \| 3 \|", summary, re.M)
    assert "## Targets (contraction learner)" in md and "## Reading" in md
    assert "## In-sample and held-out" not in md and "Held-out demos" not in md      # not run


def test_results_json_schema(quick: dict[str, Any]) -> None:
    r = quick["json"]
    assert {"suite", "protocol", "protocol_hash", "learners", "shapes", "splits", "seeds", "quick", "summary", "run",
            "results"} <= set(r)
    assert r["shapes"] == list(QUICK_UNITS) and r["seeds"] == [0] and r["quick"] is True
    assert r["protocol"] == P.LasaProtocol(ring_points=2, box_points=16, spurious_grid=12).to_dict()
    assert r["splits"] == ["in-sample"]
    assert [f"{c['learner']}__{c['shape']}__seed{c['seed']}" for c in r["results"]] == QUICK_CELLS
    for c in r["results"]:
        assert set(c["metrics"]) == set(METRICS) and c["split"] == "in-sample" and c["fold"] is None
        assert all(isinstance(v, float) and v >= 0 for v in c["metrics"].values())
        assert all(len(v) == 7 for v in c["per_demo"].values())
        assert c["train_demos"] == c["scored_demos"] == list(range(7))
        assert c["convergence"]["n_starts"] == 7 + 7 * 2 + 16 and c["convergence"]["radius_mm"] == 1.0
        assert c["train_time_s"] > 0 and c["step_time_us"] > 0
    for learner in ("contraction", "dmp"):
        s = r["summary"][learner]
        assert s["held-out"] is None and s["held-out / in-sample"] is None
        assert s["in-sample"]["units"] == 3 and set(s["in-sample"]["metrics"]) == set(METRICS)
        assert {"mean", "median"} == set(s["in-sample"]["metrics"]["dtw"])
    assert r["run"]["computed"] == 6 and r["run"]["cached"] == 0


def test_contraction_converges_from_every_start_and_fits_angle(quick: dict[str, Any]) -> None:
    cells = {c["shape"]: c for c in quick["json"]["results"] if c["learner"] == "contraction"}
    for shape, c in cells.items():
        assert c["convergence"]["rate"] == 1.0, (shape, c["convergence"])
        assert c["integrators"] == {"reproduce": "dopri5", "rollouts": "dopri5", "grid": "dopri5"}
        assert c["convergence"]["spurious_grid"] == 0.0 and c["convergence"]["n_grid"] == 12 * 12
        # the equilibria search (lfd.equilibria) finds nothing but the goal in a contracting field
        assert c["equilibria"]["clean"] and c["equilibria"]["spurious_attractors"] == 0
        assert c["equilibria"]["goal_fraction"] == 1.0
    assert all(c["equilibria"] is None for c in quick["json"]["results"] if c["learner"] == "dmp")
    s = quick["json"]["summary"]["contraction"]["in-sample"]["equilibria"]
    assert s["units_clean"] == 3 and s["spurious_attractors"] == 0
    assert "| 3 clean; 0 attractor(s), 0 orbit(s) |" in quick["md"]
    assert cells["Angle"]["metrics"]["dtw"] < ANGLE_DTW_CONTRACTION_MAX
    dmp = {c["shape"]: c for c in quick["json"]["results"] if c["learner"] == "dmp"}
    assert all(c["convergence"]["rate"] == 1.0 for c in dmp.values())


def test_second_run_resumes_and_recomputes_only_a_missing_cell(quick: dict[str, Any]) -> None:
    d = quick["dir"]
    cache = d / ".cache" / "r"
    assert sorted(p.stem for p in cache.glob("*.json")) == sorted(QUICK_CELLS)
    (cache / "dmp__Sine__seed0.json").unlink()          # as if interrupted during this cell
    def contraction_mtimes() -> dict[str, int]:
        return {p.name: p.stat().st_mtime_ns for p in cache.iterdir() if p.name.startswith("contraction")}

    mtimes = contraction_mtimes()
    assert len(mtimes) == 6
    r = bench_run(d, QUICK_ARGV, "lasa.md")["json"]
    assert r["run"]["computed"] == 1 and r["run"]["cached"] == 5
    assert contraction_mtimes() == mtimes                   # no contraction cell was retrained
    assert (cache / "dmp__Sine__seed0.json").is_file()
    before = {f"{c['learner']}{c['shape']}": c["metrics"] for c in quick["json"]["results"]}
    after = {f"{c['learner']}{c['shape']}": c["metrics"] for c in r["results"]}
    assert after.keys() == before.keys()                    # the DMP is deterministic too (another
    for k in after:                                         # process: equal to a tolerance)
        x, y = _numbers(after[k]), _numbers(before[k])
        assert x.keys() == y.keys()
        np.testing.assert_allclose([x[n] for n in x], [y[n] for n in x], rtol=1e-9, atol=1e-12, err_msg=k)


def test_same_seed_gives_the_same_numbers(quick: dict[str, Any], tmp_path: Path) -> None:
    """One cell twice in this process (``--workers 1``): the same bits. Against the fixture's run in
    a worker of a 2-process pool: the same bits too, the timings and host fields left out (every
    worker and the in-process path run one BLAS / OpenMP thread, ``lfd.threads``)."""
    runs = []
    for name in ("a", "b"):
        argv = ["bench", "lasa", "--learner", "contraction", "--quick", "--shapes", "Angle", "--split", "in-sample",
                "--workers", "1", "--json", str(tmp_path / f"{name}.json"), "--report", str(tmp_path / f"{name}.md"),
                *FEW_STARTS]
        assert main(argv) == 0
        runs.append(json.loads((tmp_path / f"{name}.json").read_text())["results"][0])
    first = next(c for c in quick["json"]["results"]
                 if c["learner"] == "contraction" and c["shape"] == "Angle")
    assert runs[0]["hash"] == first["hash"] and runs[0]["config"] == first["config"]
    for key in ("metrics", "per_demo", "convergence"):
        a, b, c = _numbers(runs[0][key]), _numbers(runs[1][key]), _numbers(first[key])
        assert a == b, key
        assert a.keys() == c.keys() and len(a) > 3
    assert results(runs[0]) == results(first)


# ---------------------------------------------------------------- the held-out split

@pytest.fixture(scope="module")
def both(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Both splits of contraction and the DMP on Angle (--quick)."""
    argv = ["bench", "lasa", "--learner", "contraction,dmp", "--quick", "--shapes", "Angle", "--workers", "2",
            *FEW_STARTS]
    return bench_run(tmp_path_factory.mktemp("lasa_both"), argv, "both.md")


def test_held_out_trains_a_field_per_demo_without_it_and_runs_it_to_its_own_end(both: dict[str, Any]) -> None:
    r, demos = both["json"], lasa("Angle")
    suite = LasaSuite(P.LasaProtocol())
    assert r["splits"] == ["in-sample", "held-out"] and r["run"]["computed"] == 16
    for learner in ("contraction", "dmp"):
        held = sorted((c for c in r["results"] if c["learner"] == learner and c["split"] == "held-out"),
                      key=lambda c: c["fold"])
        assert [c["fold"] for c in held] == list(range(7))
        for c in held:
            i = c["fold"]
            assert c["scored_demos"] == [i] and c["train_demos"] == [k for k in range(7) if k != i]
            assert set(c["metrics"]) == set(METRICS) and all(len(v) == 1 for v in c["per_demo"].values())
            assert all(np.isfinite(v) and v >= 0 for v in c["metrics"].values()), (learner, i)
            y = load_arrays(both["dir"] / ".cache" / "r", suite.record_stem(c))["reproduction"]
            assert y.shape == (1, demos.n_samples, 2)
            np.testing.assert_allclose(y[0, 0], demos.x[i, 0], atol=1e-9)           # from its own start
            end = np.linalg.norm(y[0, -1] - demos.x[i, -1])                        # to its own end
            assert end < HELD_OUT_END_MM[learner], (learner, i, end)
        s = r["summary"][learner]
        assert s["held-out"]["units"] == 1 and s["in-sample"]["units"] == 1
        c = s["held-out / in-sample"]["dtw"]
        mean = float(np.mean([h["metrics"]["dtw"] for h in held]))
        assert c["held-out"] == pytest.approx(mean, rel=1e-12) and c["ratio"] == pytest.approx(mean / c["in-sample"])


def test_report_shows_in_sample_and_held_out_side_by_side(both: dict[str, Any]) -> None:
    md, s = both["md"], both["json"]["summary"]
    section = md.split("## In-sample and held-out")[1].split("## ")[0]
    assert "| learner | shapes | DTW (sum, mm) in-sample | held-out | ratio | RMSE (mm) in-sample |" in section
    for learner in ("contraction", "dmp"):
        c = s[learner]["held-out / in-sample"]
        row = next(line for line in section.splitlines() if line.startswith(f"| {learner} |"))
        cols = [x.strip() for x in row.split("|")[1:-1]]
        assert cols[1] == "1" and cols[2:5] == [f"{c['dtw']['in-sample']:.0f}", f"{c['dtw']['held-out']:.0f}",
                                                 f"{c['dtw']['ratio']:.2f}"]
        per = md.split(f"## Per shape: {learner}")[1].split("## ")[0]
        assert f"Held-out demos, {learner}:" in per and "| Angle |" in per.split("Held-out demos")[1]
    assert "## Held-out demos (mean / median over shapes)" in md and "Held out (each demo scored by a model" in md


def test_tradeoff_reads_the_nodes_in_sample_dtw_from_results_old_and_new(tmp_path: Path) -> None:
    """``lfd bench tradeoff`` puts the NODE's DTW beside its own: from the in-sample records of a
    results JSON, or from the ``train`` entry of results written before the held-out split."""
    from lfd.bench.tradeoff import node_dtws

    path = tmp_path / "r.json"
    path.write_text(json.dumps({"results": [
        {"learner": "node", "shape": "Angle", "split": "in-sample", "metrics": {"dtw": 1.0}},
        {"learner": "node", "shape": "Angle", "split": "held-out", "fold": 0, "metrics": {"dtw": 9.0}},
        {"learner": "node", "shape": "Sine", "train": {"dtw": 2.0}},
        {"learner": "dmp", "shape": "GShape", "split": "in-sample", "metrics": {"dtw": 3.0}}]}))
    assert node_dtws(path) == {"Angle": 1.0, "Sine": 2.0}
    assert node_dtws(tmp_path / "none.json") is None


def _numbers(obj: Any, prefix: str = "") -> dict[str, float]:
    """Flatten the numbers of a nested dict/list into {path: value}."""
    if isinstance(obj, dict):
        return {k: v for key, val in obj.items() for k, v in _numbers(val, f"{prefix}/{key}").items()}
    if isinstance(obj, list):
        return {k: v for i, val in enumerate(obj) for k, v in _numbers(val, f"{prefix}/{i}").items()}
    return {prefix: float(obj)} if isinstance(obj, (int, float)) else {}


# ---------------------------------------------------------------- the Ray executor

# on a Ray cluster: tests/test_ray_cluster.py


@pytest.mark.parametrize("mode, error, stderr, message", [
    (None, RuntimeError("Failed to connect to Ray cluster at 10.0.0.5:6379"),
     "gcs_client.cc:210: Failed to get cluster ID: Unauthenticated: RPC error: InvalidAuthToken: missing\n",
     "it wants token authentication (set RAY_AUTH_MODE=token, with the cluster's token in ~/.ray/auth_token "
     "or $RAY_AUTH_TOKEN)"),
    ("token", RuntimeError("Failed to connect to Ray cluster at 10.0.0.5:6379"), "InvalidAuthToken\n",
     "it refused this process's Ray token (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token)"),
    (None, ConnectionError("no GCS there\nsecond line"), "", "no GCS there"),
    (None, ValueError(), "", "ValueError"),
])
def test_a_failed_ray_join_is_one_line(mode: str | None, error: Exception, stderr: str, message: str,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Why ``ray.init`` could not join, in one line, from its exception and Ray's held-back stderr."""
    from lfd.bench.executor import _init_error

    if mode is None:
        monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    else:
        monkeypatch.setenv("RAY_AUTH_MODE", mode)
    assert _init_error(error, stderr) == message


def test_ray_stderr_is_held_back_at_the_file_descriptor(capfd: pytest.CaptureFixture[str]) -> None:
    """What native code writes on fd 2 while joining a cluster is held, and fd 2 is restored after."""
    import os

    from lfd.bench.executor import _HeldStderr

    held = _HeldStderr()
    with held:
        os.write(2, b"[C++] a warning a second\n")
    os.write(2, b"after\n")
    assert held.text == "[C++] a warning a second\n" and capfd.readouterr().err == "after\n"


def test_the_core_does_not_import_ray() -> None:
    """``import lfd`` and the bench runner leave Ray alone (it is imported by the Ray executor only)."""
    import subprocess
    import sys

    code = "import sys, lfd, lfd.bench.runner, lfd.commands.bench, lfd.cli; sys.exit('ray' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


# ---------------------------------------------------------------- nothing of a held-out demo leaks

def _bent(demos: Any, fold: int) -> Any:
    """The demos with demo ``fold``'s interior bent away (its first and last samples kept): positions by a
    smooth bump of a fifth of the extent, orientations (poses) turned by up to 20 degrees about z."""
    from lfd.demos import DemoSet
    from lfd.rotations import from_rotation_vectors

    x = demos.x.copy()
    s = np.sin(np.linspace(0.0, np.pi, demos.n_samples)) ** 2
    s[[0, -1]] = 0.0                                                            # both ends exactly kept
    extent = float(np.max(np.ptp(demos.x.reshape(-1, demos.dim), axis=0)))
    x[fold] += 0.2 * extent * s[:, None] * np.ones(demos.dim) / np.sqrt(demos.dim)
    q = None
    if demos.q is not None:
        q = demos.q.copy()
        turn = np.zeros((demos.n_samples, 3))
        turn[:, 2] = np.radians(20.0) * s
        for k in range(demos.n_samples):
            q[fold, k] = from_rotation_vectors(turn[k:k + 1], q[fold, k])[0]
    return DemoSet(demos.t, x, name=demos.name, q=q, frame=demos.frame)


@pytest.mark.parametrize("suite_name,learner", [("lasa", "tracking"), ("lasa", "dmp"), ("lasa", "node"),
                                                ("robottasks", "tracking"), ("robottasks", "dmp")])
def test_a_held_out_demo_leaks_nothing_but_its_start_and_end(suite_name: str, learner: str) -> None:
    """Bend the held-out demo's interior: its reproduction must not move (the model saw only the others),
    while its score does (the bent demo is what it is scored against)."""
    from lfd.bench.robottasks import RobotTasksProtocol, RobotTasksSuite

    suite: Any = LasaSuite(P.LasaProtocol()) if suite_name == "lasa" else RobotTasksSuite(RobotTasksProtocol())
    unit, fold = ("Angle", 3) if suite_name == "lasa" else ("pouring", 4)
    plain = suite.demos(unit)
    bent = _bent(plain, fold)
    assert np.array_equal(bent.x[fold, [0, -1]], plain.x[fold, [0, -1]])
    extent = float(np.max(np.ptp(plain.x.reshape(-1, plain.dim), axis=0)))
    assert float(np.max(np.linalg.norm(bent.x[fold] - plain.x[fold], axis=1))) > 0.19 * extent
    options = suite.quick(learner)
    runs = []
    for demos in (plain, bent):
        suite.demos = lambda unit, demos=demos: demos                       # this suite's data, for this run
        runs.append(suite.evaluate(suite.cell(learner, unit, 0, fold, options)))
    (a, ya), (b, yb) = runs
    assert a["scored_demos"] == [fold] and fold not in a["train_demos"]
    np.testing.assert_allclose(yb["reproduction"], ya["reproduction"], rtol=0, atol=1e-9)
    assert b["metrics"]["dtw" if suite_name == "lasa" else "dtw_mm"] > 1.5 * a["metrics"]["dtw" if suite_name == "lasa"
                                                                                          else "dtw_mm"]


# ---------------------------------------------------------------- the cache keys hold the code

@pytest.mark.parametrize("change", ["learner code", "scoring code", "protocol version", "report text"])
def test_a_cache_from_before_a_change_is_reused_only_when_no_number_can_move(
        change: str, both: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    """The run's cached DMP cell is read back as it is; after an edit of the DMP's code or of the
    code that scores it (a comment appended to lfd/bench/dmp.py or lfd/metrics.py), or a raised
    protocol version, it is not (the cell is computed again); an edit of the report's text only
    (lfd/bench/report.py) keeps it."""
    from lfd import fingerprint
    from lfd.bench.runner import read_cached

    r = both["json"]
    protocol = P.LasaProtocol(**{k: v for k, v in r["protocol"].items() if k != "version"})
    suite = LasaSuite(protocol)
    cache = both["dir"] / ".cache" / "r"
    cell = lambda: suite.cell("dmp", "Angle", 0, None, suite.quick("dmp"))   # noqa: E731
    fingerprint._fingerprint.cache_clear()
    record, problem = read_cached(cell(), cache)
    assert problem is None and record is not None and record["learner"] == "dmp"
    edited = {"learner code": "lfd.bench.dmp", "scoring code": "lfd.metrics", "report text": "lfd.bench.report"}
    if change == "protocol version":
        monkeypatch.setattr(P, "PROTOCOL_VERSION", P.PROTOCOL_VERSION + 1)
    else:
        source = fingerprint.read_source
        monkeypatch.setattr(fingerprint, "read_source",
                            lambda name: source(name) + (b"\n# edited\n" if name == edited[change] else b""))
    fingerprint._fingerprint.cache_clear()
    try:
        again, problem = read_cached(cell(), cache)
    finally:
        monkeypatch.undo()
        fingerprint._fingerprint.cache_clear()
    assert problem is None
    if change == "report text":
        assert again == record
    else:
        assert again is None
