"""The ``lfd`` command: one subcommand per module of ``lfd.commands``.

Each command module exposes ``add_parser(subparsers) -> argparse.ArgumentParser`` and
``run(args) -> int``. Add a command by writing its module and appending its name to COMMANDS.
Every user error (``LfdError``, an ``OSError`` such as a missing, unreadable or unwritable
file, a bad option) ends in ONE line ``lfd: error: <message>`` on stderr and exit code 2; Ctrl-C
ends in ``lfd: interrupted`` and exit code 130. Any other exception is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn, Sequence

COMMANDS: list[str] = ["train", "eval", "plot", "bench", "certify"]

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line, like every other error of the command."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"lfd: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every command of COMMANDS registered."""
    parser = _Parser(prog="lfd", description="Learn a velocity field from demonstrations, "
                     "evaluate it and plot it.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"lfd.commands.{name}")
        module.add_parser(sub).set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv`` (default: sys.argv[1:]); returns the exit code."""
    import torch

    from lfd.errors import LfdError

    # Small networks on a few cores: one intra-op thread is faster and avoids oversubscription
    # (measured: a spiral rollout 0.37 s on one thread, 3.7-31 s on two under load).
    torch.set_num_threads(1)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:  # --help (0) or a usage error (2), already printed
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    try:
        return int(args._run(args))
    except (LfdError, OSError) as e:  # OSError: missing, unreadable or unwritable files
        print(f"lfd: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("lfd: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror or type(e).__name__}"
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
