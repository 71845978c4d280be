"""The ``lfd`` command: one subcommand per module of ``lfd.commands``.

Each command module exposes ``add_parser(subparsers) -> argparse.ArgumentParser`` and
``run(args) -> int``. Add a command by writing its module and appending its name to COMMANDS.
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
import os
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

COMMANDS: list[str] = ["train", "eval", "plot", "bench", "certify", "export"]

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left


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


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every command of COMMANDS registered.

    Building it imports only the command modules, never torch: ``lfd --help`` stays fast.
    """
    parser = _Parser(prog="lfd", description="Learn a velocity field from demonstrations, "
                     "evaluate it and plot it.")
    parser.add_argument("--version", action="version", version=f"lfd {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"lfd.commands.{name}")
        module.add_parser(sub).set_defaults(_run=module.run)
    return parser


def _raise_interrupt(signum: int, frame: Any) -> None:
    """SIGTERM (and a second SIGINT) end the run like Ctrl-C: cleanup runs, exit code 130."""
    raise KeyboardInterrupt


def install_signal_handlers() -> dict[int, Any]:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt; returns the previous handlers.

    Done first thing in ``main``, before the heavy imports, so an early Ctrl-C is no traceback.
    Outside the main thread (where Python cannot set handlers) nothing changes.
    """
    previous: dict[int, Any] = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, _raise_interrupt)
    except ValueError:  # not the main thread
        pass
    return previous


def restore_signal_handlers(previous: dict[int, Any]) -> None:
    for sig, handler in previous.items():
        signal.signal(sig, handler)


# imported under ``_DeferredInterrupts`` before a command runs: an interrupt inside an import can
# surface as another error (numpy turns it into an AttributeError), so it waits until they are done
PRELOAD = ("torch", "numpy", "scipy.signal", "torchdiffeq", "lfd.demos", "lfd.field", "lfd.learners")


class _DeferredInterrupts:
    """Within the block, SIGINT and SIGTERM only mark the run interrupted (a second one ends the
    process at once, exit 130); on leaving, a marked run raises KeyboardInterrupt."""

    def __init__(self) -> None:
        self.hit = False
        self.previous: dict[int, Any] = {}

    def _mark(self, signum: int, frame: Any) -> None:
        if self.hit:
            _say("lfd: interrupted")
            os._exit(EXIT_INTERRUPTED)
        self.hit = True

    def __enter__(self) -> _DeferredInterrupts:
        try:
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.previous[sig] = signal.signal(sig, self._mark)
        except ValueError:  # not the main thread
            pass
        return self

    def __exit__(self, *exc: Any) -> None:
        restore_signal_handlers(self.previous)
        if self.hit:
            raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv`` (default: sys.argv[1:]); returns the exit code."""
    previous = install_signal_handlers()
    try:
        return run_guarded(_main, argv, "lfd")
    finally:
        restore_signal_handlers(previous)


def run_guarded(run: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None, prog: str) -> int:
    """``run(argv)``, with Ctrl-C (and SIGTERM, once the handlers are installed) ending in
    ``<prog>: interrupted`` and exit code 130, and a reader that went away (``| head``) in a quiet
    exit 141. Shared by ``lfd`` and ``scripts/demo_arm.py``."""
    try:
        try:
            code = run(argv)
            sys.stdout.flush()
            return code
        except KeyboardInterrupt:
            _say(f"{prog}: interrupted")
            return EXIT_INTERRUPTED
        except BrokenPipeError:  # ``... | head -1``: the reader has gone; end quietly
            _silence_stdout()
            return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:  # a second Ctrl-C while reporting the first
        return EXIT_INTERRUPTED


def _main(argv: Sequence[str] | None) -> int:
    import warnings

    from lfd.errors import LfdError

    with _DeferredInterrupts():
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as e:  # --help (0) or a usage error (2), already printed
            return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
        for module in PRELOAD:
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


def _say(text: str) -> None:
    try:
        print(text, file=sys.stderr)
    except (OSError, ValueError):
        pass


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush raises no second error."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror or type(e).__name__}"
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


if __name__ == "__main__":
    sys.exit(main())
