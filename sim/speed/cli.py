"""The ``speed`` command (``scripts/speed.py``): ``speed NAME [options]`` runs the measurement NAME of
``sim.speed.SUBCOMMANDS``; ``speed --help`` lists them and ``speed NAME --help`` gives NAME's options.

A subcommand's module gives ``add_arguments(parser)`` and ``run(args) -> exit code``; only the named
one is imported. Bad options or input (an unknown robot, a missing model file) end with one line
``speed NAME: error: ...`` on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from lfd.errors import LfdError
from sim.errors import SimError
from sim.run.parsing import OneLineParser, fail
from sim.speed import SUBCOMMANDS

__all__ = ["main"]

PROG = "speed"


def _top_parser() -> OneLineParser:
    listing = "\n".join(f"  {name:14s} {what}" for name, (_, what) in SUBCOMMANDS.items())
    ap = OneLineParser(prog=PROG, formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Speed measurements: print medians and p95, assert nothing.",
                       epilog=f"measurements:\n{listing}\n\n'{PROG} NAME --help' gives NAME's options.")
    ap.add_argument("name", choices=SUBCOMMANDS, metavar="NAME", help="the measurement (below)")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``speed NAME [options]`` (module docstring); returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    name = _top_parser().parse_args(args[:1]).name
    module = importlib.import_module(SUBCOMMANDS[name][0])
    prog = f"{PROG} {name}"
    ap = OneLineParser(prog=prog, description=(module.__doc__ or "").split("\n\n")[0],
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    module.add_arguments(ap)
    ap.add_argument("--quick", action="store_true", help="a smoke test in seconds: tiny training, few repeats "
                                                         "(the numbers mean nothing)")
    options = ap.parse_args(args[1:])
    from robots import RobotError  # (mujoco)

    try:
        return int(module.run(options))
    except (LfdError, SimError, RobotError) as e:
        return fail(prog, str(e))
