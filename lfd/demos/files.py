"""Demo files: CSV and NPZ, read as recordings (``lfd.demos.recording`` cleans them) and written atomically."""

from __future__ import annotations

import csv
import os
import re
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import BinaryIO

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.demos.recording import recorded_set
from lfd.errors import DemoError
from lfd.io import atomic_write

POSE_HEADER = ["demo", "t", "x", "y", "z", "qw", "qx", "qy", "qz"]
_PER_DEMO = re.compile(r"[txq]\d+")   # the NPZ keys of demos of their own lengths: t0, x0, q0, t1, ...


def load_file(path: str | os.PathLike, clean: bool | str | Iterable[str] = True) -> DemoSet:
    """Read demos from a CSV or an NPZ file, as recordings: cleaned up (``lfd.demos.recording``: gaps,
    noise, standing still, pauses, lengths; ``DemoSet.notes`` says what was done). ``clean`` names the
    clean-up steps to run (``lfd.demos.recording.clean_steps``: True all, False none).

    - CSV, positions: columns ``demo,t,x1..xd``; poses: ``demo,t,x,y,z,qw,qx,qy,qz`` (metres, the
      robot's base frame; the header decides). Each demo has its own rows, of any number.
    - NPZ, demos of one length: ``t`` (T,) or (N, T), ``x`` (N, T, d), and for poses ``q`` (N, T, 4).
    - NPZ, demos of their own lengths: ``t0`` (T_0,), ``x0`` (T_0, d), ``q0`` (T_0, 4) for poses,
      then ``t1``, ``x1``, ... numbered from 0 without holes.

    Quaternions are (w, x, y, z). Demos of different lengths (after the clean-up) are resampled in
    time to the longest length: positions linearly, orientations by spherical interpolation.
    """
    p = Path(path)
    name = str(path)
    if not p.is_file():
        raise DemoError(f"{name}: no such file")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npz":
            return _load_npz(p, name, clean)
        if suffix == ".csv":
            return _load_csv(p, name, clean)
    except DemoError:
        raise
    except PermissionError:
        raise
    except MemoryError:
        raise DemoError(f"{name}: too large to load") from None
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, csv.Error) as e:
        text = str(e).strip()
        raise DemoError(f"{name}: cannot read ({text.splitlines()[0][:200] if text else type(e).__name__})") from None
    raise DemoError(f"{name}: unknown demo file type '{suffix}' (use .csv or .npz)")


def _real_array(a: np.ndarray, key: str, name: str) -> np.ndarray:
    """``a`` as float64 if it holds real numbers (ints, unsigned ints, floats); else DemoError."""
    if np.iscomplexobj(a):
        raise DemoError(f"{name}: {key} holds complex numbers; positions, times and quaternions must be real")
    if a.dtype.kind not in "iuf":
        raise DemoError(f"{name}: {key} must hold numbers, got dtype {a.dtype}")
    return np.asarray(a, dtype=np.float64)


def _load_npz(p: Path, name: str, clean: bool | str | Iterable[str]) -> DemoSet:
    if not zipfile.is_zipfile(p):
        raise DemoError(f"{name}: not an NPZ file (not a zip archive, or truncated)")
    with np.load(p, allow_pickle=False) as z:
        arrays = {key: _real_array(z[key], key, name) for key in z.files if key in ("t", "x", "q")
                  or _PER_DEMO.fullmatch(key)}
    if any(_PER_DEMO.fullmatch(key) for key in arrays):
        return _per_demo_npz(arrays, name, clean)
    missing = {"t", "x"} - set(arrays)
    if missing:
        raise DemoError(f"{name}: missing array(s) {', '.join(sorted(missing))} (need t and x, or t0, x0, "
                        "t1, x1, ...)")
    t, x, q = arrays["t"], arrays["x"], arrays.get("q")
    if x.ndim != 3:
        raise DemoError(f"{name}: x must have shape (N, T, d), got {x.shape}")
    if t.ndim == 1:
        if t.shape[0] != x.shape[1]:
            raise DemoError(f"{name}: t has {t.shape[0]} samples but x has {x.shape[1]}")
        t = np.broadcast_to(t, x.shape[:2])
    elif t.shape != x.shape[:2]:
        raise DemoError(f"{name}: t must have shape (T,) or {x.shape[:2]}, got {t.shape}")
    if q is not None and q.shape != (*x.shape[:2], 4):
        raise DemoError(f"{name}: quaternions have shape {q.shape}, expected {(*x.shape[:2], 4)} (w, x, y, z)")
    return recorded_set(list(t), list(x), None if q is None else list(q), name, clean)


def _per_demo_npz(arrays: dict[str, np.ndarray], name: str, clean: bool | str | Iterable[str]) -> DemoSet:
    """Demos of their own lengths: t0 (T_0,), x0 (T_0, d)[, q0 (T_0, 4)], t1, ..."""
    if "t" in arrays or "x" in arrays:
        raise DemoError(f"{name}: holds both t, x and per-demo arrays t0, x0, ...; use one layout")
    n = 1 + max(int(key[1:]) for key in arrays)
    poses = any(key.startswith("q") for key in arrays)
    need = [f"{k}{i}" for i in range(n) for k in ("tx" + "q" * poses)]
    missing = [key for key in need if key not in arrays]
    if missing:
        raise DemoError(f"{name}: per-demo arrays t0, x0{', q0' * poses}, t1, ... must be numbered from 0 "
                        f"without holes; missing {', '.join(missing[:6])}")
    d = arrays["x0"].shape[-1] if arrays["x0"].ndim == 2 else None
    for i in range(n):
        t, x = arrays[f"t{i}"], arrays[f"x{i}"]
        if t.ndim != 1 or x.ndim != 2 or x.shape != (len(t), d):
            raise DemoError(f"{name}: t{i} has shape {t.shape} and x{i} {x.shape}; expected (T,) and (T, d) "
                            "with one d for every demo")
        if poses and arrays[f"q{i}"].shape != (len(t), 4):
            raise DemoError(f"{name}: q{i} has shape {arrays[f'q{i}'].shape}, expected {(len(t), 4)} (w, x, y, z)")
    return recorded_set([arrays[f"t{i}"] for i in range(n)], [arrays[f"x{i}"] for i in range(n)],
                        [arrays[f"q{i}"] for i in range(n)] if poses else None, name, clean)


def _load_csv(p: Path, name: str, clean: bool | str | Iterable[str]) -> DemoSet:
    with open(p, newline="", encoding="utf-8-sig") as f:  # -sig: spreadsheets may write a BOM
        rows = list(csv.reader(f))
    if not rows:
        raise DemoError(f"{name}: empty file")
    header = [h.strip() for h in rows[0]]
    d = len(header) - 2
    pose = header == POSE_HEADER
    if not pose and (header[:2] != ["demo", "t"] or header[2:] != [f"x{i + 1}" for i in range(d)] or d < 1):
        raise DemoError(f"{name}: header must be demo,t,x1..xd or {','.join(POSE_HEADER)}, "
                        f"got {','.join(header)}")
    demos: dict[str, list[list[float]]] = {}
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != d + 2:
            raise DemoError(f"{name}: line {line} has {len(row)} columns, expected {d + 2} "
                            "(mixed dimensions)")
        try:
            demos.setdefault(row[0].strip(), []).append([float(c) for c in row[1:]])
        except ValueError:
            raise DemoError(f"{name}: line {line} has a value that is not a number") from None
    if not demos:
        raise DemoError(f"{name}: no samples")
    arrays = [np.asarray(v) for v in demos.values()]
    if pose:
        return recorded_set([a[:, 0] for a in arrays], [a[:, 1:4] for a in arrays], [a[:, 4:] for a in arrays],
                            name, clean)
    return recorded_set([a[:, 0] for a in arrays], [a[:, 1:] for a in arrays], None, name, clean)


def save_file(demos: DemoSet, path: str | os.PathLike) -> None:
    """Write demos as CSV or NPZ (by suffix), atomically; ``load_file`` reads them back bit for bit
    when the clean-up finds nothing to do (a set it cleaned, the generated ones)."""
    p = Path(path)
    if p.suffix.lower() == ".npz":
        def write(f: BinaryIO) -> None:
            if demos.q is None:
                np.savez(f, t=demos.t, x=demos.x)
            else:
                np.savez(f, t=demos.t, x=demos.x, q=demos.q)
    elif p.suffix.lower() == ".csv":
        def write(f: BinaryIO) -> None:
            pose = demos.q is not None
            lines = [",".join(POSE_HEADER) if pose else "demo,t," + ",".join(f"x{j + 1}" for j in range(demos.dim))]
            values = np.concatenate([demos.x, demos.q], axis=-1) if demos.q is not None else demos.x
            for i in range(demos.n_demos):
                for k in range(demos.n_samples):
                    lines.append(f"{i},{float(demos.t[i, k])!r}," + ",".join(repr(float(v)) for v in values[i, k]))
            f.write(("\n".join(lines) + "\n").encode())
    else:
        raise DemoError(f"{path}: unknown demo file type (use .csv or .npz)")
    atomic_write(p, write)
