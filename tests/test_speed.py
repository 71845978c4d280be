"""The speed command (``sim.speed``, scripts/speed.py): each measurement runs with ``--quick`` and prints
its table; bad options end with one line and exit code 2 before any work. Nothing here is timed.
"""

from __future__ import annotations

import re

import pytest
from cli_runs import run_main

from sim.speed import SUBCOMMANDS
from sim.speed.cli import main

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]

NUMBER = r"\d+\.\d+"
#: subcommand -> (its quick command line, a line it prints: the median of what it times)
QUICK: dict[str, tuple[list[str], str]] = {
    "field": ([], rf"^contraction +{NUMBER} +{NUMBER} +{NUMBER} +{NUMBER}$"),
    "pose": ([], rf"^tracking +{NUMBER} +{NUMBER} +{NUMBER}$"),
    "node": ([], rf"^seed 0: train wall .* MAE {NUMBER}  point_fn {NUMBER} us \(p95 {NUMBER}\)$"),
    "ik": (["--robot", "planar"], rf"^  pink  median +{NUMBER} us/solve   p95 +{NUMBER} us$"),
    "loop": (["--robot", "planar", "--learner", "contraction", "--skip-actuation"],
             rf"^closed-loop step      : median +{NUMBER} us   p95 +{NUMBER} us   \(\d+ steps\)$"),
    "obstacles": (["--shapes", ""], rf"^3-D NODE field +bare median +{NUMBER} us .* ratio {NUMBER}x"),
    "arm-clearance": ([], rf"^whole arm +{NUMBER} +{NUMBER} +\d+$"),
    "render": (["--robot", "planar", "--cases", "single"], rf"^single 64x48 +{NUMBER} +{NUMBER} +{NUMBER}"),
    "tasks": ([], rf"^place +objects +{NUMBER} us +{NUMBER} us +-?{NUMBER} us +-?{NUMBER} +{NUMBER}$"),
}


def test_every_subcommand_has_a_quick_check() -> None:
    assert set(QUICK) == set(SUBCOMMANDS)


@pytest.mark.parametrize("name", list(QUICK))
def test_quick_run_prints_its_median(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    argv, line = QUICK[name]
    assert main([name, "--quick", *argv]) == 0
    out = capsys.readouterr().out
    assert re.search(line, out, re.MULTILINE), out


@pytest.mark.parametrize("argv, message", [
    ([], "the following arguments are required: NAME"),
    (["warp"], "invalid choice: 'warp'"),
    (["loop", "--repeats", "0"], "speed loop: error: --repeats must be in 1..1000"),
    (["render", "--cases", "all"], "speed render: error: --cases must name some of"),
    (["ik", "--robot", "nosuchbot", "--quick"], "speed ik: error:"),
    (["ik", "--learner", "node,contraction"], "speed ik: error: --learner node,contraction: ik replays one field"),
    (["field", "--frobnicate"], "speed field: error: unrecognized arguments: --frobnicate"),
])
def test_bad_input_is_one_line_exit_2(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(main, argv, capsys)
    assert code == 2 and message in err and len(err.splitlines()) == 1 and not out, err
