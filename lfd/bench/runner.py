"""Run benchmark cells in parallel local processes, resumably.

A cell is one (learner, shape, seed). Each finished cell is written at once, atomically, as
``<cache>/<learner>__<shape>__seed<seed>.npz`` (the figure arrays), then ``.json`` (the record,
which marks the cell done). The record carries ``hash`` = stable_hash(protocol, learner, resolved
config, shape, seed), the key of its inputs; the JSON file adds ``npz_sha256`` (the sha256 of the
NPZ file) and ``checksum`` (the sha256 of the canonical JSON of everything else in it). A later run
takes a cell from the cache only when both checksums hold and the hash matches, so an interrupted
run resumes where it stopped and a changed protocol or option recomputes only what it changes. A
bad entry (unreadable, edited, truncated, its NPZ missing) is never used: it is computed again
after one warning line naming it (``read_cached``).

The cells run through ``lfd.bench.executor.run_parallel`` (a local pool or Ray, surviving a dead
worker). Both compute each cell with the same code and seeds; their numbers agree to rounding across
processes (tests/test_bench.py, rtol 1e-6). A record's ``attempts`` counts the tries it took and
its ``node`` says where the last one ran (``run_parallel``: the host, and on Ray the node's IP and id).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
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
from lfd.bench.protocol import LasaProtocol, stable_hash
from lfd.io import atomic_write, finite_or_none, write_json

# cells of slower learners first, so the pool's tail is short
LEARNER_ORDER: tuple[str, ...] = ("node", "contraction", "tracking", "dmp")


def resolve_config(learner: str, options: dict[str, Any]) -> dict[str, Any]:
    """The learner's full config for ``options`` (defaults filled in); ConfigError if invalid."""
    if learner == "dmp":
        from lfd.bench.dmp import make_config

        return dataclasses.asdict(make_config(**options))
    from lfd.learners import get_learner

    return dataclasses.asdict(get_learner(learner).make_config(**options))


@dataclass(frozen=True)
class Cell:
    """One unit of work: one learner trained with one seed on one LASA shape, and scored.

    Build it with ``make``, which computes ``hash``; each field is described beside it.
    """

    learner: str                                  # a name of lfd.learners.LEARNERS, or "dmp"
    shape: str                                    # a LASA shape name
    seed: int                                     # the learner's seed
    options: dict[str, Any] = field(hash=False)   # the learner's keyword options, as for lfd.train
    protocol: LasaProtocol = field(hash=False)    # the benchmark's fixed settings
    hash: str = ""                                # the cache key: protocol, learner, full config, shape, seed

    @classmethod
    def make(cls, learner: str, shape: str, seed: int, options: dict[str, Any],
             protocol: LasaProtocol) -> Cell:
        key = {"protocol": protocol.to_dict(), "learner": learner,
               "config": resolve_config(learner, options), "shape": shape, "seed": seed}
        return cls(learner, shape, seed, dict(options), protocol, stable_hash(key))

    @property
    def stem(self) -> str:
        return f"{self.learner}__{self.shape}__seed{self.seed}"


@dataclass
class BenchResult:
    """The outcome of a benchmark run (``run_cells``); ``sim.RunResult`` is one arm run instead.

    Attributes
    ----------
    records : list of dict
        One JSON record per cell, in the order of the cells given (``evaluate_cell``).
    computed : list of str
        Stems (``Cell.stem``) of the cells trained and scored in this run.
    cached : list of str
        Stems of the cells read from the cache.
    failed : list of dict
        The cells given up (``run_parallel``), each ``{"cell": stem, "reason", "attempts"}``; they
        have no record and no cache entry, so a later run tries them again.
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


def read_cached(cell: Cell, cache: str | Path) -> tuple[dict[str, Any] | None, str | None]:
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


def cached_record(cell: Cell, cache: str | Path) -> dict[str, Any] | None:
    """The cell's record if its cache entry is good and of these inputs (``read_cached``), else None."""
    return read_cached(cell, cache)[0]


def load_arrays(cache: str | Path, record: dict[str, Any]) -> dict[str, np.ndarray]:
    """The figure arrays of a record (see ``lfd.bench.evaluate.evaluate_cell``)."""
    stem = f"{record['learner']}__{record['shape']}__seed{record['seed']}"
    with np.load(Path(cache) / f"{stem}.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def compute_cell(cell: Cell) -> tuple[dict[str, Any], bytes]:
    """Train and score one cell: its record (with ``hash`` and ``cell_s``, the wall time of
    training and scoring) and its figure arrays as NPZ bytes. Writes nothing."""
    from lfd.bench.evaluate import evaluate_cell

    t0 = time.perf_counter()
    record, arrays = evaluate_cell(cell.learner, cell.shape, cell.seed, cell.options, cell.protocol)
    record = finite_or_none({"hash": cell.hash, **record, "cell_s": time.perf_counter() - t0})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    return record, buf.getvalue()


def store_cell(cell: Cell, cache: str | Path, record: dict[str, Any], npz: bytes) -> dict[str, Any]:
    """Write a computed cell: its NPZ, then its JSON (the JSON marks it done), the JSON carrying
    the NPZ's sha256 and its own checksum. Returns the record (without the two checksums)."""
    entry = {**finite_or_none(record), "npz_sha256": hashlib.sha256(npz).hexdigest()}
    entry["checksum"] = _entry_checksum(entry)
    atomic_write(Path(cache) / f"{cell.stem}.npz", lambda f: f.write(npz))
    write_json(Path(cache) / f"{cell.stem}.json", entry)
    return {k: v for k, v in entry.items() if k not in ("checksum", "npz_sha256")}


def run_cell(cell: Cell, cache: str) -> dict[str, Any]:
    """Train and score one cell and write it to ``cache`` (``compute_cell``, ``store_cell``)."""
    return store_cell(cell, cache, *compute_cell(cell))


def _worker_cell(cell: Cell) -> tuple[dict[str, Any], bytes]:
    """``compute_cell`` in a worker process (local pool or Ray), with one torch thread."""
    torch.set_num_threads(1)
    return compute_cell(cell)


def run_cells(cells: Sequence[Any], cache: str | Path, workers: int = 1, fresh: bool = False,
              progress: bool = True, executor: str = "local", address: str | None = None,
              compute: Callable[[Any], tuple[dict[str, Any], bytes]] | None = None,
              desc: str = "lasa") -> BenchResult:
    """Run every cell not already in ``cache`` (all of them with ``fresh``), ``workers`` at a
    time, on ``executor`` (module docstring; ``local`` with 1 worker: in this process, with one
    torch thread; ``ray`` with ``address``: on that cluster). A bad cache entry is computed again
    after one ``RuntimeWarning`` naming it. A cell whose worker process dies is tried again, up to
    ``MAX_ATTEMPTS`` times, then listed in ``BenchResult.failed`` and left out of the records and
    the cache. ``compute`` (default: a LASA cell's) maps a cell (with ``stem`` and ``learner``, as
    ``Cell``) to (record, npz bytes); a record with an ``error`` is a cell its learner refused: listed
    in ``failed`` (``refused``), not cached, so a later run tries it again. Returns records in the
    order of ``cells``."""
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
    bar = tqdm(total=len(cells), initial=len(cached), desc=desc, unit="cell", disable=not progress)

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
