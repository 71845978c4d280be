"""The ``lfd`` command: one subcommand per module of ``lfd.commands``.

Each command module exposes ``add_parser(subparsers) -> argparse.ArgumentParser`` and
``run(args) -> int``, and may expose ``preload(args) -> tuple of str``, the modules its run needs
(default ``PRELOAD``). Add a command by writing its module and appending its name to COMMANDS.
Command modules import torch, numpy and the like inside ``run``, never at module level or in
``add_parser``: ``lfd --help`` builds every parser and must stay fast (tests/test_hostile.py).
Every user error (``LfdError``, an ``OSError`` such as a missing, unreadable or unwritable
file, a bad option) ends in ONE line ``lfd: error: <message>`` on stderr and exit code 2; Ctrl-C
or SIGTERM, from the first moment of ``main``, ends in ``lfd: interrupted`` and exit code 130
(temporary files removed, nothing half-written); a reader that closes the pipe (``lfd ... | head``)
ends the command quietly with 141. Warnings are one line ``lfd: warning: ...``. Any other
exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from lfd.interrupts import (
    EXIT_BROKEN_PIPE,
    EXIT_INTERRUPTED,
    DeferredInterrupts,
    install_signal_handlers,
    restore_signal_handlers,
    run_guarded,
)
from lfd.interrupts import say as _say

COMMANDS: list[str] = ["train", "eval", "plot", "bench", "certify", "export"]

EXIT_USAGE = 2
__all__ = ["COMMANDS", "EXIT_BROKEN_PIPE", "EXIT_INTERRUPTED", "EXIT_USAGE", "build_parser", "install_signal_handlers",
           "main", "restore_signal_handlers", "run_guarded"]


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line, like every other error of the command, and
    whose help shows plain text (docstrings' ``literal`` markup removed)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"lfd: error: {message} (see '{self.prog} --help')\n")

    def format_help(self) -> str:
        return super().format_help().replace("``", "")

    def format_usage(self) -> str:
        return super().format_usage().replace("``", "")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lfd-arm")
    except PackageNotFoundError:
        return "unknown"


class _Version(argparse.Action):
    """``--version``: prints ``lfd <version>`` and exits; the version is looked up only then."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str = "show program's version number and exit") -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> NoReturn:
        sys.stdout.write(f"lfd {_version()}\n")
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every command of COMMANDS registered (``only``: that command alone,
    for a command line that names it first: its parser, errors and help are the same).

    Building it imports only the command modules, never torch: ``lfd --help`` stays fast.
    """
    parser = _Parser(prog="lfd", description="Learn a velocity field from demonstrations, "
                     "evaluate it and plot it.")
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS if only is None else (only,):
        module = importlib.import_module(f"lfd.commands.{name}")
        module.add_parser(sub).set_defaults(_run=module.run, _preload=getattr(module, "preload", None))
    return parser


# imported with interrupts deferred before a command runs (lfd.interrupts.DeferredInterrupts), unless
# the command names its own (its module's ``preload(args)``: ``lfd train`` imports only its learner's)
PRELOAD = ("torch", "numpy", "torchdiffeq", "lfd.demos", "lfd.field", "lfd.learners")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv`` (default: sys.argv[1:]); returns the exit code."""
    previous = install_signal_handlers()  # first thing: an early Ctrl-C or SIGTERM is no traceback
    try:
        return run_guarded(_main, argv, "lfd")
    finally:
        restore_signal_handlers(previous)


def _main(argv: Sequence[str] | None) -> int:
    import warnings

    from lfd.errors import LfdError

    with DeferredInterrupts("lfd"):
        try:
            words = list(sys.argv[1:] if argv is None else argv)
            # a command line that starts with a command builds that command's parser alone
            args = build_parser(words[0] if words and words[0] in COMMANDS else None).parse_args(words)
        except SystemExit as e:  # --help (0) or a usage error (2), already printed
            return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
        for module in (PRELOAD if args._preload is None else args._preload(args)):
            importlib.import_module(module)
    from lfd.threads import torch_threads

    # Small networks on a few cores: one intra-op thread is faster and avoids oversubscription
    # (a second thread makes rollouts many times slower on a loaded machine).
    with torch_threads(1), warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            return int(args._run(args))
        except BrokenPipeError:
            raise
        except (LfdError, OSError) as e:  # OSError: missing, unreadable or unwritable files
            _say(f"lfd: error: {_one_line(e)}")
            return EXIT_USAGE


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:
    """A warning as one line ``lfd: warning: ...`` (no source file, no code line)."""
    text = str(message).strip()
    _say(f"lfd: warning: {text.splitlines()[0] if text else category.__name__}")


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror or type(e).__name__}"
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
