"""The report commands of ``sim.studies`` (scripts/panda_obstacles.py, robottasks_arm.py, scaling.py):
each one's smoke-test mode writes its report, with the numbers a real run puts there; bad options end
with one line and exit code 2. The sweep has its own tests (test_sweep.py).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cli_runs import run_main

from sim.studies import obstacles, recovery, robottasks, scaling

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]

PNG = b"\x89PNG\r\n\x1a\n"


def test_obstacles_quick_writes_the_users_case(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "obstacles_arm.md"
    code, out, _ = run_main(obstacles.main, ["--quick", "--cache", str(tmp_path / "cache"), "--report", str(report)],
                            capsys)
    assert code == 0 and f"wrote {report}" in out
    text = report.read_text()
    assert text.startswith("# Whole-arm safety on the Panda")
    row = re.search(r"^\| tracking \| none \| 1 \| (\d+) \| 1 \(100 %\) \| 0 \| 0 \| ([\d.]+) \|", text, re.MULTILINE)
    assert row and int(row[1]) == 0 and float(row[2]) < 5.0, text   # no contact, the goal within 5 mm
    assert "| tracking | push |" not in text and "Runs that touch or miss the goal: 0." in text


def test_robottasks_quick_writes_the_first_task(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "robottasks_arm.md"
    code, out, _ = run_main(robottasks.main, ["--quick", "--out", str(tmp_path / "runs"), "--report", str(report)],
                            capsys)
    assert code == 0 and "bottle2shelf: done" in out
    rows = [line.split(" | ") for line in report.read_text().splitlines() if line.startswith("| bottle2shelf |")]
    assert len(rows) == 1 and rows[0][1] == "none"
    track_mm, goal_mm, violations = float(rows[0][2]), float(rows[0][4]), int(rows[0][7])
    assert track_mm < 2.0 and goal_mm < 1.0 and violations == 0


def test_scaling_quick_writes_the_dmp_curves(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "scaling.md"
    argv = ["--quick", "--learners", "dmp", "--skip-control", "--cache", str(tmp_path / "cache"), "--out", str(report)]
    code, out, _ = run_main(scaling.main, argv, capsys)
    assert code == 0 and f"wrote {report}" in out
    text = report.read_text()
    assert "**Quick mode (a smoke test)" in text and "## Exponents" in text
    assert re.search(r"^\| dmp \| d \| -?\d", text, re.MULTILINE), text
    for curve in ("dim", "demos", "samples"):
        assert (tmp_path / "figures" / f"scaling_{curve}.png").read_bytes()[:8] == PNG
    assert not (tmp_path / "figures" / "scaling_control.png").exists()


@pytest.mark.parametrize("main, argv, message", [
    (obstacles.main, ["--placements", "0"], "panda_obstacles: error: --placements must be between 1 and 1000"),
    (robottasks.main, ["--report", "/proc/no/such.md", "--quick"], "robottasks_arm: error: /proc/no/such.md"),
    (robottasks.main, ["--fast"], "robottasks_arm: error: unrecognized arguments: --fast"),
    (recovery.main, ["--report", "/proc/no/such.md"], "recovery_tradeoff: error: /proc/no/such.md"),
    (recovery.main, ["--rates", "1"], "recovery_tradeoff: error: unrecognized arguments: --rates"),
])
def test_bad_options_give_one_line_and_exit_2(main: object, argv: list[str], message: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(main, argv, capsys)  # type: ignore[arg-type]
    assert code == 2 and message in err and len(err.splitlines()) == 1 and not out, err
