"""Ctrl-C (SIGINT) and SIGTERM into a running ``lfd train``, during training and during the save:
exit code 130, one line ``lfd: interrupted``, and no model file or temporary file left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from lfd.demos import save_file, spiral

ROOT = Path(__file__).resolve().parents[1]
# Runs ``lfd train`` in a child that announces on stderr when it is training (in the training loop,
# after two iterations) or saving (the whole payload written into the temporary file, before the
# rename), then lingers there so the signal lands in that phase and nowhere else.
CHILD = textwrap.dedent("""
    import sys, time
    import torch
    import lfd.learners.node as node
    from lfd.cli import main

    phase, argv = sys.argv[1], sys.argv[2:]
    if phase == "save":
        import os
        real_fsync = os.fsync
        def fsync(fd):  # the model file's atomic write: its temporary file is written, not yet renamed
            real_fsync(fd)
            print("PHASE", file=sys.stderr, flush=True)
            time.sleep(60)
        os.fsync = fsync
    else:
        real_length = node.segment_length
        said = []
        def segment_length(config, k):
            if k == 2 and not said:
                said.append(k)
                print("PHASE", file=sys.stderr, flush=True)
                time.sleep(60)  # inside the training loop, without burning the CPU others need
            return real_length(config, k)
        node.segment_length = segment_length
    sys.exit(main(argv))
""")


@pytest.fixture(scope="module")
def demos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("sig") / "demos.npz"
    save_file(spiral(n_demos=2, n_samples=40, seed=1), path)
    return path


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("phase", ["train", "save"])
def test_signal_to_this_process_exits_130_and_leaves_no_file(
        demos: Path, tmp_path: Path, phase: str, sig: signal.Signals, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Every (signal, phase) pair in-process: ``main`` installs the handlers, the test process sends
    the signal to itself from inside the training loop or from inside the save."""

    import lfd.learners.node as node
    from lfd.cli import main

    if phase == "save":
        real_fsync = os.fsync

        def fsync(fd: int) -> None:   # the model file's atomic write, before its rename
            real_fsync(fd)
            assert [p.name for p in out.parent.iterdir()][0].endswith(".tmp")  # mid-save indeed
            os.kill(os.getpid(), sig)

        monkeypatch.setattr(os, "fsync", fsync)
    else:
        real_length = node.segment_length

        def segment_length(config, k):  # type: ignore[no-untyped-def]
            if k == 2:
                os.kill(os.getpid(), sig)
            return real_length(config, k)

        monkeypatch.setattr(node, "segment_length", segment_length)
    out = tmp_path / "models" / "m.pt"
    out.parent.mkdir()
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    code = main(["train", "--demos", str(demos), "--out", str(out), "--iterations", "50" if phase == "train" else "3",
                 "--hidden", "4", "--quiet"])
    assert code == 130 and capsys.readouterr() == ("", "lfd: interrupted\n")
    assert list(out.parent.iterdir()) == []  # no model, no hidden .tmp
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before  # restored


def test_signals_exit_130_and_leave_no_file(demos: Path, tmp_path: Path) -> None:
    """Real child processes: Ctrl-C (SIGINT) during training and SIGTERM during the save, run
    concurrently (each child pays seconds of imports; the other two pairs are covered in-process)."""
    cases = [(signal.SIGINT, "train"), (signal.SIGTERM, "save")]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    children = []
    try:
        for sig, phase in cases:
            out = tmp_path / f"{sig.name}-{phase}" / "m.pt"
            out.parent.mkdir()
            iters = "100000" if phase == "train" else "3"
            argv = ["train", "--demos", str(demos), "--out", str(out), "--iterations", iters, "--hidden", "4",
                    "--quiet"]
            proc = subprocess.Popen([sys.executable, "-c", CHILD, phase, *argv], stderr=subprocess.PIPE,
                                    stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env, preexec_fn=as_from_a_terminal)
            children.append((sig, phase, out, proc))
        for sig, phase, out, proc in children:
            line = proc.stderr.readline()  # blocks until the child is in the phase (or dies)
            assert line.strip() == "PHASE", f"{sig.name} {phase}: " + line + proc.stderr.read()
            if phase == "save":
                assert [p.name for p in out.parent.iterdir()][0].endswith(".tmp")  # mid-save indeed
            proc.send_signal(sig)
        for sig, phase, out, proc in children:
            rest = proc.stderr.read()
            code = proc.wait(timeout=120)
            assert (code, rest) == (130, "lfd: interrupted\n"), f"{sig.name} {phase}: {code} {rest}"
            assert proc.stdout.read() == ""
            assert list(out.parent.iterdir()) == [], f"{sig.name} {phase}"  # no model, no hidden .tmp
    finally:
        for *_, proc in children:
            proc.kill()
            proc.wait()
            proc.stdout.close()
            proc.stderr.close()


def _handles_sigterm(pid: int) -> bool:
    """Whether the process has a handler for SIGTERM (Python itself installs none: the program's
    code has started), from its caught-signal mask in /proc."""
    try:
        with open(f"/proc/{pid}/status") as f:
            mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(mask >> (signal.SIGTERM - 1) & 1)


# the file a program writes last, when it ran to its end
def as_from_a_terminal() -> None:
    """In the child before it starts: SIGINT and SIGTERM at their defaults, as a shell starts a
    program. (A process that ignores SIGINT, as a test worker may after some library did so,
    passes that on, and Python then ignores a Ctrl-C until the program sets its own handler.)"""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


COMPLETE = {"sweep_arm": "summary.json", "lfd": "m.pt", "demo_arm": "metrics.json"}
# the project's files that run before the handlers are in place: the interpreter's start-up, then these
BEFORE_HANDLERS = ("lfd/__init__.py", "lfd/errors.py", "lfd/interrupts.py", "lfd/lazy.py", "lfd/cli.py",
                   "scripts/sweep_arm.py", "sim/__init__.py", "sim/media/gl.py", "sim/errors.py", "sim/run/cli.py")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the signal masks in /proc")
def test_early_signal_exits_130_without_traceback(tmp_path: Path) -> None:
    """SIGINT and SIGTERM into ``scripts/sweep_arm.py``, ``lfd train`` and the installed
    ``lfd-demo-arm`` launcher (whose first line imports ``sim.run.cli``) a few moments after their
    start: during the interpreter's start-up, the programs' module-level imports and their first
    work. Once the program's code has taken the signals (SIGTERM caught at the moment it is sent)
    the end is exit 130, exactly one line ``<prog>: interrupted``, nothing on stdout and nothing
    written; before, the signal ends the bare interpreter (killed by it, or Python's own
    KeyboardInterrupt from its start-up), with no frame of the project's code past its first lines
    and nothing written either."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "LFD_CACHE_DIR": str(tmp_path / "models")}
    sweep = [sys.executable, str(ROOT / "scripts" / "sweep_arm.py"), "--robots", "planar", "--learners",
             "contraction", "--kinds", "push", "--directions", "1", "--forces", "20", "--workers", "1"]
    lfd = [sys.executable, "-c", "import sys; from lfd.cli import main; sys.exit(main())", "train", "--demos",
           "spiral", "--iterations", "100000", "--quiet"]
    launcher = [str(Path(sys.executable).parent / "lfd-demo-arm"), "--robot", "planar", "--learner", "contraction",
                "--perturb", "none", "--no-video", "--iters", "100000", "--quiet"]
    cases = [("sweep_arm", sweep, 0.02, signal.SIGINT), ("sweep_arm", sweep, 0.1, signal.SIGTERM),
             ("sweep_arm", sweep, 0.1, signal.SIGINT), ("sweep_arm", sweep, 0.3, signal.SIGTERM),
             ("sweep_arm", sweep, 0.5, signal.SIGINT), ("lfd", lfd, 0.05, signal.SIGTERM),
             ("lfd", lfd, 0.3, signal.SIGINT), ("demo_arm", launcher, 0.15, signal.SIGTERM),
             ("demo_arm", launcher, 0.4, signal.SIGINT)]
    cases = [c for c in cases if Path(c[1][0]).exists()]   # the launcher: where the project is installed
    (tmp_path / "models").mkdir()
    children = []
    try:
        for i, (prog, argv, delay, sig) in enumerate(cases):
            out = tmp_path / f"out{i}"
            argv = [*argv, "--out", str(out / "m.pt" if prog == "lfd" else out)]
            proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                                    env=env, preexec_fn=as_from_a_terminal)
            children.append([prog, delay, sig, out, proc, time.monotonic(), None])
        pending = sorted(children, key=lambda c: c[1])
        for child in pending:  # each signal at its delay after its child's start
            time.sleep(max(0.0, child[5] + child[1] - time.monotonic()))
            child[6] = _handles_sigterm(child[4].pid)
            child[4].send_signal(child[2])
        lost = False
        for prog, delay, sig, out, proc, _, ours in children:
            stdout, stderr = proc.communicate(timeout=120)
            what = f"{prog} {sig.name} at {delay} s: rc {proc.returncode}, stderr {stderr[-600:]!r}"
            if not ours and proc.returncode == 0:
                # CPython's own start-up can drop a signal (before any code of the project runs: the
                # program then simply runs to its end); what it wrote must then be the whole run
                lost = True
                assert (out / COMPLETE[prog]).is_file(), what
                continue
            assert not out.exists() or not any(out.rglob("*")), what + f"; left {list(out.rglob('*'))}"
            if ours:
                assert (proc.returncode, stderr, stdout) == (130, f"{prog}: interrupted\n", ""), what
            elif proc.returncode != 130:   # the bare interpreter, before the program's first lines had run
                assert proc.returncode in (-sig, 1), what
                frames = [line.split('"')[1] for line in stderr.splitlines() if line.startswith('  File "')]
                project = [f for f in frames if f.startswith(str(ROOT)) and not f.startswith(sys.prefix)]
                assert all(f.endswith(BEFORE_HANDLERS) for f in project), what
            else:
                assert stderr == f"{prog}: interrupted\n" and "Traceback" not in stderr, what
        if not lost:
            assert not [p for p in (tmp_path / "models").rglob("*") if p.is_file()]   # no model half-cached
    finally:
        for child in children:
            child[4].kill()
            child[4].wait()
