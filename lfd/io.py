"""Writing files, for the whole tree: atomic writes and strict JSON.

- ``atomic_path``: a temporary path beside the target that replaces it on success (for writers
  that need a file name, e.g. a video encoder); ``atomic_write``: the same through a file object,
  fsync'ed. A crash, Ctrl-C or SIGTERM mid-write leaves any previous file untouched.
- ``finite_or_none``, ``json_text`` and ``write_json``: strict JSON (RFC 8259 has no NaN or
  Infinity): every non-finite float is written as null, numpy scalars and arrays as plain numbers
  and lists, and ``allow_nan=False`` refuses anything that slips through.
- ``check_writable`` and ``same_file``: checks before long work that its output can be written.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

from lfd.errors import OutputError

__all__ = ["atomic_path", "atomic_write", "check_writable", "finite_or_none", "json_text", "kept_section", "same_file",
           "write_json"]


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary file beside ``path`` to write; on a clean exit it replaces ``path``.

    Parameters
    ----------
    path : str or path-like
        The file to write; missing parent folders are created.
    suffix : str
        The temporary file's suffix (e.g. ``.mp4`` where the writer picks a format by suffix).

    Yields
    ------
    Path
        The temporary file (created empty, named ``.<name>.<random><suffix>``). On a clean exit
        it gets the usual permissions (0666 less the umask) and is renamed to ``path``; on any
        exception (KeyboardInterrupt included) it is removed and ``path`` is left as it was.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=p.parent)
    os.close(fd)
    done = False
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, p)
        done = True
    finally:
        if not done and os.path.exists(tmp):
            os.unlink(tmp)


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> None:
    """Write through ``write(file)`` into a temporary file beside ``path``, fsync, then rename.

    A crash, Ctrl-C or SIGTERM (see ``lfd.cli``) mid-write leaves any previous file at ``path``
    untouched and removes the temporary file. An ``OSError`` names ``path``, not the temporary file.

    Parameters
    ----------
    path : str or path-like
        The file to write.
    write : callable
        Writes the content to the binary file object it is given.
    """
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
    except OSError as e:
        raise OSError(e.errno, e.strerror or str(e), str(path)) from None


def finite_or_none(obj: Any) -> Any:
    """A copy of a JSON-able structure with NaN and +-inf as None (null in JSON).

    Dicts, lists and tuples are copied recursively (tuples become lists); numpy scalars become
    Python numbers and numpy arrays nested lists; anything else is returned as is.
    """
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    np = sys.modules.get("numpy")  # not imported: then no numpy value can be here
    if np is not None and isinstance(obj, np.ndarray):
        return finite_or_none(obj.tolist())
    if np is not None and isinstance(obj, np.generic):
        return finite_or_none(obj.item())
    return obj


def json_text(obj: Any, indent: int | None = 2) -> str:
    """Strict JSON of ``obj`` (``finite_or_none``, then ``allow_nan=False``), ending in a newline.

    Raises ``TypeError`` for a value JSON cannot hold.
    """
    return json.dumps(finite_or_none(obj), indent=indent, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike, obj: Any, indent: int | None = 2) -> None:
    """Write ``json_text(obj, indent)`` to ``path`` atomically (``atomic_write``)."""
    data = json_text(obj, indent).encode()
    atomic_write(path, lambda f: f.write(data))


def check_writable(path: str | os.PathLike, what: str = "output") -> None:
    """Raise ``OutputError`` unless a file could be written at ``path`` (checked before long work).

    The path must not be a folder, and its folder (or the nearest existing parent, which
    ``atomic_write`` creates the rest below) must accept a new file: probed by creating and
    removing an empty temporary file, which also works for root and read-only mounts.
    """
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{path}: is a folder, not a file ({what})")
    parent = p.parent
    while not parent.exists():
        if parent == parent.parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{path}: cannot write ({parent} is not a folder)")
    try:
        fd, probe = tempfile.mkstemp(prefix=".lfd-probe.", dir=parent)
    except OSError as e:
        raise OutputError(f"{path}: cannot write ({e.strerror or type(e).__name__})") from None
    os.close(fd)
    os.unlink(probe)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name the same file (the same resolved path, or the same inode)."""
    try:
        if Path(a).resolve() == Path(b).resolve():
            return True
        return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)
    except OSError:
        return False


def kept_section(path: str | os.PathLike, heading: str) -> list[str]:
    """The lines of the markdown file ``path`` from the line ``heading`` on (a hand-written section
    that a script keeps when it rewrites the rest of its report), or none if either is missing.

    Parameters
    ----------
    path : str or path-like
        The report.
    heading : str
        The section's heading line, e.g. ``"## Why the NODE misses"``.

    Returns
    -------
    list of str
        The lines, without line ends.
    """
    p = Path(path)
    if not p.exists():
        return []
    old = p.read_text().splitlines()
    return old[old.index(heading):] if heading in old else []
