"""The examples a newcomer runs in order (examples/): each runs as a user would run it, from a
fresh folder, sharing one model cache, and prints what it promises."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("[0-9][0-9]_*.py"))
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("examples")


def run_example(name: str, workdir: Path) -> str:
    path = ROOT / "examples" / name
    env = {**os.environ, "LFD_CACHE_DIR": str(workdir / "cache")}
    proc = subprocess.run([sys.executable, str(path), str(workdir / "out")], cwd=workdir, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_every_example_is_short_and_documented() -> None:
    assert len(EXAMPLES) >= 5
    for path in EXAMPLES:
        text = path.read_text()
        assert len(text.splitlines()) <= 60, path.name
        assert text.startswith('"""') and f"python examples/{path.name}" in text, path.name


def test_01_trains_and_plots_the_field(workdir: Path) -> None:
    out = run_example("01_train_and_plot.py", workdir)
    assert "trained model" in out
    dist = float(out.split("largest distance to the goal at the demos' end: ")[1].split()[0])
    assert dist < 5.0                                   # mm, on a shape about 60 mm across
    assert (workdir / "out" / "01_field.png").read_bytes()[:4] == b"\x89PNG"


def test_02_certifies_and_the_bound_holds_far_away(workdir: Path) -> None:
    out = run_example("02_certify.py", workdir)
    assert out.startswith("verdict: certified")
    assert "the bound holds at every step: True" in out


def test_03_runs_the_panda_with_a_push(workdir: Path) -> None:
    out = run_example("03_arm_push.py", workdir)
    report = json.loads((workdir / "out" / "03_arm" / "metrics.json").read_text())
    runs = {r["scenario"]: r["metrics"] for r in report["runs"]}
    assert set(runs) == {"none", "push"} and "2 video(s)" in out
    assert runs["none"]["final_goal_error_m"] < 0.005 and runs["push"]["recovery_time_s"] is not None
    assert all(m["joint_limit_violations"] == 0 for m in runs.values())


def test_04_the_field_avoids_the_obstacle(workdir: Path) -> None:
    out = run_example("04_obstacle.py", workdir)
    assert "the field's path stays outside" in out and out.splitlines()[0].endswith("True")
    arm = out.split("on the arm: goal ")[1]
    assert float(arm.split()[0]) < 5.0 and "contact steps 0," in arm and "blocked False" in arm   # mm; no margin given


def test_05_sweeps_pushes_from_eight_directions(workdir: Path) -> None:
    out = run_example("05_sweep.py", workdir)
    assert len([line for line in out.splitlines() if line.startswith("push ")]) == 8
    assert "recovered 8 of 8" in out


def test_06_runs_a_recorded_pour_in_full_pose(workdir: Path) -> None:
    out = run_example("06_poses.py", workdir)
    report = json.loads((workdir / "out" / "06_poses" / "metrics.json").read_text())
    runs = {r["scenario"]: r["metrics"] for r in report["runs"]}
    assert set(runs) == {"none", "offset"} and "tracking" in out
    for m in runs.values():
        assert m["final_goal_error_m"] < 0.002 and m["final_goal_error_deg"] < 1.0
        assert m["tracking_rmse_deg"] < 1.0 and m["joint_limit_violations"] == 0


def test_07_runs_the_real_arm_controller_at_1_khz(workdir: Path) -> None:
    out = run_example("07_real_arm_loop.py", workdir)
    first, peaks = out.splitlines()[:2]
    assert "cycles at 1 kHz" in first and float(first.split(" at ")[-1].split()[0]) < 1.0   # mm from the goal
    assert peaks.endswith("over the limits: 0")
