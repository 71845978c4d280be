"""The files of one arm job, staged out of sight and moved into place together.

A job's output folder is never half old, half new: every file under the output folder is first
written into a hidden staging folder beside it (``.<name>.partial-<pid>``), and files planned
elsewhere (``--video PATH``, ``--json PATH``) under a hidden name in their own folder. Only when
every file is complete does ``OutputSet.commit`` move them into place, with SIGINT and SIGTERM
held back for those few renames: the staging folder replaces the output folder by two renames
(the old one, if any, is removed after), then the outside files, each by one atomic rename. A job
that fails or is interrupted before that leaves nothing behind (``OutputSet.discard``).

An existing output folder is replaced only on request (``overwrite``), and only when it holds a
previous job (its ``metrics.json`` has ``runs``) and none of the job's inputs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from lfd.errors import ConfigError, OutputError
from lfd.io import check_writable, same_file

__all__ = ["OutputSet", "fresh_dir"]


def fresh_dir(base: Path) -> Path:
    """``base``, or ``base-1``, ``base-2``, ...: the first that does not exist yet."""
    path, k = base, 0
    while path.exists():
        k += 1
        path = Path(f"{base}-{k}")
    return path


def _is_previous_job(folder: Path) -> bool:
    """Whether ``folder`` holds a previous job's files (a ``metrics.json`` with ``runs``)."""
    try:
        with open(folder / "metrics.json", encoding="utf-8") as f:
            return isinstance(json.load(f).get("runs"), list)
    except (OSError, ValueError, AttributeError):
        return False


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait (blocked, then delivered) until the block ends."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, ValueError, OSError):  # no pthread_sigmask on this platform
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


class OutputSet:
    """The planned files of one job under ``out`` (and any outside it).

    Parameters
    ----------
    out : Path
        The output folder.
    overwrite : bool
        Replace an existing ``out`` that holds a previous job; otherwise a non-empty ``out`` is
        refused (``ConfigError``).
    inputs : dict
        {what: path} of the job's input files, never to be overwritten or removed.
    """

    def __init__(self, out: Path, overwrite: bool, inputs: dict[str, str | None]) -> None:
        self.out = Path(out)
        self.inputs = {k: v for k, v in inputs.items() if v}
        if self.out.exists() and not self.out.is_dir():
            raise ConfigError(f"{self.out}: --out exists and is not a folder")
        if self.out.is_dir() and any(self.out.iterdir()):
            if not overwrite:
                raise ConfigError(f"{self.out}: --out is not empty; choose a new folder, or pass --overwrite "
                                  "to replace a previous run there")
            if not _is_previous_job(self.out):
                raise ConfigError(f"{self.out}: --overwrite replaces only a previous run's folder (with its "
                                  "metrics.json); this one holds other files")
            for what, path in self.inputs.items():
                if Path(path).resolve().is_relative_to(self.out.resolve()):
                    raise OutputError(f"{self.out}: --overwrite would remove the {what} {path}")
        check_writable(self.out / "metrics.json", "--out")
        self.stage_dir = self.out.parent / f".{self.out.name}.partial-{os.getpid()}"
        self._planned: list[Path] = []
        self._outside: dict[Path, Path] = {}   # final path -> staged path, for files outside ``out``
        self._made: list[Path] = []            # folders created for them, removed again on discard

    def plan(self, paths: Iterable[Path], what: str = "output") -> None:
        """Check each of ``paths`` before any work: writable, not an input, not planned twice."""
        for path in paths:
            for name, other in self.inputs.items():
                if same_file(path, other):
                    raise OutputError(f"{path}: {what} would overwrite the {name}; choose another path")
            if any(same_file(path, p) or path == p for p in self._planned):
                raise OutputError(f"{path}: two outputs would be the same file")
            if not self._inside(path):
                check_writable(path, what)
            self._planned.append(Path(path))

    def _inside(self, path: Path) -> bool:
        return Path(os.path.abspath(path)).is_relative_to(os.path.abspath(self.out))

    def staged(self, path: Path) -> Path:
        """Where to write the planned file ``path`` now: its staged name (folders created)."""
        path = Path(path)
        if self._inside(path):
            staged = self.stage_dir / Path(os.path.abspath(path)).relative_to(os.path.abspath(self.out))
            above = self.stage_dir.parent     # the staging folder itself goes whole
        else:
            staged = self._outside.setdefault(path, path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}"))
            above = staged.parent
        self._made.extend(reversed([p for p in (above, *above.parents) if not p.exists()]))
        staged.parent.mkdir(parents=True, exist_ok=True)
        return staged

    def commit(self, last: Path | None = None) -> None:
        """Move every staged file into place (``last``, e.g. metrics.json, after all others)."""
        with _signals_held():
            old = None
            if self.stage_dir.exists():
                if self.out.exists():
                    old = self.out.parent / f".{self.out.name}.old-{os.getpid()}"
                    os.rename(self.out, old)
                os.rename(self.stage_dir, self.out)
            outside = sorted(self._outside.items(), key=lambda kv: kv[0] == last)
            for final, staged in outside:
                if staged.exists():
                    final.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(staged, final)
            self._outside.clear()
            self._made.clear()
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)

    def discard(self) -> None:
        """Remove everything staged so far; the files in place stay as they were."""
        shutil.rmtree(self.stage_dir, ignore_errors=True)
        for staged in self._outside.values():
            try:
                staged.unlink()
            except OSError:
                pass
        self._outside.clear()
        for folder in reversed(self._made):
            try:
                folder.rmdir()
            except OSError:   # not empty: something else is in it
                pass
        self._made.clear()
