"""Model files: atomic writes, and loading that never executes code.

A model file is a ``torch.save`` of a plain dict (strings, numbers, lists, tensors):
``{"format_version", "learner", "dim", "config", "normalization", "state_dict", "history"}``.
It is read back with ``torch.load(..., weights_only=True)``, which refuses pickled code.
"""

from __future__ import annotations

import os
import pickle
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Callable, BinaryIO

import torch

from lfd.errors import ModelError

FORMAT_VERSION = 1
REQUIRED_KEYS = ("format_version", "learner", "dim", "config", "normalization", "state_dict")


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> None:
    """Write through ``write(file)`` into a temporary file beside ``path``, fsync, then rename.

    A crash or Ctrl-C mid-write leaves any previous file at ``path`` untouched.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_payload(payload: dict[str, Any], path: str | os.PathLike) -> None:
    """Atomically write a model payload (see module docstring)."""
    payload = {"format_version": FORMAT_VERSION, **payload}
    atomic_write(path, lambda f: torch.save(payload, f))


def load_payload(path: str | os.PathLike) -> dict[str, Any]:
    """Read and check a model payload, with ``weights_only=True``."""
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        payload = torch.load(p, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, OSError, ValueError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ModelError(f"{path}: not a readable model file ({first})") from None
    if not isinstance(payload, dict) or any(k not in payload for k in REQUIRED_KEYS):
        raise ModelError(f"{path}: not a model file (missing keys)")
    if payload["format_version"] != FORMAT_VERSION:
        raise ModelError(f"{path}: model format version {payload['format_version']} is not supported "
                         f"(this version reads {FORMAT_VERSION})")
    return payload
