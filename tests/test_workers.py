"""Workers that die and programs that are killed: a pool or Ray worker process killed with
SIGKILL under a run (the run is retried, then given up with its reason), and sweeps or benchmarks
killed or terminated (records kept, no process left behind). Each test checks the exit code, what
is left on disk and in the process table.

The process tests read ``/proc`` (Linux); elsewhere they are skipped. (Corrupt caches, full disks
and broken GL back-ends: tests/test_reliability.py; Ray clusters: tests/test_ray_cluster.py.)
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from lfd.bench.executor import Failure, WorkerError, run_parallel

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
SWEEP_ARGS = ["--robots", "planar", "--learners", "node", "--directions", "8", "--forces", "20", "--offsets",
              "0.05", "--kinds", "push,offset", "--option", "node.iterations=30", "--option", "node.hidden=[16,16]"]
SWEEP_RUNS = 16
LONG_DIRECTIONS = 32
PROC = Path("/proc")
needs_proc = pytest.mark.skipif(not (PROC / "self" / "stat").exists(), reason="reads /proc (Linux)")


def _no_temporaries(folder: Path) -> None:
    left = [p.name for p in folder.rglob("*") if ".tmp" in p.name]
    assert not left, left


# ---------------------------------------------------------------- dead workers
def die_on_first_try(item: tuple[str, int, str]) -> int:
    """A run that kills its own worker process: ``once`` on its first try (a marker file
    remembers it), ``always`` on every try; ``fine`` returns at once. Returns 10 x index."""
    folder, index, mode = item
    marker = Path(folder) / f"tried{index}"
    if mode == "always" or (mode == "once" and not marker.exists()):
        marker.touch()
        time.sleep(0.3)   # let the other worker take its run
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.3)
    return 10 * index


def test_local_pool_retries_a_killed_run_and_gives_up_after_the_limit(tmp_path: Path) -> None:
    modes = ["fine", "once", "fine", "always", "fine"]
    items = [(str(tmp_path), i, m) for i, m in enumerate(modes)]
    done: dict[int, tuple[int, int]] = {}
    failed: dict[int, Failure] = {}
    run_parallel(die_on_first_try, items, 2, on_done=lambda i, r, n, w: done.__setitem__(i, (r, n)),
                 on_failed=failed.__setitem__)
    assert done == {0: (0, 1), 1: (10, 2), 2: (20, 1), 4: (40, 1)}
    assert failed == {3: Failure("the worker process was killed by SIGKILL", 3)}


def test_without_a_failure_callback_a_lost_run_is_a_worker_error_after_the_others(tmp_path: Path) -> None:
    items = [(str(tmp_path), 0, "always"), (str(tmp_path), 1, "fine")]
    done: dict[int, Any] = {}
    with pytest.raises(WorkerError, match=r"^1 run\(s\) lost: a worker process died under each of them 2 times "
                                          r"\(the worker process was killed by SIGKILL\)$"):
        run_parallel(die_on_first_try, items, 2, on_done=lambda i, r, n, w: done.__setitem__(i, r),
                     max_attempts=2)
    assert done == {1: 10}


def test_only_the_runs_of_the_dead_worker_count_a_try() -> None:
    """Of a broken pool's lost runs, those on the worker that died (not of the pool's SIGTERM) count a
    try; a worker that dies holding none (at start, or idle) costs nobody a try."""
    from lfd.bench.executor import _blamed

    started = [0, 101, 102, 0]           # run -> pid of the worker that took it (0: still queued)
    assert _blamed([1, 2, 3], started, {101: -signal.SIGKILL, 102: -signal.SIGTERM}) == [1]
    assert _blamed([1, 2, 3], started, {101: -signal.SIGTERM, 102: -signal.SIGTERM, 103: -signal.SIGKILL}) == []
    assert _blamed([0, 3], started, {101: -signal.SIGKILL}) == []
    assert _blamed([1, 2], started, {102: -signal.SIGTERM}) == [1]      # an exit code unknown: blamed


# ---------------------------------------------------------------- killed sweeps and benchmarks
def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/<pid>/stat after the command name (state first), None when it is gone."""
    try:
        text = (PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of a process from /proc, None when it is gone."""
    fields = _stat_fields(pid)
    return None if fields is None else (fields[0], int(fields[1]))


def _cpu_ticks(pid: int) -> int:
    """The process's user + system CPU time in clock ticks (0 when it is gone)."""
    fields = _stat_fields(pid)
    return 0 if fields is None else int(fields[11]) + int(fields[12])


def _busy_workers(pid: int) -> list[int]:
    """Pool workers below ``pid`` that used the CPU over the last 0.3 s: running a run, not waiting for
    one (a worker killed between runs has nothing in flight to retry)."""
    workers = _workers(pid)
    before = {w: _cpu_ticks(w) for w in workers}
    time.sleep(0.3)
    return [w for w in workers if _cpu_ticks(w) > before[w]]


def _cmdline(pid: int) -> str:
    try:
        return (PROC / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _descendants(pid: int) -> list[int]:
    parents: dict[int, int] = {}
    for d in PROC.iterdir():
        if d.name.isdigit() and (s := _stat(int(d.name))) is not None:
            parents[int(d.name)] = s[1]
    out, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        out += kids
        frontier += kids
    return out


def _alive(pids: list[int]) -> list[int]:
    """The processes of ``pids`` still running (a zombie has ended)."""
    return [p for p in pids if (s := _stat(p)) is not None and s[0] not in ("Z", "X")]


def _workers(pid: int) -> list[int]:
    """Pool workers below ``pid``: children of its forkserver."""
    procs = _descendants(pid)
    servers = [p for p in procs if "multiprocessing.forkserver" in _cmdline(p)
               and (s := _stat(p)) is not None and s[1] == pid]
    return [p for p in procs if (s := _stat(p)) is not None and s[1] in servers]


def _wait_for(check: Callable[[], Any], timeout: float, what: str) -> Any:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = check()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def _gone_within(pids: list[int], seconds: float) -> list[int]:
    t0 = time.monotonic()
    while _alive(pids) and time.monotonic() - t0 < seconds:
        time.sleep(0.2)
    return _alive(pids)


@pytest.fixture(scope="module")
def sweep_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a sweep subprocess, with its models trained once into a cache of its own."""
    env = {**os.environ, "LFD_CACHE_DIR": str(tmp_path_factory.mktemp("models")), "PYTHONUNBUFFERED": "1"}
    out = tmp_path_factory.mktemp("warm")
    r = subprocess.run([PYTHON, str(ROOT / "scripts" / "sweep_arm.py"), "--out", str(out), "--workers", "1",
                        "--limit", "1", *SWEEP_ARGS], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr
    return env


def _start_sweep(out: Path, env: dict[str, str], *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen([PYTHON, str(ROOT / "scripts" / "sweep_arm.py"), "--out", str(out), "--workers", "2",
                             *SWEEP_ARGS, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)


@needs_proc
def test_sweep_survives_killed_workers(sweep_env: dict[str, str], tmp_path: Path) -> None:
    """Both pool workers killed with SIGKILL once one is seen running a run: the runs they held are tried
    again (a worker seen busy may just have finished its run; its twin is then likely in one), and the
    sweep ends with every record, the retries in them."""
    runs = 2 * LONG_DIRECTIONS          # a push and an offset per direction: longer than a poll takes to see one
    proc = _start_sweep(tmp_path, sweep_env, "--directions", str(LONG_DIRECTIONS))
    try:
        def busy() -> list[int]:
            if proc.poll() is not None:
                done = len(list((tmp_path / "runs").glob("*.json")))
                raise AssertionError(f"the sweep ended ({proc.returncode}, {done} records) before a worker "
                                     "was seen busy")
            return _busy_workers(proc.pid)

        _wait_for(lambda: list((tmp_path / "runs").glob("*.json")), 300, "the first record")   # workers started
        _wait_for(busy, 120, "a pool worker running a run")
        for worker in _workers(proc.pid):
            os.kill(worker, signal.SIGKILL)
        out, err = proc.communicate(timeout=600)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    records = [json.loads(p.read_text()) for p in sorted((tmp_path / "runs").glob("*.json"))]
    assert len(records) == runs and f"{runs}/{runs} succeeded" in out
    attempts = sorted(r["attempts"] for r in records)
    assert attempts[-1] == 2 and attempts[0] == 1, attempts          # the retry is in the records
    assert all(r["error"] is None and r["metrics"] for r in records)
    _no_temporaries(tmp_path)


@needs_proc
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_killed_sweep_leaves_no_process_behind(sig: signal.Signals, sweep_env: dict[str, str],
                                               tmp_path: Path) -> None:
    proc = _start_sweep(tmp_path, sweep_env)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2, 300, "two pool workers")
        children = _descendants(proc.pid)
        os.kill(proc.pid, sig)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert _gone_within(children, 10.0) == []
    if sig == signal.SIGTERM:
        assert proc.returncode == 130 and err.strip().splitlines()[-1] == "sweep_arm: interrupted", err
    _no_temporaries(tmp_path)


@needs_proc
def test_killed_bench_leaves_no_worker_computing(tmp_path: Path) -> None:
    proc = subprocess.Popen([PYTHON, "-m", "lfd.cli", "bench", "lasa", "--learner", "dmp", "--quick", "--workers",
                             "2", "--json", str(tmp_path / "r.json"), "--report", str(tmp_path / "r.md")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2, 300, "two pool workers")
        children = _descendants(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert _gone_within(children, 10.0) == []
    assert not (tmp_path / "r.json").exists()


@needs_proc
@pytest.mark.slow
def test_killed_ray_sweep_leaves_no_process_behind(sweep_env: dict[str, str], tmp_path: Path) -> None:
    """A local Ray instance (raylet, GCS, agents, workers) ends with its driver, kill -9 included."""
    pytest.importorskip("ray")
    proc = _start_sweep(tmp_path, sweep_env, "--executor", "ray")
    try:
        _wait_for(lambda: list((tmp_path / "runs").glob("*.json")), 300, "the first record")
        children = _descendants(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert len(children) > 3 and _gone_within(children, 10.0) == []
