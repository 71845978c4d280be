"""The robustness sweep of the arm (``sim.studies.sweep``, scripts/sweep_arm.py): one JSON record per run,
resume, summary and figures. Ray's records against the local pool's, bit for bit and with a killed
worker, are in test_ray_cluster.py.

Small on purpose: the planar arm, two tiny learned fields (trained once into a temporary model
cache), 2 push directions x 1 force + 2 start offsets per learner (8 runs).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_runs import run_main

from sim.studies import sweep

ARGS = ["--robots", "planar", "--directions", "2", "--forces", "20", "--offsets", "0.05", "--kinds", "push,offset",
        "--option", "node.iterations=30", "--option", "node.hidden=[16,16]", "--option", "contraction.iterations=10",
        "--option", "contraction.layers=1", "--option", "contraction.hidden=8"]
N_RUNS = 8


@pytest.fixture(scope="module")
def local(model_cache: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sweep_local")
    assert sweep.main(["--out", str(out), "--workers", "2", *ARGS]) == 0
    return out


def _records(out: Path) -> dict[str, dict[str, Any]]:
    return {p.name: json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))}


def test_records_summary_and_figures(local: Path) -> None:
    recs = _records(local)
    assert len(recs) == N_RUNS
    assert not list((local / "runs").glob("*.tmp*"))                       # atomic: no leftovers
    for name, r in recs.items():
        assert name == f"{r['name']}.json" and len(r["key"]) == 16
        assert r["kind"] in ("push", "offset") and isinstance(r["success"], bool) and r["error"] is None
        assert r["metrics"]["final_goal_error_m"] >= 0
        if r["kind"] == "push":
            assert "recovery_time_s" in r["metrics"] and r["metrics"]["max_deviation_m"] > 0
    summary = json.loads((local / "summary.json").read_text())
    assert summary["runs"] == N_RUNS and summary["run"]["computed"] == N_RUNS
    assert set(summary["summary"]) == {f"planar/{lr}/{k}" for lr in ("node", "contraction") for k in ("push", "offset")}
    for name in ("heatmap.png", "basin.png"):
        assert (local / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_resume_recomputes_only_a_missing_run(local: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recs = sorted((local / "runs").glob("*.json"))
    gone = recs[3]
    gone.unlink()
    mtimes = {p.name: p.stat().st_mtime_ns for p in recs if p != gone}
    assert sweep.main(["--out", str(local), "--workers", "1", *ARGS]) == 0
    assert "1 run(s) computed, 7 from" in capsys.readouterr().out
    assert gone.is_file()
    assert {p.name: p.stat().st_mtime_ns for p in recs if p != gone} == mtimes


#: what the one line says -> the options that make the sweep say it
BAD_INPUT: dict[str, list[str]] = {
    "invalid choice": ["--executor", "dask"],
    "HOST:PORT": ["--executor", "ray", "--address", "no-port"],
    "needs --executor ray": ["--address", "10.0.0.1:6379"],
    "no Ray cluster reachable": ["--executor", "ray", "--address", "127.0.0.1:1"],
    "--forces": ["--forces", "-5"],
    "--workers": ["--workers", "0"],
    "--kinds": ["--kinds", "spin"],
    "--learners": ["--learners", "gp"],
}


@pytest.mark.parametrize("message, argv", BAD_INPUT.items())
def test_bad_input_is_one_line_exit_2(message: str, argv: list[str], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_main(sweep.main, ["--out", str(tmp_path), *argv], capsys)
    assert code == 2 and message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "runs").exists()
