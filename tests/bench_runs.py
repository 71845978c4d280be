"""Running ``lfd bench`` in a test: a run's outputs, and a refused command line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from lfd.cli import main


def bench_run(folder: Path, argv: list[str], report: str) -> dict[str, Any]:
    """``lfd bench ARGV --json FOLDER/r.json --report FOLDER/REPORT``, which must succeed: the
    folder, the results JSON and the report's text."""
    assert main([*argv, "--json", str(folder / "r.json"), "--report", str(folder / report)]) == 0
    return {"dir": folder, "json": json.loads((folder / "r.json").read_text()), "md": (folder / report).read_text()}


def refused(argv: list[str], folder: Path, capsys: pytest.CaptureFixture[str], outputs: bool = True) -> str:
    """``lfd bench ARGV`` with outputs in FOLDER/out (with ``outputs``, ``--json`` and ``--report``
    are added; without, ARGV names them): exit code 2, one line on stderr (returned), nothing written."""
    out = folder / "out"
    code = main([*argv, "--json", str(out / "r.json"), "--report", str(out / "r.md")] if outputs else argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert not out.exists()
    return err
