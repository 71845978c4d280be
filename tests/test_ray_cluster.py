"""The Ray executor on a cluster of two nodes, both on this machine: the arm sweep
(scripts/sweep_arm.py), the LASA benchmark (``lfd bench``) and ``run_parallel``'s retries.

One cluster serves the module (each Ray start costs many seconds): a head and a second node (one
CPU each, ``ray start`` in a temporary directory, free ports, token authentication with a token of
the test's own). A sweep joins them with ``--address`` and one Ray worker process is killed with
SIGKILL while it runs a task: the sweep must use both nodes, finish (exit 0, every record), show
the retry in the records' ``attempts`` and give the records of a local sweep, bit for bit
(``records.results``: timings, ``attempts`` and ``node`` left out). The benchmark's records on the
cluster are those computed locally, bit for bit, and a rerun computes nothing; a task that kills its
own worker once is run again, one that always does is given up after ``max_attempts`` tries with
Ray's reason. The cluster's processes (each node in a session of its own) are ended afterwards,
and none may be left. Slow (the Ray starts): Linux only (it reads ``/proc``); skipped without Ray.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from records import results

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
PROC = Path("/proc")
# 4 runs of one tiny learned field (2 push directions, 2 start offsets)
SWEEP = ["--robots", "planar", "--learners", "node", "--directions", "2", "--forces", "20", "--offsets", "0.05",
         "--kinds", "push,offset", "--option", "node.iterations=30", "--option", "node.hidden=[16,16]"]
RUNS = 4
TASK_TITLE = "ray::_ray_task"    # the process title of a Ray worker running one of run_parallel's tasks

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not (PROC / "self" / "stat").exists(), reason="reads /proc (Linux)")]


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _session(sid: int) -> list[int]:
    """The live processes of session ``sid`` (from /proc; a node's workers have process sessions of
    their own, in its session)."""
    out = []
    for d in PROC.iterdir():
        if d.name.isdigit():
            try:
                text = (d / "stat").read_text()
            except OSError:
                continue
            fields = text[text.rindex(")") + 2:].split()
            if int(fields[3]) == sid and fields[0] not in ("Z", "X"):
                out.append(int(d.name))
    return out


def _title(pid: int) -> str:
    try:
        return (PROC / str(pid) / "cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
    except OSError:
        return ""


def _stop(sessions: list[int]) -> None:
    """End the cluster: SIGTERM to each process of the nodes' sessions, SIGKILL to those left after
    3 s. (``ray stop`` would end every Ray process of this machine, other users' included.)"""
    for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 5.0)):
        for pid in [p for s in sessions for p in _session(s)]:
            try:
                os.kill(pid, sig)
            except OSError:
                pass
        t0 = time.monotonic()
        while any(_session(s) for s in sessions) and time.monotonic() - t0 < wait:
            time.sleep(0.2)


@pytest.fixture(scope="module")
def cluster() -> Iterator[dict[str, Any]]:
    """A head and a second node, one CPU each, and a local sweep started beside them (it trains the
    field into the model cache the cluster's sweep reads): ``{"address", "env", "sessions",
    "temp", "local"}`` (the local sweep's process)."""
    pytest.importorskip("ray")
    ray_cli = Path(PYTHON).with_name("ray")
    if not ray_cli.is_file():
        pytest.skip("no ray command beside this Python")
    temp = Path(tempfile.mkdtemp(prefix="lfdray", dir="/tmp"))   # short: Ray's socket paths must fit 107 bytes
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_AUTH_TOKEN_PATH")}
    env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32), RAY_USAGE_STATS_ENABLED="0",
               LFD_CACHE_DIR=str(temp / "models"), PYTHONUNBUFFERED="1")
    gcs, dash, agent_h, agent_w = _free_ports(4)
    common = ["--num-cpus", "1", "--object-store-memory", str(100 * 2**20), "--disable-usage-stats"]
    nodes = [["--head", "--port", str(gcs), "--include-dashboard=false", "--dashboard-port", str(dash),
              "--dashboard-agent-listen-port", str(agent_h), "--temp-dir", str(temp / "h")],
             ["--address", f"127.0.0.1:{gcs}", "--dashboard-agent-listen-port", str(agent_w),
              "--temp-dir", str(temp / "w")]]
    sessions: list[int] = []
    local = _sweep(temp / "local", env, "--workers", "1")      # in one process: no pool to start
    try:
        for args in nodes:
            proc = subprocess.Popen([str(ray_cli), "start", *args, *common], stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True)
            sessions.append(proc.pid)             # its daemons and workers stay in this session
            out = proc.communicate(timeout=180)[0]
            assert proc.returncode == 0, out[-2000:]
        yield {"address": f"127.0.0.1:{gcs}", "env": env, "sessions": sessions, "temp": temp, "local": local}
    finally:
        local.kill()
        local.communicate()
        _stop(sessions)
        left = [p for g in sessions for p in _session(g)]
        named = subprocess.run(["pgrep", "-f", str(temp)], capture_output=True, text=True).stdout.split()
        shutil.rmtree(temp, ignore_errors=True)
        assert not left and not named, (left, named)   # the cluster left no process behind


def _sweep(out: Path, env: dict[str, str], *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen([PYTHON, str(ROOT / "scripts" / "sweep_arm.py"), "--out", str(out), *SWEEP, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _records(out: Path) -> dict[str, dict[str, Any]]:
    return {p.name: json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))}


def test_a_sweep_on_two_nodes_survives_a_killed_worker_and_gives_the_local_records(cluster: dict[str, Any]) -> None:
    temp, env, head = cluster["temp"], cluster["env"], cluster["sessions"][0]
    out, err = cluster["local"].communicate(timeout=600)
    assert cluster["local"].returncode == 0, err
    proc = _sweep(temp / "ray", env, "--workers", "2", "--executor", "ray", "--address", cluster["address"])
    killed = None
    try:
        t0 = time.monotonic()
        while killed is None and proc.poll() is None and time.monotonic() - t0 < 300:
            # a worker of the head running a task (the first task of a worker loads the model: seconds);
            # the other node then runs at least the task it took meanwhile
            running = [p for p in _session(head) if _title(p).startswith(TASK_TITLE)]
            if running:
                killed = running[0]
                os.kill(killed, signal.SIGKILL)
            time.sleep(0.05)
        out, err = proc.communicate(timeout=600)
    finally:
        proc.kill()
    assert killed is not None and proc.returncode == 0, err
    assert f"{RUNS}/{RUNS} succeeded" in out and "on 2 node(s)" in out, out
    a, b = _records(temp / "local"), _records(temp / "ray")
    assert len(a) == RUNS and a.keys() == b.keys()
    for name in a:
        assert results(b[name]) == results(a[name]), name                # bit for bit
    assert sorted(r["attempts"] for r in b.values()) == [1] * (RUNS - 1) + [2]   # the killed task ran again
    nodes = {r["node"]["ray_node_id"] for r in b.values()}
    summary = json.loads((temp / "ray" / "summary.json").read_text())
    assert len(nodes) == 2 and set(summary["run"]["nodes"]) == nodes
    assert all(r["node"]["host"] == socket.gethostname() and r["node"]["ip"] for r in b.values())
    assert {r["node"]["host"] for r in a.values()} == {socket.gethostname()}


def _driver(env: dict[str, str], *argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """A Python process of ``argv`` with the cluster's token in its environment (Ray reads it when
    it starts, so drivers that join the cluster run as processes of their own)."""
    return subprocess.run([PYTHON, *argv], capture_output=True, text=True, env=env, cwd=cwd, timeout=600)


def test_the_benchmark_on_the_cluster_gives_the_local_records_and_resumes(
        cluster: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two DMP cells (fast: a contraction cell costs minutes on a loaded CI box) on the cluster and
    in this process (``--workers 1``, as every worker computes them): the same records bit for bit
    (timings and host fields left out); a rerun on the cluster computes nothing (so it starts no Ray
    driver and runs in this process too)."""
    from lfd.cli import main

    def argv(name: str, *extra: str) -> list[str]:
        return ["bench", "lasa", "--learner", "dmp", "--quick", "--shapes", "Angle,Sine", "--split", "in-sample",
                "--ring-points", "2", "--box-points", "16", "--spurious-grid", "12",
                "--json", str(tmp_path / name / "r.json"), "--report", str(tmp_path / name / "r.md"), *extra]

    on_ray = ("--executor", "ray", "--address", cluster["address"], "--workers", "2")
    p = _driver(cluster["env"], "-m", "lfd.cli", *argv("ray", *on_ray), cwd=tmp_path)   # Ray reads the token at start
    assert p.returncode == 0, p.stderr[-2000:]
    assert main(argv("local", "--workers", "1")) == 0
    r, local = (json.loads((tmp_path / n / "r.json").read_text()) for n in ("ray", "local"))
    assert r["run"]["executor"] == "ray" and r["run"]["computed"] == 2 and local["run"]["executor"] == "local"
    ref = {(c["learner"], c["shape"]): c for c in local["results"]}
    assert len(r["results"]) == 2 and ref.keys() == {(c["learner"], c["shape"]) for c in r["results"]}
    for cell in r["results"]:
        assert cell["hash"] == ref[(cell["learner"], cell["shape"])]["hash"]
        assert results(cell) == results(ref[(cell["learner"], cell["shape"])]), cell["shape"]   # bit for bit
    capsys.readouterr()
    assert main(argv("ray", *on_ray)) == 0
    assert "0 cell(s) computed, 2 from" in capsys.readouterr().out


RETRIES = """
import json, os, sys
from lfd.bench.executor import run_parallel
from test_workers import die_on_first_try

folder, address = sys.argv[1:]
items = [(folder, 0, "once"), (folder, 1, "fine"), (folder, 2, "always")]
done, failed = {}, {}
run_parallel(die_on_first_try, items, 2, "ray", address=address, on_done=lambda i, r, n, w: done.update({i: [r, n]}),
             paths=(os.getcwd(),), on_failed=lambda i, f: failed.update({i: [f.attempts, f.reason]}), max_attempts=2)
print(json.dumps({"done": done, "failed": failed}))
"""


def test_run_parallel_on_the_cluster_retries_a_killed_run_and_gives_up_after_the_limit(cluster: dict[str, Any],
                                                                                      tmp_path: Path) -> None:
    p = _driver(cluster["env"], "-c", RETRIES, str(tmp_path), cluster["address"], cwd=Path(__file__).parent)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["done"] == {"0": [0, 2], "1": [10, 1]}
    assert list(out["failed"]) == ["2"] and out["failed"]["2"][0] == 2 and "WorkerCrashedError" in out["failed"]["2"][1]
