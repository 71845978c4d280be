"""Ctrl-C and SIGTERM for the programs of the project (``lfd``, ``lfd-demo-arm``, ``scripts/``).

Every long-running entry point ends the same way when interrupted: one line ``<prog>: interrupted``
on stderr, exit code 130, no traceback, temporary files removed (the writers of ``lfd.io`` and
``lfd.modelfile`` are atomic). Two phases:

* while modules are imported, SIGINT and SIGTERM are only remembered (``DeferredInterrupts``): an
  interrupt inside an import can surface as another error (numpy turns it into an AttributeError);
  the interrupt is acted on when the imports are done, and a second signal ends the process at once;
* while the program runs, both raise KeyboardInterrupt (``install_signal_handlers``), so cleanup
  (``finally`` blocks, temporary files, worker pools) runs before ``run_guarded`` reports it.

A script takes both from its first lines with ``run_script``, before its own module-level imports::

    if __name__ == "__main__":
        from lfd.interrupts import run_script

        run_script(__file__)

This module imports only the standard library, so that importing it costs next to nothing.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys

TYPE_CHECKING = False  # typing itself is not imported: this module is loaded before anything else
if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from typing import Any, NoReturn

__all__ = ["EXIT_BROKEN_PIPE", "EXIT_INTERRUPTED", "DeferredInterrupts", "install_signal_handlers",
           "restore_signal_handlers", "run_guarded", "run_main", "run_script"]

EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left
SIGNALS = (signal.SIGINT, signal.SIGTERM)


def say(text: str) -> None:
    """Print ``text`` on stderr, ignoring a stderr that is closed or gone."""
    try:
        print(text, file=sys.stderr)
    except (OSError, ValueError):
        pass


def _raise_interrupt(signum: int, frame: Any) -> None:
    """SIGTERM (and a second SIGINT) end the run like Ctrl-C: cleanup runs, exit code 130."""
    raise KeyboardInterrupt


def _set_handlers(handler: Any) -> dict[int, Any]:
    previous: dict[int, Any] = {}
    try:
        for sig in SIGNALS:
            previous[sig] = signal.signal(sig, handler)
    except ValueError:  # not the main thread: Python cannot set handlers there
        pass
    return previous


def install_signal_handlers() -> dict[int, Any]:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt.

    Outside the main thread (where Python cannot set handlers) nothing changes.

    Returns
    -------
    dict of int to handler
        The previous handlers, for ``restore_signal_handlers``.
    """
    return _set_handlers(_raise_interrupt)


def restore_signal_handlers(previous: dict[int, Any]) -> None:
    """Put back the handlers ``install_signal_handlers`` (or ``DeferredInterrupts``) replaced.

    Parameters
    ----------
    previous : dict of int to handler
        What ``install_signal_handlers`` returned.
    """
    for sig, handler in previous.items():
        signal.signal(sig, handler)


class DeferredInterrupts:
    """Within the block, SIGINT and SIGTERM only mark the run interrupted; on leaving, a marked run
    raises KeyboardInterrupt. A second signal inside the block ends the process at once
    (``<prog>: interrupted``, exit 130).

    Parameters
    ----------
    prog : str
        The program's name, for the line printed on a second signal.
    """

    def __init__(self, prog: str) -> None:
        self.prog = prog
        self.hit = False
        self.previous: dict[int, Any] = {}

    def _mark(self, signum: int, frame: Any) -> None:
        if self.hit:
            say(f"{self.prog}: interrupted")
            os._exit(EXIT_INTERRUPTED)
        self.hit = True

    def __enter__(self) -> DeferredInterrupts:
        self.previous = _set_handlers(self._mark)
        return self

    def __exit__(self, *exc: Any) -> None:
        restore_signal_handlers(self.previous)
        if self.hit:
            raise KeyboardInterrupt


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush raises no second error."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def run_guarded(run: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None, prog: str) -> int:
    """``run(argv)``, with Ctrl-C (and SIGTERM, once the handlers are installed) ending in
    ``<prog>: interrupted`` and exit code 130, and a reader that went away (``| head``) in a quiet
    exit 141.

    Parameters
    ----------
    run : callable
        The program, ``run(argv) -> exit code``.
    argv : sequence of str or None
        Its command line (None: ``sys.argv[1:]``).
    prog : str
        The program's name in the line printed when interrupted.

    Returns
    -------
    int
        The exit code.
    """
    try:
        try:
            code = run(argv)
            sys.stdout.flush()
            return code
        except KeyboardInterrupt:
            say(f"{prog}: interrupted")
            return EXIT_INTERRUPTED
        except BrokenPipeError:  # ``... | head -1``: the reader has gone; end quietly
            _silence_stdout()
            return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:  # a second Ctrl-C while reporting the first
        return EXIT_INTERRUPTED


def run_main(prog: str, load: Callable[[], Callable[[Sequence[str] | None], int]],
             argv: Sequence[str] | None = None) -> int:
    """Run a program whose modules ``load`` imports: the imports with interrupts deferred, then
    ``load()(argv)`` with SIGINT and SIGTERM raising KeyboardInterrupt, through ``run_guarded``.

    Parameters
    ----------
    prog : str
        The program's name in the line printed when interrupted.
    load : callable
        Imports what the program needs and returns its main, ``main(argv) -> exit code``.
    argv : sequence of str or None
        The command line (None: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code; the handlers in place before are restored.
    """
    def run(args: Sequence[str] | None) -> int:
        with DeferredInterrupts(prog):
            main = load()
        return main(args)

    previous = install_signal_handlers()
    try:
        return run_guarded(run, argv, prog)
    finally:
        restore_signal_handlers(previous)


def run_script(path: str, module: str | None = None) -> NoReturn:
    """Run the script at ``path`` as the process: import ``module`` (by default the script itself,
    as the module of its file's name, so that worker processes find its functions by that name) and
    the modules its ``PRELOAD`` names (the ones its ``main`` imports on the way) with interrupts
    deferred, call its ``main()`` and exit with its code; interrupted, ``<name>: interrupted`` and
    exit 130, ``<name>`` the script's file name without ``.py``.

    Parameters
    ----------
    path : str
        The script's file (its ``__file__``); Python puts its folder first on the import path.
    module : str, optional
        The module whose ``main()`` runs, if not the script's own.
    """
    name = os.path.splitext(os.path.basename(path))[0]

    def load() -> Callable[[Sequence[str] | None], int]:
        program = importlib.import_module(module or name)
        for heavy in getattr(program, "PRELOAD", ()):
            importlib.import_module(heavy)
        return lambda argv: int(program.main() or 0)

    sys.exit(run_main(name, load))
