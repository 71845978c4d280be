"""Model files: checksummed payloads, written atomically (``lfd.io``), and loading that never executes code.

A model file is a ``torch.save`` of a plain dict (strings, numbers, lists, tensors):
``{"format_version", "learner", "dim", "config", "normalization", "state_dict", "history",
"demo_box", "pose_chart", "checksum"}`` (``history``, ``demo_box``, the training demos' bounding box
[lo, hi], and ``pose_chart``, a pose field's ``lfd.pose.PoseChart``, are optional). It is read back
with ``torch.load(..., weights_only=True)``, which refuses pickled code. ``checksum`` is the sha256
of every other entry (``payload_checksum``): the tensors' dtype,
shape and bytes in key order, and the canonical JSON of the rest, so one flipped byte anywhere
in the payload is a ``ModelError`` on load, never a silently different field. Weights must be
finite. Files of format 1 (no checksum) are refused: train the model again. Older spellings
within format 2 are mapped on load (``_upgrade``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

from lfd.errors import ModelError
from lfd.io import atomic_write

FORMAT_VERSION = 2
REQUIRED_KEYS = ("format_version", "learner", "dim", "config", "normalization", "state_dict", "checksum")
MAX_MODEL_BYTES = 2 * 1024**3  # refuse to unpickle larger files: no learner of ours comes near


def _canonical(value: Any) -> str:
    """Canonical JSON of the non-tensor entries: sorted keys, tuples as lists, floats by repr."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=repr)


def payload_checksum(payload: dict[str, Any]) -> str:
    """sha256 hex digest of every entry of ``payload`` except ``checksum``.

    Tensors of ``state_dict`` enter with key, dtype, shape and raw bytes, in key order; every
    other entry enters as canonical JSON. Raises ``ModelError`` if an entry cannot be hashed.
    """
    import torch

    h = hashlib.sha256()
    try:
        rest = {k: v for k, v in payload.items() if k not in ("checksum", "state_dict")}
        h.update(_canonical(rest).encode())
        state = payload.get("state_dict") or {}
        for key in sorted(state):
            t = state[key]
            if not isinstance(t, torch.Tensor) or t.layout != torch.strided:
                raise TypeError(f"state_dict entry '{key}' is not a dense tensor")
            flat = t.detach().cpu().contiguous().reshape(-1)
            h.update(f"\0{key}\0{t.dtype}\0{tuple(t.shape)}\0".encode())
            h.update(flat.view(torch.uint8).numpy().tobytes() if flat.numel() else b"")
    except (TypeError, ValueError, RuntimeError, AttributeError) as e:
        raise ModelError(f"cannot checksum the model payload ({_first_line(e)})") from None
    return h.hexdigest()


def save_payload(payload: dict[str, Any], path: str | os.PathLike) -> None:
    """Atomically write a model payload with its checksum (see module docstring).

    The archive is built in memory first, then written with ``lfd.io.atomic_write``: a failed
    write (a full disk, a lost mount) is an ``OSError`` naming ``path`` and leaves no file behind
    (torch's own writer would turn it into a RuntimeError on a half-written archive).
    """
    import io

    import torch

    payload = {"format_version": FORMAT_VERSION, **payload}
    payload["checksum"] = payload_checksum(payload)
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getbuffer()
    atomic_write(path, lambda f: f.write(data))


def load_payload(path: str | os.PathLike, allow_nonfinite: bool = False) -> dict[str, Any]:
    """Read and check a model payload, with ``weights_only=True``.

    Checks, in order: a readable torch archive of plain data, the required keys and their types,
    the format version, the checksum (then older spellings are mapped, ``_upgrade``), finite
    weights (unless ``allow_nonfinite``: ``lfd certify`` reads such a model to report it NOT
    certified) and a consistent normalisation. Any failure
    is a one-line ``ModelError`` naming ``path``.
    """
    import torch

    p = Path(path)
    if not p.is_file():
        raise ModelError(f"{path}: no such model file")
    if p.stat().st_size > MAX_MODEL_BYTES:
        raise ModelError(f"{path}: {p.stat().st_size} bytes is too large for a model file")
    with open(p, "rb") as f:
        if f.read(4) != b"PK\x03\x04":  # torch.save's zip archive; never unpickle anything else
            raise ModelError(f"{path}: not a readable model file (not a torch archive)")
    try:
        payload = torch.load(p, map_location="cpu", weights_only=True)
    except OSError as e:   # the file opened above: torch's reader fails on a damaged archive
        raise ModelError(f"{path}: not a readable model file (truncated or corrupt: "
                         f"{e.strerror or type(e).__name__})") from None
    except Exception as e:  # noqa: BLE001  any reader failure is a bad file; never show torch's advice
        raise ModelError(f"{path}: not a readable model file ({_load_reason(e)})") from None
    if isinstance(payload, dict) and payload.get("format_version") == 1:
        raise ModelError(f"{path}: model format version 1 has no checksum and is no longer read; "
                         "train the model again")
    if isinstance(payload, dict) and "format_version" in payload and payload["format_version"] != FORMAT_VERSION:
        raise ModelError(f"{path}: model format version {str(payload['format_version'])[:20]} is not "
                         f"supported (this version reads {FORMAT_VERSION})")
    if not isinstance(payload, dict) or any(k not in payload for k in REQUIRED_KEYS):
        raise ModelError(f"{path}: not a model file (missing keys)")
    try:
        checksum = payload_checksum(payload)
    except ModelError as e:
        raise ModelError(f"{path}: {e}") from None
    if payload["checksum"] != checksum:
        raise ModelError(f"{path}: checksum mismatch: the model file is corrupt")
    _upgrade(payload)
    _check_contents(payload, str(path), allow_nonfinite)
    return payload


def _upgrade(payload: dict[str, Any]) -> None:
    """Map the older spellings of format-2 files to today's, in place, once, after the checksum
    (which covers the file as written). Every other reader sees only today's spelling."""
    history = payload.get("history")
    # Files written before the demo box became an entry of its own kept it in the training history.
    if "demo_box" not in payload and isinstance(history, dict) and "demo_box" in history:
        history = dict(history)
        payload["demo_box"] = history.pop("demo_box")
        payload["history"] = history
    # NODE files written before its option "iters" took the name every learner uses, "iterations".
    config = payload.get("config")
    if payload.get("learner") == "node" and isinstance(config, dict) and "iters" in config \
            and "iterations" not in config:
        payload["config"] = {("iterations" if k == "iters" else k): v for k, v in config.items()}


def _check_contents(payload: dict[str, Any], path: str, allow_nonfinite: bool = False) -> None:
    """Types and values of a checksummed payload (a crafted file can carry a valid checksum)."""
    import torch

    from lfd.demos import MAX_DIM

    def bad(what: str) -> ModelError:
        return ModelError(f"{path}: not a valid model file ({what})")

    if not isinstance(payload["learner"], str):
        raise bad("learner is not a name")
    dim = payload["dim"]
    if not isinstance(dim, int) or isinstance(dim, bool) or not 2 <= dim <= MAX_DIM:
        raise bad(f"dim must be an integer from 2 to {MAX_DIM}")
    if not isinstance(payload["config"], dict) or not all(isinstance(k, str) for k in payload["config"]):
        raise bad("config is not a dict of options")
    state = payload["state_dict"]
    if not isinstance(state, dict) or not state:
        raise bad("no weights")
    for key, t in state.items():
        if not isinstance(key, str) or not isinstance(t, torch.Tensor):
            raise bad(f"state_dict entry {str(key)[:40]!r} is not a tensor")
        if t.is_floating_point() and not allow_nonfinite and not bool(torch.isfinite(t).all()):
            raise ModelError(f"{path}: the model's weights contain NaN or inf ({key})")
    norm = payload["normalization"]
    try:
        goal = [float(g) for g in norm["goal"]]
        scale = float(norm["scale"])
    except (TypeError, KeyError, ValueError, IndexError):
        raise bad("normalization must hold goal and scale") from None
    if len(goal) != dim or not all(math.isfinite(g) for g in goal) or not (math.isfinite(scale) and scale > 0):
        raise bad(f"normalization needs {dim} finite goal coordinates and a positive scale")
    history = payload.get("history")
    if history is not None and not isinstance(history, dict):
        raise bad("history is not a dict")
    history = history or {}
    loss = history.get("loss")
    if loss is not None and (not isinstance(loss, (list, tuple))
                             or not all(isinstance(v, (int, float)) for v in loss)):
        raise bad("history loss is not a list of numbers")
    box = payload.get("demo_box")
    if box is not None:
        try:
            ok = (len(box) == 2 and all(len(c) == dim for c in box)
                  and all(math.isfinite(float(v)) for c in box for v in c))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise bad(f"demo_box must be two corners of {dim} finite numbers")
    chart = payload.get("pose_chart")
    if chart is not None:
        from lfd.pose import PoseChart

        if dim != 6 or not isinstance(chart, dict):
            raise bad("a pose chart needs a 6-D model")
        try:
            PoseChart.from_dict(chart)
        except (TypeError, KeyError, ValueError) as e:
            raise bad(str(e).splitlines()[0][:120]) from None


def _load_reason(e: BaseException) -> str:
    """A short reason for a failed torch.load, without torch's advice to disable weights_only."""
    import pickle
    import zipfile

    text = str(e)
    if isinstance(e, pickle.UnpicklingError) or "weights_only" in text.lower() or "Weights only" in text:
        return "it holds data other than tensors and plain values"
    if isinstance(e, (EOFError, zipfile.BadZipFile)) or "zip" in text.lower() or "archive" in text.lower():
        return "not a torch archive, or truncated"
    return type(e).__name__


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
