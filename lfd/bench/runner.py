"""Run benchmark cells in parallel local processes, resumably.

A cell is one learner, unit, seed and split of a suite (``lfd.bench.suite.Cell``; the field-level
obstacle sweep's and the Panda sweep's cells work alike). Each finished cell is written at once,
atomically, as ``<cache>/<stem>.npz`` (the figure arrays), then ``.json`` (the record, which marks
the cell done). The record carries ``hash``, the key of its inputs (the cell's); the JSON file adds
``npz_sha256`` (the sha256 of the NPZ file) and ``checksum`` (the sha256 of the canonical JSON of
everything else in it). A later run takes a cell from the cache only when both checksums hold and
the hash matches, so an interrupted run resumes where it stopped and a changed protocol or option
recomputes only what it changes. A bad entry (unreadable, edited, truncated, its NPZ missing) is
never used: it is computed again after one warning line naming it (``read_cached``).

The cells run through ``lfd.bench.executor.run_parallel`` (a local pool or Ray, surviving a dead
worker). Both compute each cell with the same code and seeds; their numbers agree to rounding across
processes (tests/test_bench.py). A record's ``attempts`` counts the tries it took and its ``node``
says where the last one ran (``run_parallel``: the host, and on Ray the node's IP and id).
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from lfd.bench.executor import Failure, check_executor, run_parallel
from lfd.errors import LfdError
from lfd.io import atomic_write, finite_or_none, write_json

# cells of slower learners first, so the pool's tail is short
LEARNER_ORDER: tuple[str, ...] = ("node", "contraction", "tracking", "dmp")


@dataclass
class BenchResult:
    """The outcome of a benchmark run (``run_cells``); ``sim.RunResult`` is one arm run instead.

    Attributes
    ----------
    records : list of dict
        One JSON record per cell, in the order of the cells given (``lfd.bench.suite.Suite.evaluate``).
    computed : list of str
        Stems of the cells trained and scored in this run.
    cached : list of str
        Stems of the cells read from the cache.
    failed : list of dict
        The cells given up (``run_parallel``), each ``{"cell": stem, "reason", "attempts"}``, or
        refused by their learner (``"refused": True``); they have no record and no cache entry, so a
        later run tries them again.
    """

    records: list[dict[str, Any]]
    computed: list[str]
    cached: list[str]
    failed: list[dict[str, Any]] = field(default_factory=list)


def _entry_checksum(entry: dict[str, Any]) -> str:
    """sha256 of the canonical JSON of a cache entry without its ``checksum``."""
    body = {k: v for k, v in entry.items() if k != "checksum"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def read_cached(cell: Any, cache: str | Path) -> tuple[dict[str, Any] | None, str | None]:
    """Check the cache entry of ``cell`` (its JSON and NPZ, module docstring).

    Returns
    -------
    (record, problem)
        ``(record, None)`` for a good entry of these inputs; ``(None, None)`` when there is none,
        or it holds other inputs (another ``hash``) or was written before entries carried a
        checksum: then the cell is simply computed; ``(None, reason)`` for a bad entry (unreadable,
        edited, truncated, its NPZ missing or not the one it names), which must be computed again.
    """
    js, npz = Path(cache) / f"{cell.stem}.json", Path(cache) / f"{cell.stem}.npz"
    if not js.is_file():
        return None, None
    try:
        entry = json.loads(js.read_text())
    except (OSError, ValueError):
        return None, "unreadable JSON"
    if not isinstance(entry, dict):
        return None, "not a cell record"
    if "checksum" not in entry:
        return None, None
    try:
        intact = entry["checksum"] == _entry_checksum(entry)
    except (TypeError, ValueError):
        intact = False
    if not intact:
        return None, "checksum mismatch (edited or corrupt)"
    if entry.get("hash") != cell.hash:
        return None, None
    try:
        data = npz.read_bytes()
    except OSError:
        return None, "its NPZ is missing or unreadable"
    if hashlib.sha256(data).hexdigest() != entry.get("npz_sha256"):
        return None, "its NPZ does not match its checksum (truncated or corrupt)"
    return {k: v for k, v in entry.items() if k not in ("checksum", "npz_sha256")}, None


def load_arrays(cache: str | Path, stem: str) -> dict[str, np.ndarray]:
    """The figure arrays of the cell ``stem`` from its cache entry."""
    with np.load(Path(cache) / f"{stem}.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def compute_cell(cell: Any) -> tuple[dict[str, Any], bytes]:
    """Train and score one cell (``cell.evaluate()``): its record (with ``hash`` and ``cell_s``,
    the wall time of training and scoring) and its figure arrays as NPZ bytes; writes nothing. A
    learner that refuses the unit (an ``LfdError``, e.g. demos it cannot train on) gives
    ``({"error": one line}, b"")``."""
    t0 = time.perf_counter()
    try:
        record, arrays = cell.evaluate()
    except LfdError as e:
        text = str(e).strip()
        return {"error": (text.splitlines()[0] if text else type(e).__name__)[:300]}, b""
    record = finite_or_none({"hash": cell.hash, **record, "cell_s": time.perf_counter() - t0})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return record, buf.getvalue()


def store_cell(cell: Any, cache: str | Path, record: dict[str, Any], npz: bytes) -> dict[str, Any]:
    """Write a computed cell: its NPZ, then its JSON (the JSON marks it done), the JSON carrying
    the NPZ's sha256 and its own checksum. Returns the record (without the two checksums)."""
    entry = {**finite_or_none(record), "npz_sha256": hashlib.sha256(npz).hexdigest()}
    entry["checksum"] = _entry_checksum(entry)
    atomic_write(Path(cache) / f"{cell.stem}.npz", lambda f: f.write(npz))
    write_json(Path(cache) / f"{cell.stem}.json", entry)
    return {k: v for k, v in entry.items() if k not in ("checksum", "npz_sha256")}


def _worker_cell(cell: Any) -> tuple[dict[str, Any], bytes]:
    """``compute_cell`` in a worker process (local pool or Ray), with one torch thread."""
    torch.set_num_threads(1)
    return compute_cell(cell)


def run_cells(cells: Sequence[Any], cache: str | Path, workers: int = 1, fresh: bool = False,
              progress: bool | None = None, executor: str = "local", address: str | None = None,
              compute: Callable[[Any], tuple[dict[str, Any], bytes]] | None = None,
              desc: str = "bench") -> BenchResult:
    """Run every cell not already in ``cache`` (all of them with ``fresh``), ``workers`` at a
    time, on ``executor`` (module docstring; ``local`` with 1 worker: in this process, with one
    torch thread; ``ray`` with ``address``: on that cluster). A bad cache entry is computed again
    after one ``RuntimeWarning`` naming it. A cell whose worker process dies is tried again, up to
    ``MAX_ATTEMPTS`` times, then listed in ``BenchResult.failed`` and left out of the records and
    the cache. ``compute`` (default: ``compute_cell``, with one torch thread) maps a cell (with
    ``stem``, ``learner`` and ``hash``, as ``lfd.bench.suite.Cell``) to (record, npz bytes); a
    record with an ``error`` is a cell its learner refused: listed in ``failed`` (``refused``),
    not cached, so a later run tries it again. ``progress``: a progress bar (default: only when
    stderr is a terminal). Returns records in the order of ``cells``."""
    address = check_executor(executor, address)
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    done: dict[str, dict[str, Any]] = {}
    cached: list[str] = []
    todo: list[Any] = []
    for c in cells:
        rec, problem = (None, None) if fresh else read_cached(c, cache)
        if problem:
            warnings.warn(f"bench cache: {cache / c.stem}.json: {problem}; computing the cell again",
                          RuntimeWarning, stacklevel=2)
        if rec is None:
            todo.append(c)
        else:
            done[c.stem] = rec
            cached.append(c.stem)
    rank = {name: i for i, name in enumerate(LEARNER_ORDER)}
    todo.sort(key=lambda c: rank.get(c.learner, len(rank)))
    failed: list[dict[str, Any]] = []
    shown = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(total=len(cells), initial=len(cached), desc=desc, unit="cell", disable=not shown)

    def finished(i: int, result: tuple[dict[str, Any], bytes], attempts: int, node: dict[str, str]) -> None:
        c = todo[i]
        record, npz = result
        if "error" in record:
            failed.append({"cell": c.stem, "reason": record["error"], "attempts": attempts, "refused": True})
        else:
            done[c.stem] = store_cell(c, cache, {**record, "attempts": attempts, "node": node}, npz)
        bar.set_postfix_str(c.stem)
        bar.update()

    def lost(i: int, failure: Failure) -> None:
        failed.append({"cell": todo[i].stem, "reason": failure.reason, "attempts": failure.attempts})
        bar.update()

    try:
        if todo:
            run_parallel(compute or _worker_cell, todo, workers, executor, address, finished, on_failed=lost)
    finally:
        bar.close()
    return BenchResult([done[c.stem] for c in cells if c.stem in done], [c.stem for c in todo], cached,
                       sorted(failed, key=lambda f: f["cell"]))
