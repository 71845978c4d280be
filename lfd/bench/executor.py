"""Run items in parallel, on a local process pool or on Ray, surviving a dead worker.

Executors (``EXECUTORS``; both through ``run_parallel``, whose callbacks run in THIS process):

* ``local``: a ``ProcessPoolExecutor`` (forkserver context where available, else spawn), one
  thread each for torch and the native pools (BLAS, OpenMP), SIGINT ignored: Ctrl-C reaches only
  the parent, which stops the pool; an item cut short leaves no file. Each worker ends when its
  parent dies (kill -9 included). A worker that dies takes the pool with it: the lost items run
  again on a new pool, each up to ``MAX_ATTEMPTS`` times. A worker imports ``fn`` by its module's
  name from this process's import path (nothing here edits ``sys.path``).
* ``ray``: Ray tasks (one CPU, one thread each). Without an address Ray starts a local instance
  with ``workers`` CPUs; with ``address`` (``HOST:PORT``, ``ray://HOST:PORT`` or ``auto``; default
  ``$RAY_ADDRESS``) it joins that cluster. A task returns its result and THIS process writes the
  files, so the cache needs no shared file system. A task whose worker Ray reports lost is
  submitted again, up to ``MAX_ATTEMPTS`` times. Ray is imported only here (``pip install
  'lfd-arm[ray]'``); ``ray.shutdown()`` runs on every exit, Ctrl-C and SIGTERM included, without
  cancelling the running tasks first (``_run_ray``); a local instance gets a watchdog process
  that ends its processes when this one dies. Joining a cluster with token authentication needs
  ``RAY_AUTH_MODE=token`` and its token (``_init_error`` says so in one line).

Each finished item comes with where it ran (``on_done``'s ``node``: ``{"host"}`` on the local
pool; ``{"host", "ip", "ray_node_id"}`` of the Ray node), for the records' ``node`` field: a host
field, not a result. Used by the benchmark suites (``lfd.bench.runner``), ``lfd bench tradeoff``
and the arm sweeps.
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
import tempfile
import threading
import traceback
import warnings
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from lfd.errors import LfdError

EXECUTORS: tuple[str, ...] = ("local", "ray")
PROBE_TIMEOUT_S = 5.0      # TCP connect to a given Ray address before ray.init
MAX_ATTEMPTS = 3           # tries of a run whose worker process dies, before it is given up
EXIT_ORPHANED = 129        # a pool worker's exit code when its parent has gone (128 + SIGHUP)
_ADDRESS = re.compile(r"^(ray://)?(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9][A-Za-z0-9_.-]*):(\d{1,5})$")
_STARTED: Any = None   # in a pool worker: the shared array of the pid that runs each item
_TOKEN_HINT = "set RAY_AUTH_MODE=token, with the cluster's token in ~/.ray/auth_token or $RAY_AUTH_TOKEN"

#: ``on_done(index, result, attempts, node)`` of ``run_parallel``
OnDone = Callable[[int, Any, int, dict[str, str]], None]


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


def _init_worker(alive: Any, started: Any) -> None:
    """Set up a pool worker: SIGINT ignored (the parent stops the pool), one thread for torch and
    in each native pool (BLAS, OpenMP; ``lfd.threads.limit_native_threads``), the shared ``started``
    array, warnings on one line, tqdm's lock a thread lock, and a thread that ends the process when
    the parent dies.

    tqdm's default lock holds a named semaphore in a forkserver or spawn worker, which a killed
    worker cannot unlink: the parent's resource tracker would then warn of "leaked semaphore
    objects" at exit (the workers draw no bars, so a lock between processes serves nothing)."""
    global _STARTED
    from tqdm import tqdm

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tqdm.set_lock(threading.RLock())
    from lfd.threads import limit_native_threads

    limit_native_threads(1)   # torch, numpy's BLAS, OpenMP: one thread, as in a Ray task and in-process
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
    their PYTHONPATH: on a cluster of several machines, the same checkout at the same path on each).

    Returns the ``ray`` module; ``ConfigError`` (one line) when Ray is missing or the cluster cannot
    be joined (a cluster that wants a token this process does not send says so). What Ray's C++
    code writes on stderr while joining is held back, and shown only when the join succeeds. Call
    ``ray.shutdown()`` when done."""
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
    held = _HeldStderr()
    try:
        if address:
            with held:   # an unauthenticated join: a warning a second for ~20 s before the error
                ray.init(address=address, **kwargs)
            _write_stderr(held.text)
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
        raise ConfigError(f"cannot start or join {where}: {_init_error(e, held.text)}") from None
    finally:   # ray.init makes SIGTERM exit with code 15; keep the caller's handler (Ctrl-C, exit 130)
        if sigterm is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, sigterm)
    return ray


def _init_error(error: Exception, stderr: str) -> str:
    """One line on why ``ray.init`` failed, from its exception and what Ray wrote on stderr."""
    auth = "AuthenticationError" in type(error).__name__ or "InvalidAuthToken" in stderr + str(error)
    if auth and os.environ.get("RAY_AUTH_MODE", "").strip().lower() != "token":
        return f"it wants token authentication ({_TOKEN_HINT})"
    if auth:
        return "it refused this process's Ray token (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token)"
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class _HeldStderr:
    """File descriptor 2 sent to a temporary file inside the ``with`` block (Ray's C++ code writes
    there, past ``sys.stderr``); ``text`` is what was written, once the block has ended."""

    def __init__(self) -> None:
        self.text = ""
        self._saved = -1
        self._file: Any = None

    def __enter__(self) -> _HeldStderr:
        try:
            sys.stderr.flush()
            self._file = tempfile.TemporaryFile()
            self._saved = os.dup(2)
            os.dup2(self._file.fileno(), 2)
        except (OSError, ValueError):   # no fd 2 to redirect: leave stderr alone
            self._restore()
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._restore()

    def _restore(self) -> None:
        if self._saved >= 0:
            try:
                sys.stderr.flush()
            except (OSError, ValueError):
                pass
            os.dup2(self._saved, 2)
            os.close(self._saved)
            self._saved = -1
        if self._file is not None:
            self._file.seek(0)
            self.text = self._file.read().decode(errors="replace")
            self._file.close()
            self._file = None


def _write_stderr(text: str) -> None:
    if text:
        try:
            sys.stderr.write(text)
        except (OSError, ValueError):
            pass


def local_node() -> dict[str, str]:
    """Where an item of the local pool (or of this process) ran: ``{"host": hostname}``."""
    return {"host": socket.gethostname()}


def ray_node() -> dict[str, str]:
    """Where this Ray task runs: ``{"host", "ip", "ray_node_id"}`` of its node (in a Ray worker)."""
    import ray

    return {"host": socket.gethostname(), "ip": str(ray.util.get_node_ip_address()),
            "ray_node_id": str(ray.get_runtime_context().get_node_id())}


def _ray_task(fn: Callable[[Any], Any], item: Any) -> tuple[Any, dict[str, str]]:
    """A Ray task: ``fn(item)`` (one thread in each native pool, as in a local worker) and the node
    that ran it (``ray_node``)."""
    from lfd.threads import native_threads

    with native_threads(1):
        return fn(item), ray_node()


def run_parallel(fn: Callable[[Any], Any], items: list[Any], workers: int, executor: str = "local",
                 address: str | None = None, on_done: OnDone | None = None,
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
        Parallel processes; ``local`` with 1 worker runs in this process, one thread for torch and
        each native pool (as every worker).
    executor : str
        ``local`` (a process pool) or ``ray`` (module docstring).
    address : str, optional
        The Ray cluster to join (``ray`` only).
    on_done : callable, optional
        ``on_done(index, result, attempts, node)``, called in THIS process as each item finishes,
        in any order; ``attempts`` counts the tries it took (1 unless a worker died under it) and
        ``node`` says where the last one ran (``local_node``; Ray: ``ray_node``).
    paths : tuple of str
        Directories Ray's workers need on their ``PYTHONPATH`` besides this ``lfd``'s (a local pool's
        workers start with this process's import path).
    on_failed : callable, optional
        ``on_failed(index, failure)`` for an item given up (``Failure``): a worker process died
        under it ``max_attempts`` times. Without it, such items end the call with a ``WorkerError``
        once every other item is done.
    max_attempts : int
        Tries of an item whose worker process dies (kill -9, out of memory, a crash in native
        code). Local pool: the pool is replaced and the lost items submitted again; only the items
        that were running on the worker that died count a try (``_blamed``: the others ended by the
        pool's own SIGTERM); a worker that dies holding no item costs nobody a try, unless pools
        keep dying so ``max_attempts`` times in a row with nothing done. Ray: the task is submitted
        again when Ray reports its worker lost.

    Notes
    -----
    Ctrl-C or an exception (of ``fn`` in a worker, or of a callback) stops the workers (local:
    terminated; Ray: ``ray.shutdown()``, module docstring) and propagates. Pool workers end
    on their own when this process dies, kill -9 included.
    """
    done = on_done or (lambda i, r, n, w: None)
    lost: list[tuple[int, Failure]] = []
    failed = on_failed or (lambda i, f: lost.append((i, f)))
    if executor == "ray":
        _run_ray(fn, items, workers, address, paths, done, failed, max_attempts)
    elif workers <= 1:
        from lfd.threads import native_threads

        with native_threads(1):   # as in a pool worker or a Ray task: the same floats
            here = local_node()
            for i, item in enumerate(items):
                done(i, fn(item), 1, here)
    else:
        _run_local(fn, items, workers, done, failed, max_attempts)
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


def _run_local(fn: Callable[[Any], Any], items: list[Any], workers: int, done: OnDone,
               failed: Callable[[int, Failure], None], max_attempts: int) -> None:
    """``run_parallel`` on local process pools: a new pool after each worker death."""
    here = local_node()
    ctx = _context()
    started = ctx.RawArray("q", max(len(items), 1))   # item -> pid of the worker that took it
    alive_r, alive_w = ctx.Pipe(duplex=False)          # alive_w stays here: its close ends the workers
    deaths = [0] * len(items)
    queue = list(range(len(items)))
    idle_deaths = 0   # pools broken in a row by a worker that held no item (dying at start, or idle)
    try:
        while queue:
            progress = False
            pool = ProcessPoolExecutor(max_workers=min(workers, len(queue)), mp_context=ctx,
                                       initializer=_init_worker, initargs=(alive_r, started))
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
                            done(i, fut.result(), deaths[i] + 1, here)
                            progress = True
            except BaseException:
                _kill_pool(pool)
                raise
            pool.shutdown(wait=True)
            queue = []
            if not broken:
                continue
            exitcodes = {pid: getattr(proc, "exitcode", None) for pid, proc in procs.items()}
            blamed = _blamed(broken, started, exitcodes)
            idle_deaths = 0 if blamed or progress else idle_deaths + 1
            if not blamed and idle_deaths >= max_attempts:   # the pool keeps dying with nothing running
                blamed = list(broken)
            codes = [c for c in exitcodes.values() if c not in (None, -signal.SIGTERM)]
            for i in sorted(broken):
                if i in blamed:
                    deaths[i] += 1
                    if deaths[i] >= max_attempts:
                        code = exitcodes.get(started[i], codes[0] if codes else None)
                        failed(i, Failure(_death(code), deaths[i]))
                        continue
                queue.append(i)
    finally:
        alive_w.close()
        alive_r.close()


def _blamed(broken: list[int], started: Any, exitcodes: dict[int, int | None]) -> list[int]:
    """The items of a broken pool to charge a try: those that were running on the worker that died.

    Parameters
    ----------
    broken : list of int
        The items the broken pool lost (running or still queued).
    started : sequence of int
        Item -> pid of the worker that took it (0: none did).
    exitcodes : dict
        Pid -> exit code of the pool's workers (None: unknown).

    Returns
    -------
    list of int
        The lost items that ran on a worker that ended other than by the pool's SIGTERM (which the
        pool sends its other workers when one dies); empty when the dead worker held none (it died
        starting, or idle): the lost items are then tried again at no cost.
    """
    return [i for i in broken if started[i] and exitcodes.get(started[i]) != -signal.SIGTERM]


def _run_ray(fn: Callable[[Any], Any], items: list[Any], workers: int, address: str | None,
             paths: tuple[str, ...], done: OnDone, failed: Callable[[int, Failure], None],
             max_attempts: int) -> None:
    """``run_parallel`` on Ray (``_ray_items``), then ``ray.shutdown()``: on an exception, Ctrl-C
    included, nothing is cancelled first (``ray.cancel`` racing a task's completion aborts the
    driver inside Ray, "Check failed: ... submissible_tasks_"; ``ray.shutdown`` ends a local
    instance with its workers, and a cluster's raylets end the tasks of a driver that has left),
    and the locals of the frames it passed through are dropped first: an ``ObjectRef`` freed after
    ``ray.shutdown`` ends the process at once with exit code 1 (Ray's core worker is gone), and its
    traceback would hold some."""
    reaper = None if address else _start_reaper()
    try:
        ray = start_ray(workers, address, paths)
    except BaseException:
        _stop_reaper(reaper)
        raise
    try:
        _ray_items(ray, fn, items, done, failed, max_attempts)
    except BaseException as e:
        traceback.clear_frames(e.__traceback__)
        raise
    finally:
        ray.shutdown()
        _stop_reaper(reaper)


def _ray_items(ray: Any, fn: Callable[[Any], Any], items: list[Any], done: OnDone,
               failed: Callable[[int, Failure], None], max_attempts: int) -> None:
    """Run every item as a Ray task; a task whose worker is lost is submitted again."""
    names = ("WorkerCrashedError", "OutOfMemoryError", "NodeDiedError", "LocalRayletDiedError")
    lost_worker = tuple(getattr(ray.exceptions, n) for n in names if hasattr(ray.exceptions, n))
    remote = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
    deaths = [0] * len(items)
    refs = {remote.remote(fn, item): i for i, item in enumerate(items)}
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        for ref in ready:
            i = refs.pop(ref)
            try:
                result, node = ray.get(ref)
            except lost_worker as e:
                deaths[i] += 1
                if deaths[i] >= max_attempts:
                    text = str(e).strip().splitlines()
                    failed(i, Failure(f"{type(e).__name__}: {text[0] if text else 'worker lost'}"[:200], deaths[i]))
                else:
                    again = remote.remote(fn, items[i])
                    refs[again] = i
                    pending.append(again)
                continue
            done(i, result, deaths[i] + 1, node)


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
