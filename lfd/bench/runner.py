"""Run benchmark cells in parallel local processes, resumably.

A cell is one (learner, shape, seed). Each finished cell is written at once, atomically, as
``<cache>/<learner>__<shape>__seed<seed>.json`` (the record) and ``.npz`` (the figure arrays).
The record carries ``hash`` = stable_hash(protocol, learner, resolved config, shape, seed); a
later run skips a cell whose JSON and NPZ exist and whose hash matches, so an interrupted run
resumes where it stopped and a changed protocol or option recomputes only what it changes.

Executors (``EXECUTORS``):

* ``local``: a ``ProcessPoolExecutor`` (forkserver context where available, else spawn) with
  one torch thread each and SIGINT ignored: Ctrl-C reaches only the parent, which stops the
  pool and its processes; a cell cut short leaves no file.
* ``ray``: Ray tasks (one CPU, one torch thread each). Without an address Ray starts a local
  instance with ``workers`` CPUs (no dashboard); with ``address`` (``HOST:PORT``, ``ray://HOST:PORT``
  or ``auto``; default ``$RAY_ADDRESS``) it joins that cluster. A task returns the record and the
  NPZ bytes and THIS process writes the files, so the cache needs no shared file system. Ray is
  imported only here (``pip install 'lfd-arm[ray]'``); ``ray.shutdown()`` runs on every exit,
  Ctrl-C included, after cancelling the cells still running.

Both compute each cell with the same code and seeds; their numbers agree to rounding across
processes (tests/test_bench.py, rtol 1e-6).
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import multiprocessing as mp
import os
import re
import signal
import socket
import sys
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from lfd.bench.protocol import LasaProtocol, stable_hash
from lfd.io import atomic_write, finite_or_none, write_json

# cells of slower learners first, so the pool's tail is short
LEARNER_ORDER: tuple[str, ...] = ("node", "contraction", "tracking", "dmp")
EXECUTORS: tuple[str, ...] = ("local", "ray")
PROBE_TIMEOUT_S = 5.0      # TCP connect to a given Ray address before ray.init
_ADDRESS = re.compile(r"^(ray://)?(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9][A-Za-z0-9_.-]*):(\d{1,5})$")


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
    """

    records: list[dict[str, Any]]
    computed: list[str]
    cached: list[str]


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
    """Write a computed cell: its NPZ, then its JSON (the JSON marks it done). Returns the record."""
    atomic_write(Path(cache) / f"{cell.stem}.npz", lambda f: f.write(npz))
    write_json(Path(cache) / f"{cell.stem}.json", record)
    return record


def run_cell(cell: Cell, cache: str) -> dict[str, Any]:
    """Train and score one cell and write it to ``cache`` (``compute_cell``, ``store_cell``)."""
    return store_cell(cell, cache, *compute_cell(cell))


def _init_worker(paths: tuple[str, ...] = ()) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)
    for p in paths:                      # before any task is unpickled (a forkserver may be older)
        if p not in sys.path:
            sys.path.append(p)


def _context() -> mp.context.BaseContext:
    methods = mp.get_all_start_methods()
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")


def check_executor(executor: str, address: str | None = None) -> str | None:
    """Validate an executor name and a Ray address (``HOST:PORT``, ``ray://HOST:PORT`` or ``auto``;
    None: ``$RAY_ADDRESS`` if set, for ``ray``; a HOST:PORT must accept a TCP connection within
    ``PROBE_TIMEOUT_S``). Returns the address to join (None: start locally); ``ConfigError`` with
    one line otherwise. Does not import Ray."""
    from lfd.errors import ConfigError

    if executor not in EXECUTORS:
        raise ConfigError(f"unknown executor '{executor}'; known: {', '.join(EXECUTORS)}")
    if executor != "ray":
        if address:
            raise ConfigError("--address needs --executor ray")
        return None
    if address is None:
        address = os.environ.get("RAY_ADDRESS") or None
        source = "RAY_ADDRESS"
    else:
        source = "--address"
    if address is None or address == "auto":
        return address
    match = _ADDRESS.match(address.strip())
    if not match or not 0 < int(match.group(3)) < 65536:
        raise ConfigError(f"{source} '{address}': expected HOST:PORT (e.g. 10.0.0.5:6379), ray://HOST:PORT or auto")
    host, port = match.group(2).strip("[]"), int(match.group(3))
    try:   # fail fast: ray.init waits minutes for an unreachable cluster, printing C++ warnings
        socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S).close()
    except OSError as e:
        raise ConfigError(f"{source} '{address}': no Ray cluster reachable there "
                          f"({e.strerror or type(e).__name__})") from None
    return address.strip()


def run_cells(cells: list[Cell], cache: str | Path, workers: int = 1, fresh: bool = False,
              progress: bool = True, executor: str = "local", address: str | None = None) -> BenchResult:
    """Run every cell not already in ``cache`` (all of them with ``fresh``), ``workers`` at a
    time, on ``executor`` (module docstring; ``local`` with 1 worker: in this process, with one
    torch thread; ``ray`` with ``address``: on that cluster). Returns records in the order of
    ``cells``."""
    address = check_executor(executor, address)
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
        if executor == "ray":
            if todo:
                _run_ray(todo, cache, workers, address, done, bar)
        elif workers <= 1:
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
    return BenchResult([done[c.stem] for c in cells], [c.stem for c in todo], cached)


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
        _kill_pool(pool)
        raise
    pool.shutdown(wait=True)


def _ray_cell(cell: Cell) -> tuple[dict[str, Any], bytes]:
    """``compute_cell`` in a Ray worker, with one torch thread."""
    torch.set_num_threads(1)
    return compute_cell(cell)


def start_ray(workers: int, address: str | None, paths: tuple[str, ...] = ()) -> Any:
    """``ray.init``: join the cluster at ``address``, else start a local instance with ``workers``
    CPUs and no dashboard; the workers import this same ``lfd`` (its directory, and ``paths``, on
    their PYTHONPATH). Returns the ``ray`` module; ``ConfigError`` (one line) when Ray is missing or
    unreachable. Call ``ray.shutdown()`` when done."""
    from lfd.errors import ConfigError

    try:
        import ray
    except ImportError:
        raise ConfigError("--executor ray needs Ray: pip install 'lfd-arm[ray]'") from None
    root = str(Path(__file__).resolve().parents[2])
    path = os.pathsep.join(p for p in (root, *paths, os.environ.get("PYTHONPATH", "")) if p)
    runtime_env = {"env_vars": {"PYTHONPATH": path, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}}
    kwargs: dict[str, Any] = dict(runtime_env=runtime_env, log_to_driver=False, logging_level=logging.ERROR)
    try:
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(address="local", num_cpus=workers, include_dashboard=False, **kwargs)
    except KeyboardInterrupt:
        ray.shutdown()
        raise
    except Exception as e:  # noqa: BLE001  (ConnectionError, RuntimeError, ValueError, ...)
        ray.shutdown()
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"cannot start or join {where}: {first}") from None
    return ray


def run_parallel(fn: Callable[[Any], Any], items: list[Any], workers: int, executor: str = "local",
                 address: str | None = None, on_done: Callable[[int, Any], None] | None = None,
                 paths: tuple[str, ...] = ()) -> None:
    """Call the module-level function ``fn`` on every item, ``workers`` at a time, on ``executor``
    (module docstring; ``local`` with 1 worker: in this process), and ``on_done(index, result)``
    in THIS process as each finishes, in any order. ``paths``: directories the workers need on
    their import path (Ray). Ctrl-C or an exception stops the workers (local: terminated; Ray:
    tasks cancelled, then ``ray.shutdown()``) and propagates."""
    done = on_done or (lambda i, r: None)
    if executor == "ray":
        ray = start_ray(workers, address, paths)
        try:
            remote = ray.remote(num_cpus=1, max_retries=0)(fn)
            refs = {remote.remote(item): i for i, item in enumerate(items)}
            pending = list(refs)
            try:
                while pending:
                    ready, pending = ray.wait(pending, num_returns=1)
                    for ref in ready:
                        done(refs[ref], ray.get(ref))
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise
        finally:
            ray.shutdown()
        return
    if workers <= 1:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for i, item in enumerate(items):
                done(i, fn(item))
        finally:
            torch.set_num_threads(threads)
        return
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_context(), initializer=_init_worker,
                               initargs=(tuple(paths),))
    futures: dict[Future, int] = {pool.submit(fn, item): i for i, item in enumerate(items)}
    try:
        pending_f = set(futures)
        while pending_f:
            finished, pending_f = wait(pending_f, return_when=FIRST_COMPLETED)
            for fut in finished:
                done(futures[fut], fut.result())
    except BaseException:
        _kill_pool(pool)
        raise
    pool.shutdown(wait=True)


def _run_ray(todo: list[Cell], cache: Path, workers: int, address: str | None,
             done: dict[str, dict[str, Any]], bar: Any) -> None:
    def finished(i: int, result: tuple[dict[str, Any], bytes]) -> None:
        c = todo[i]
        done[c.stem] = store_cell(c, cache, *result)
        bar.set_postfix_str(c.stem)
        bar.update()

    run_parallel(_ray_cell, todo, workers, "ray", address, finished)


def _kill_pool(pool: ProcessPoolExecutor) -> None:
    """Stop a process pool now (Ctrl-C, an error): cancel what is queued, terminate the workers."""
    procs = list(getattr(pool, "_processes", {}).values())  # the executor has no public kill
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=5)
