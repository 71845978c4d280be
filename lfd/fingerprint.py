"""A fingerprint of the code behind a result: the source of some modules and all they import of lfd.

The caches (``lfd.cache`` for trained fields, ``lfd.bench.suite`` for benchmark cells) put it in their
keys, so a result computed before a change to a learner's code, or to the code that scores it, is
never read back as if it were current. The closure is found statically (every ``import`` and
``from ... import`` in a module, those inside functions included, with the packages that hold each
module), so it holds what could run, not only what ran. Comments and docstrings count: any edit of
a file in the closure makes a new fingerprint.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
from functools import cache
from pathlib import Path

ROOT = "lfd"


def code_fingerprint(*modules: str, exclude: tuple[str, ...] = ()) -> str:
    """16 hex digits: sha256 over the names and source bytes of ``modules`` and of every module of
    ``lfd`` they import, transitively (module docstring).

    Parameters
    ----------
    *modules : str
        Dotted module names of ``lfd``, e.g. ``"lfd.learners.node"``, ``"lfd.bench.lasa"``.
    exclude : tuple of str
        Modules (and the modules inside them) left out and not followed: code that only presents a
        result (report text, pages, plots) and cannot change a number.

    Returns
    -------
    str
        The fingerprint; the same for the same files, in any process.
    """
    return _fingerprint(tuple(sorted(set(modules))), tuple(sorted(set(exclude))))


@cache
def _fingerprint(modules: tuple[str, ...], exclude: tuple[str, ...]) -> str:
    data = hashlib.sha256()
    for name in sorted(closure(modules, exclude)):
        data.update(name.encode() + b"\0" + read_source(name) + b"\0")
    return data.hexdigest()[:16]


def closure(modules: tuple[str, ...], exclude: tuple[str, ...] = ()) -> set[str]:
    """The modules of ``lfd`` that ``modules`` import, transitively, with their packages and themselves,
    less those in ``exclude`` (and what only they import)."""
    seen: set[str] = set()
    todo = list(modules)
    while todo:
        name = todo.pop()
        if name in seen or _path(name) is None or any(name == e or name.startswith(e + ".") for e in exclude):
            continue
        seen.add(name)
        parts = name.split(".")
        todo.extend(".".join(parts[:k]) for k in range(1, len(parts)))   # the packages run on import
        todo.extend(_imports(name))
    return seen


def read_source(name: str) -> bytes:
    """The source bytes of module ``name`` (empty when it has no source file)."""
    path = _path(name)
    return b"" if path is None else path.read_bytes()


@cache
def _path(name: str) -> Path | None:
    """The source file of an ``lfd`` module, or None for a name that is no such module."""
    if name != ROOT and not name.startswith(ROOT + "."):
        return None
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError, AttributeError):
        return None
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    return Path(spec.origin)


def _imports(name: str) -> list[str]:
    """The ``lfd`` modules named by the imports of module ``name`` (for ``from a import b``: ``a``, and
    ``a.b`` where that is a module)."""
    path = _path(name)
    if path is None:
        return []
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[str] = []
    for node in ast.walk(ast.parse(read_source(name))):
        if isinstance(node, ast.Import):
            found.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            found.append(base)
            found.extend(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return [m for m in found if m == ROOT or m.startswith(ROOT + ".")]
