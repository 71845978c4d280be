"""Running a command's ``main`` in-process as a test does: its exit code, argparse's included, and
what it printed (``from cli_runs import run_main``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import pytest


def run_main(main: Callable[[list[str]], Any], argv: Sequence[str],
             capsys: pytest.CaptureFixture[str]) -> tuple[Any, str, str]:
    """(exit code, stdout, stderr stripped) of ``main(argv)``; argparse's ``SystemExit`` gives its code."""
    try:
        code = main(list(argv))
    except SystemExit as e:
        code = e.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip()
