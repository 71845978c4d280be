"""Run benchmark cells in parallel local processes, resumably.

A cell is one (learner, shape, seed). Each finished cell is written at once, atomically, as
``<cache>/<learner>__<shape>__seed<seed>.json`` (the record) and ``.npz`` (the figure arrays).
The record carries ``hash`` = stable_hash(protocol, learner, resolved config, shape, seed); a
later run skips a cell whose JSON and NPZ exist and whose hash matches, so an interrupted run
resumes where it stopped and a changed protocol or option recomputes only what it changes.

Workers are a ``ProcessPoolExecutor`` (forkserver context where available, else spawn) with
one torch thread each and SIGINT ignored: Ctrl-C reaches only the parent, which stops the
pool and its processes; a cell cut short leaves no file.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import multiprocessing as mp
import signal
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from lfd.bench.protocol import Protocol, stable_hash
from lfd.modelfile import atomic_write

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
    """One unit of work. options : the learner's keyword options (as passed to ``lfd.train``)."""

    learner: str
    shape: str
    seed: int
    options: dict[str, Any] = field(hash=False)
    protocol: Protocol = field(hash=False)
    hash: str = ""

    @classmethod
    def make(cls, learner: str, shape: str, seed: int, options: dict[str, Any],
             protocol: Protocol) -> "Cell":
        key = {"protocol": protocol.to_dict(), "learner": learner,
               "config": resolve_config(learner, options), "shape": shape, "seed": seed}
        return cls(learner, shape, seed, dict(options), protocol, stable_hash(key))

    @property
    def stem(self) -> str:
        return f"{self.learner}__{self.shape}__seed{self.seed}"


@dataclass
class RunResult:
    """records : one JSON record per cell, in the order of the cells given;
    computed, cached : stems of the cells trained in this run and of those read from the cache."""

    records: list[dict[str, Any]]
    computed: list[str]
    cached: list[str]


def finite_or_none(obj: Any) -> Any:
    """A copy of a JSON-able structure with NaN and +-inf replaced by None (strict JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if isinstance(obj, np.generic):
        return finite_or_none(obj.item())
    return obj


def write_json(path: str | Path, obj: Any) -> None:
    """Strict JSON (non-finite -> null), indented, written atomically."""
    text = json.dumps(finite_or_none(obj), indent=1, allow_nan=False) + "\n"
    atomic_write(path, lambda f: f.write(text.encode()))


def cached_record(cell: Cell, cache: Path) -> dict[str, Any] | None:
    """The cell's record if its JSON and NPZ exist and its hash matches, else None."""
    js, npz = cache / f"{cell.stem}.json", cache / f"{cell.stem}.npz"
    if not (js.is_file() and npz.is_file()):
        return None
    try:
        record = json.loads(js.read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("hash") == cell.hash else None


def load_arrays(cache: str | Path, record: dict[str, Any]) -> dict[str, np.ndarray]:
    """The figure arrays of a record (see ``lfd.bench.evaluate.evaluate_cell``)."""
    stem = f"{record['learner']}__{record['shape']}__seed{record['seed']}"
    with np.load(Path(cache) / f"{stem}.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def run_cell(cell: Cell, cache: str) -> dict[str, Any]:
    """Train and score one cell, write its NPZ then its JSON (the JSON marks it done).
    The record gets ``hash`` and ``cell_s``, the wall time of training and scoring."""
    from lfd.bench.evaluate import evaluate_cell

    t0 = time.perf_counter()
    record, arrays = evaluate_cell(cell.learner, cell.shape, cell.seed, cell.options, cell.protocol)
    record = finite_or_none({"hash": cell.hash, **record, "cell_s": time.perf_counter() - t0})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    atomic_write(Path(cache) / f"{cell.stem}.npz", lambda f: f.write(buf.getvalue()))
    write_json(Path(cache) / f"{cell.stem}.json", record)
    return record


def _init_worker() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)


def _context() -> mp.context.BaseContext:
    methods = mp.get_all_start_methods()
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")


def run_cells(cells: list[Cell], cache: str | Path, workers: int = 1, fresh: bool = False,
              progress: bool = True) -> RunResult:
    """Run every cell not already in ``cache`` (all of them with ``fresh``), ``workers`` at a
    time (1: in this process, with one torch thread). Returns records in the order of ``cells``."""
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    done: dict[str, dict[str, Any]] = {}
    cached: list[str] = []
    todo: list[Cell] = []
    for c in cells:
        rec = None if fresh else cached_record(c, cache)
        if rec is None:
            todo.append(c)
        else:
            done[c.stem] = rec
            cached.append(c.stem)
    rank = {name: i for i, name in enumerate(LEARNER_ORDER)}
    todo.sort(key=lambda c: rank.get(c.learner, len(rank)))
    bar = tqdm(total=len(cells), initial=len(cached), desc="lasa", unit="cell", disable=not progress)
    try:
        if workers <= 1:
            threads = torch.get_num_threads()
            torch.set_num_threads(1)
            try:
                for c in todo:
                    bar.set_postfix_str(c.stem)
                    done[c.stem] = run_cell(c, str(cache))
                    bar.update()
            finally:
                torch.set_num_threads(threads)
        else:
            _run_pool(todo, cache, workers, done, bar)
    finally:
        bar.close()
    return RunResult([done[c.stem] for c in cells], [c.stem for c in todo], cached)


def _run_pool(todo: list[Cell], cache: Path, workers: int, done: dict[str, dict[str, Any]],
              bar: Any) -> None:
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_context(), initializer=_init_worker)
    futures: dict[Future, Cell] = {pool.submit(run_cell, c, str(cache)): c for c in todo}
    try:
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                c = futures[fut]
                done[c.stem] = fut.result()
                bar.set_postfix_str(c.stem)
                bar.update()
    except BaseException:
        procs = list(getattr(pool, "_processes", {}).values())  # the executor has no public kill
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(timeout=5)
        raise
    pool.shutdown(wait=True)
