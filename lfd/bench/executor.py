"""Run items in parallel, on a local process pool or on Ray, surviving a dead worker.

Executors (``EXECUTORS``; both through ``run_parallel``, whose callbacks run in THIS process):

* ``local``: a ``ProcessPoolExecutor`` (forkserver context where available, else spawn) with
  one torch thread each and SIGINT ignored: Ctrl-C reaches only the parent, which stops the
  pool and its processes; a cell cut short leaves no file. Each worker watches a pipe from its
  parent and ends when the parent dies (kill -9 included). A worker that dies takes the pool with
  it: the lost cells run again on a new pool, each up to ``MAX_ATTEMPTS`` times.
* ``ray``: Ray tasks (one CPU, one torch thread each). Without an address Ray starts a local
  instance with ``workers`` CPUs (no dashboard); with ``address`` (``HOST:PORT``, ``ray://HOST:PORT``
  or ``auto``; default ``$RAY_ADDRESS``) it joins that cluster. A task returns the record and the
  NPZ bytes and THIS process writes the files, so the cache needs no shared file system. A task
  whose worker Ray reports lost is submitted again, up to ``MAX_ATTEMPTS`` times. Ray is
  imported only here (``pip install 'lfd-arm[ray]'``); ``ray.shutdown()`` runs on every exit,
  Ctrl-C and SIGTERM included (``ray.init``'s own SIGTERM handler is replaced by the caller's
  again), after cancelling the cells still running. A local instance gets a watchdog process
  that ends its processes when this one dies (kill -9 included).

Used by the LASA benchmark (``lfd.bench.runner``) and ``scripts/sweep_arm.py``.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from lfd.errors import LfdError

EXECUTORS: tuple[str, ...] = ("local", "ray")
PROBE_TIMEOUT_S = 5.0      # TCP connect to a given Ray address before ray.init
MAX_ATTEMPTS = 3           # tries of a run whose worker process dies, before it is given up
EXIT_ORPHANED = 129        # a pool worker's exit code when its parent has gone (128 + SIGHUP)
_ADDRESS = re.compile(r"^(ray://)?(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9][A-Za-z0-9_.-]*):(\d{1,5})$")
_STARTED: Any = None   # in a pool worker: the shared array of the pid that runs each item


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


def _init_worker(paths: tuple[str, ...], alive: Any, started: Any) -> None:
    """Set up a pool worker: SIGINT ignored (the parent stops the pool), one torch thread, the
    import ``paths`` (before any task is unpickled: a forkserver may be older than them), the
    shared ``started`` array, warnings on one line, and a thread that ends the process when the
    parent dies."""
    global _STARTED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)
    for p in paths:
        if p not in sys.path:
            sys.path.append(p)
    _STARTED = started
    warnings.showwarning = _one_line_warning
    threading.Thread(target=_exit_with_parent, args=(alive,), name="lfd-parent-watch", daemon=True).start()


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                      file: Any = None, line: str | None = None) -> None:
    """A pool worker's warning as one line on stderr, ``warning: <message>`` (no source line)."""
    text = str(message).strip()
    try:
        print(f"warning: {text.splitlines()[0] if text else category.__name__}", file=sys.stderr)
    except (OSError, ValueError):
        pass


def _exit_with_parent(alive: Any) -> None:
    """Block on the read end of a pipe whose only write end the parent holds: its end of file
    means the parent has gone (kill -9 included), so this worker ends at once."""
    try:
        alive.recv_bytes()
    except (EOFError, OSError):
        pass
    os._exit(EXIT_ORPHANED)


def _call(fn: Callable[[Any], Any], index: int, item: Any) -> Any:
    """``fn(item)`` in a pool worker, first marking item ``index`` as started by this process."""
    if _STARTED is not None:
        _STARTED[index] = os.getpid()
    return fn(item)


def _context() -> mp.context.BaseContext:
    methods = mp.get_all_start_methods()
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")


@dataclass(frozen=True)
class Failure:
    """A run given up after its worker process died on each of ``attempts`` tries; ``reason``
    says how the last one died."""

    reason: str
    attempts: int


class WorkerError(LfdError):
    """Runs lost for good: their worker processes died ``MAX_ATTEMPTS`` times."""


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
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(address="local", num_cpus=workers, include_dashboard=False, **kwargs)
    except KeyboardInterrupt:
        ray.shutdown()
        raise
    except SystemExit as e:   # SIGTERM during ray.init, through the handler it installs
        ray.shutdown()
        if e.code == signal.SIGTERM and sigterm not in (None, signal.SIG_DFL, signal.SIG_IGN):
            raise KeyboardInterrupt from None
        raise
    except Exception as e:  # noqa: BLE001  (ConnectionError, RuntimeError, ValueError, ...)
        ray.shutdown()
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"cannot start or join {where}: {first}") from None
    finally:   # ray.init makes SIGTERM exit with code 15; keep the caller's handler (Ctrl-C, exit 130)
        if sigterm is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, sigterm)
    return ray


def run_parallel(fn: Callable[[Any], Any], items: list[Any], workers: int, executor: str = "local",
                 address: str | None = None, on_done: Callable[[int, Any, int], None] | None = None,
                 paths: tuple[str, ...] = (), on_failed: Callable[[int, Failure], None] | None = None,
                 max_attempts: int = MAX_ATTEMPTS) -> None:
    """Call the module-level function ``fn`` on every item, ``workers`` at a time, on ``executor``.

    Parameters
    ----------
    fn : callable
        A module-level function (workers import it by name) of one item.
    items : list
        The items.
    workers : int
        Parallel processes; ``local`` with 1 worker runs in this process, with one torch thread.
    executor : str
        ``local`` (a process pool) or ``ray`` (module docstring).
    address : str, optional
        The Ray cluster to join (``ray`` only).
    on_done : callable, optional
        ``on_done(index, result, attempts)``, called in THIS process as each item finishes, in any
        order; ``attempts`` counts the tries it took (1 unless a worker died under it).
    paths : tuple of str
        Directories the workers need on their import path.
    on_failed : callable, optional
        ``on_failed(index, failure)`` for an item given up (``Failure``): a worker process died
        under it ``max_attempts`` times. Without it, such items end the call with a ``WorkerError``
        once every other item is done.
    max_attempts : int
        Tries of an item whose worker process dies (kill -9, out of memory, a crash in native
        code). Local pool: the pool is replaced and the lost items submitted again; an item that
        was running beside the one that died is tried again at no cost to its count when the dead
        worker can be told apart (it did not die of the pool's own SIGTERM). Ray: the task is
        submitted again when Ray reports its worker lost.

    Notes
    -----
    Ctrl-C or an exception (of ``fn`` in a worker, or of a callback) stops the workers (local:
    terminated; Ray: tasks cancelled, then ``ray.shutdown()``) and propagates. Pool workers end
    on their own when this process dies, kill -9 included.
    """
    done = on_done or (lambda i, r, n: None)
    lost: list[tuple[int, Failure]] = []
    failed = on_failed or (lambda i, f: lost.append((i, f)))
    if executor == "ray":
        _run_ray(fn, items, workers, address, paths, done, failed, max_attempts)
    elif workers <= 1:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for i, item in enumerate(items):
                done(i, fn(item), 1)
        finally:
            torch.set_num_threads(threads)
    else:
        _run_local(fn, items, workers, paths, done, failed, max_attempts)
    if lost:
        raise WorkerError(f"{len(lost)} run(s) lost: a worker process died under each of them "
                          f"{max_attempts} times ({lost[0][1].reason})")


def _death(exitcode: int | None) -> str:
    """How a worker process ended, from its exit code."""
    if exitcode is None:
        return "the worker process died"
    if exitcode < 0:
        try:
            return f"the worker process was killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"the worker process was killed by signal {-exitcode}"
    return f"the worker process exited with code {exitcode}"


def _run_local(fn: Callable[[Any], Any], items: list[Any], workers: int, paths: tuple[str, ...],
               done: Callable[[int, Any, int], None], failed: Callable[[int, Failure], None],
               max_attempts: int) -> None:
    """``run_parallel`` on local process pools: a new pool after each worker death."""
    ctx = _context()
    started = ctx.RawArray("q", max(len(items), 1))   # item -> pid of the worker that took it
    alive_r, alive_w = ctx.Pipe(duplex=False)          # alive_w stays here: its close ends the workers
    deaths = [0] * len(items)
    queue = list(range(len(items)))
    try:
        while queue:
            pool = ProcessPoolExecutor(max_workers=min(workers, len(queue)), mp_context=ctx,
                                       initializer=_init_worker, initargs=(tuple(paths), alive_r, started))
            procs: dict[int, Any] = {}
            futures: dict[Future, int] = {}
            broken: list[int] = []
            try:
                for i in queue:
                    started[i] = 0
                    futures[pool.submit(_call, fn, i, items[i])] = i
                pending = set(futures)
                while pending:
                    procs.update(getattr(pool, "_processes", None) or {})   # the executor has no public list
                    finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        i = futures[fut]
                        if isinstance(fut.exception(), BrokenProcessPool):
                            broken.append(i)
                        else:
                            done(i, fut.result(), deaths[i] + 1)
            except BaseException:
                _kill_pool(pool)
                raise
            pool.shutdown(wait=True)
            queue = []
            if not broken:
                continue
            ran = [i for i in broken if started[i]]
            # the pool SIGTERMs its other workers when one dies: the dead one is any other end
            culprits = [i for i in ran if getattr(procs.get(started[i]), "exitcode", None) != -signal.SIGTERM]
            for i in sorted(broken):
                if i in (culprits or ran or broken):
                    deaths[i] += 1
                    if deaths[i] >= max_attempts:
                        code = getattr(procs.get(started[i]), "exitcode", None)
                        failed(i, Failure(_death(code), deaths[i]))
                        continue
                queue.append(i)
    finally:
        alive_w.close()
        alive_r.close()


def _run_ray(fn: Callable[[Any], Any], items: list[Any], workers: int, address: str | None,
             paths: tuple[str, ...], done: Callable[[int, Any, int], None],
             failed: Callable[[int, Failure], None], max_attempts: int) -> None:
    """``run_parallel`` on Ray: a task whose worker is lost is submitted again."""
    reaper = None if address else _start_reaper()
    try:
        ray = start_ray(workers, address, paths)
    except BaseException:
        _stop_reaper(reaper)
        raise
    names = ("WorkerCrashedError", "OutOfMemoryError", "NodeDiedError", "LocalRayletDiedError")
    lost_worker = tuple(getattr(ray.exceptions, n) for n in names if hasattr(ray.exceptions, n))
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(fn)
        deaths = [0] * len(items)
        refs = {remote.remote(item): i for i, item in enumerate(items)}
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    i = refs.pop(ref)
                    try:
                        result = ray.get(ref)
                    except lost_worker as e:
                        deaths[i] += 1
                        if deaths[i] >= max_attempts:
                            text = str(e).strip().splitlines()
                            failed(i, Failure(f"{type(e).__name__}: {text[0] if text else 'worker lost'}"[:200],
                                              deaths[i]))
                        else:
                            again = remote.remote(items[i])
                            refs[again] = i
                            pending.append(again)
                        continue
                    done(i, result, deaths[i] + 1)
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
    finally:
        ray.shutdown()
        _stop_reaper(reaper)


# Run by ``_start_reaper`` as ``python -c``: record the descendants of the process argv[1] every
# half second until its stdin ends (that process closed it, or died), then end those still running.
_REAPER = """
import signal, sys, threading, psutil
signal.signal(signal.SIGINT, signal.SIG_IGN)
parent, me, seen, gone = psutil.Process(int(sys.argv[1])), psutil.Process(), {}, threading.Event()
threading.Thread(target=lambda: (sys.stdin.buffer.read(), gone.set()), daemon=True).start()
while not gone.wait(0.5):
    try:
        seen.update({c.pid: c for c in parent.children(recursive=True) if c.pid != me.pid})
    except psutil.Error:
        pass
left = [c for c in seen.values() if c.is_running()]
for c in left:
    try:
        c.terminate()
    except psutil.Error:
        pass
for c in psutil.wait_procs(left, timeout=3)[1]:
    try:
        c.kill()
    except psutil.Error:
        pass
"""


def _start_reaper() -> subprocess.Popen[bytes] | None:
    """A watchdog process for a local Ray instance (its raylet, GCS and agents are this process's
    descendants): when this process ends, kill -9 included, it ends the ones still running (Ray's
    agents otherwise wait a minute on the dead GCS first). None without psutil."""
    try:
        import psutil  # noqa: F401  (Ray's own dependency)
    except ImportError:
        return None
    return subprocess.Popen([sys.executable, "-c", _REAPER, str(os.getpid())], stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


def _stop_reaper(reaper: subprocess.Popen[bytes] | None) -> None:
    """Close the reaper's stdin (it ends what ``ray.shutdown`` left) and wait for it."""
    if reaper is None:
        return
    if reaper.stdin is not None:
        reaper.stdin.close()
    try:
        reaper.wait(timeout=10)
    except subprocess.TimeoutExpired:
        reaper.kill()


def _kill_pool(pool: ProcessPoolExecutor) -> None:
    """Stop a process pool now (Ctrl-C, an error): cancel what is queued, terminate the workers."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # the executor has no public kill
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=5)
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None:   # it closes the pool's queues (and their semaphores) once it sees the workers gone
        manager.join(timeout=5)
