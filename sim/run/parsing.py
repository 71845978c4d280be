"""Command lines of the arm's studies and speed measurements (``sim.studies``, ``sim.speed``): argparse
whose errors are one line on stderr and exit code 2, and the checks their options share.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import NoReturn

from lfd.errors import ConfigError

__all__ = ["EXIT_USAGE", "OneLineParser", "fail", "floats", "names"]

EXIT_USAGE = 2


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line ``<prog>: error: <message> (see --help)``, exit 2,
    and whose help shows plain text (docstrings' ``literal`` markup removed)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")

    def format_help(self) -> str:
        return super().format_help().replace("``", "")


def fail(prog: str, message: str) -> int:
    """Print ``<prog>: error: <message>`` (its first line) on stderr; return ``EXIT_USAGE``."""
    print(f"{prog}: error: {message.splitlines()[0] if message else 'failed'}", file=sys.stderr)
    return EXIT_USAGE


def names(text: str) -> list[str]:
    """``"a, b,,c"`` -> ``["a", "b", "c"]``: the comma-separated names of an option."""
    return [s.strip() for s in text.split(",") if s.strip()]


def floats(text: str, option: str, upper: float = 1e4) -> list[float]:
    """The comma-separated finite numbers in [0, upper] of ``--option``.

    Raises
    ------
    ConfigError
        One line naming the option, when ``text`` holds anything else or nothing.
    """
    try:
        vals = [float(v) for v in names(text)]
    except ValueError:
        raise ConfigError(f"--{option} {text!r}: expected comma-separated numbers") from None
    if not vals or any(not (math.isfinite(v) and v >= 0) for v in vals) or max(vals) > upper:
        raise ConfigError(f"--{option} {text!r}: expected finite numbers in [0, {upper:g}]")
    return vals
