"""Hostile input: every bad input is one line on stderr and exit 2, nothing half-written.

Property-based (hypothesis): malformed CSV, NPZ and model bytes give either a valid result or a
typed error (an ``LfdError``) with a one-line message. Then the command-line paths: output paths
checked before any work, outputs that would overwrite inputs, resource limits, seeds, training
that never reaches a finite loss or is interrupted, the model cache and ``demo_arm.py``.
"""

from __future__ import annotations

import io
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lfd
from lfd.cli import main
from lfd.demos import save_file, spiral
from lfd.errors import LfdError

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--iterations", "3", "--hidden", "4", "--quiet"]
FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """Valid demo files (CSV, NPZ) and a valid model file, as bytes, to mutate."""
    d = tmp_path_factory.mktemp("valid")
    demos = spiral(n_demos=2, n_samples=20, seed=1)
    save_file(demos, d / "d.csv")
    save_file(demos, d / "d.npz")
    lfd.train("node", demos, iterations=2, hidden=(4,)).save(d / "m.pt")
    return {name: (d / name).read_bytes() for name in ("d.csv", "d.npz", "m.pt")}


def _mutate(data: bytes, cuts: list[tuple[int, int]], tail: int | None) -> bytes:
    """Flip bytes at (position mod length, xor value) pairs, then keep ``tail`` bytes if given."""
    buf = bytearray(data)
    for at, xor in cuts:
        if buf:
            buf[at % len(buf)] ^= xor or 1
    return bytes(buf[:tail] if tail is not None else buf)


def _one_line_or_valid(load, path: Path) -> None:  # type: ignore[no-untyped-def]
    try:
        load(path)
    except LfdError as e:
        text = str(e)
        assert text and len(text.splitlines()) == 1, repr(text)
        assert "weights_only" not in text


MUTATIONS = dict(cuts=st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 255)), max_size=4),
                 tail=st.none() | st.integers(0, 4000))


@FUZZ
@given(**MUTATIONS)
def test_fuzzed_csv_is_valid_or_a_one_line_error(files, tmp_path, cuts, tail) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "f.csv"
    path.write_bytes(_mutate(files["d.csv"], cuts, tail))
    _one_line_or_valid(lfd.demos.load_file, path)


@FUZZ
@given(**MUTATIONS)
def test_fuzzed_npz_is_valid_or_a_one_line_error(files, tmp_path, cuts, tail) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "f.npz"
    path.write_bytes(_mutate(files["d.npz"], cuts, tail))
    _one_line_or_valid(lfd.demos.load_file, path)


@FUZZ
@given(**MUTATIONS)
def test_fuzzed_model_is_identical_or_a_one_line_error(files, tmp_path, cuts, tail) -> None:  # type: ignore[no-untyped-def]
    data = _mutate(files["m.pt"], cuts, tail)
    path = tmp_path / "m.pt"
    path.write_bytes(data)
    try:
        field = lfd.load(str(path))
    except LfdError as e:
        assert len(str(e).splitlines()) == 1 and "weights_only" not in str(e)
        return
    # it loaded: then the weights are the original ones (the checksum let no flipped weight through)
    original = tmp_path / "orig.pt"
    original.write_bytes(files["m.pt"])
    ref = lfd.load(str(original))
    for k, v in ref.module.state_dict().items():
        assert torch.equal(field.module.state_dict()[k], v)


@FUZZ
@given(arrays=st.dictionaries(st.sampled_from(["t", "x", "y"]),
                              st.sampled_from(["complex", "text", "empty", "3d", "int", "bool", "nan"]),
                              max_size=3))
def test_npz_with_odd_arrays_is_valid_or_a_one_line_error(tmp_path, arrays) -> None:  # type: ignore[no-untyped-def]
    good = spiral(n_demos=2, n_samples=20, seed=1)
    make = {"complex": lambda a: a.astype(complex), "text": lambda a: np.full(a.shape, "a"),
            "empty": lambda a: a[:0], "3d": lambda a: a[..., None], "int": lambda a: (a * 100).astype(int),
            "bool": lambda a: a > 0, "nan": lambda a: a * np.nan}
    base = {"t": good.t, "x": good.x, "y": good.x}
    np.savez(tmp_path / "a.npz", **{k: make[v](base[k]) for k, v in arrays.items()})
    _one_line_or_valid(lfd.demos.load_file, tmp_path / "a.npz")


def test_fuzz_found_nothing_silly_in_plain_cases(tmp_path: Path) -> None:
    """Deterministic corner cases of the loaders that the fuzzing above may not reach."""
    cases = {"e.csv": b"", "e.npz": b"", "nul.csv": b"demo,t,x1,x2\n\x00\x00\n", "e.pt": b"",
             "bin.csv": bytes(range(256)) * 4}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        load = lfd.load if name.endswith(".pt") else lfd.demos.load_file
        with pytest.raises(LfdError) as info:
            load(str(tmp_path / name))
        assert len(str(info.value).splitlines()) == 1
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("x.npy", b"\x93NUMPY garbage")
        z.writestr("t.npy", b"\x93NUMPY garbage")
    (tmp_path / "z.npz").write_bytes(buf.getvalue())
    with pytest.raises(LfdError, match="z.npz: cannot read"):
        lfd.demos.load_file(tmp_path / "z.npz")


# ---------------------------------------------------------------- the lfd command

@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("hostile")
    save_file(spiral(n_demos=2, n_samples=40, seed=1), d / "demos.npz")
    assert main(["train", "--demos", str(d / "demos.npz"), "--out", str(d / "model.pt"), *TINY]) == 0
    return d


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def _one_error_line(err: str, message: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lfd: error: ") and message in lines[0], err


@pytest.mark.parametrize("case", ["out is demos", "json is model", "plot over model", "out in a file",
                                  "out is a folder", "huge hidden", "huge dpi", "huge samples",
                                  "seed 2^64", "negative seed", "certify json is model"])
def test_bad_outputs_and_limits_exit_2_before_any_work(work: Path, case: str, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    demos, model = str(work / "demos.npz"), str(work / "model.pt")
    (work / "afile").write_text("")
    argv, message = {
        "out is demos": (["train", "--demos", demos, "--out", demos], "--out would overwrite the demo file"),
        "json is model": (["eval", model, "--demos", demos, "--json", model], "--json would overwrite the model"),
        "plot over model": (["plot", model, "--demos", demos, "--out", str(work / "model.png")], ""),
        "out in a file": (["train", "--demos", demos, "--out", str(work / "afile" / "m.pt")],
                          f"{work / 'afile' / 'm.pt'}: cannot write"),
        "out is a folder": (["train", "--demos", demos, "--out", str(work)], "is a folder"),
        "huge hidden": (["train", "--demos", demos, "--out", str(work / "h.pt"), "--hidden", "200000,200000"],
                        "parameters, more than the limit"),
        "huge dpi": (["plot", model, "--demos", demos, "--out", str(work / "p.png"), "--dpi", "100000"],
                     "--dpi between 1 and 1000"),
        "huge samples": (["certify", model, "--samples", "10000000000"], "--samples must be between 1 and"),
        "seed 2^64": (["train", "--demos", demos, "--out", str(work / "s.pt"), "--seed", str(2**64)],
                      "argument --seed: must be between 0 and 2^63 - 1"),
        "negative seed": (["train", "--demos", demos, "--out", str(work / "s.pt"), "--seed", "-1"],
                          "argument --seed: must be between 0 and 2^63 - 1"),
        "certify json is model": (["certify", model, "--json", model], "--json would overwrite the model"),
    }[case]
    if case == "plot over model":  # .png is required, so overwrite a model saved under a .png name
        (work / "model.png").write_bytes((work / "model.pt").read_bytes())
        argv[1] = str(work / "model.png")
        message = "--out would overwrite the model file"
    from lfd.learners.node import NodeLearner

    def no_training(*args):  # type: ignore[no-untyped-def]
        raise AssertionError("trained before checking its outputs")

    monkeypatch.setattr(NodeLearner, "fit", classmethod(no_training))
    before = sorted(p.name for p in work.iterdir())
    code, out, err = _run(argv, capsys)
    assert code == 2 and out == ""
    _one_error_line(err, message)
    assert sorted(p.name for p in work.iterdir()) == before  # nothing written, nothing left


def test_interrupted_training_exits_130_and_saves_nothing(work: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    from lfd.learners.node import NodeLearner

    real_fit = NodeLearner.fit.__func__

    def interrupted(cls, module, demos, config, progress):  # type: ignore[no-untyped-def]
        return {**real_fit(cls, module, demos, config, progress), "interrupted": True}

    monkeypatch.setattr(NodeLearner, "fit", classmethod(interrupted))
    code, out, err = _run(["train", "--demos", str(work / "demos.npz"), "--out", str(work / "i.pt"), *TINY],
                          capsys)
    assert code == 130 and err == "lfd: interrupted\n" and out == ""
    assert not (work / "i.pt").exists() and not list(work.glob(".i.pt.*"))


@pytest.mark.parametrize("losses", [[], [float("nan")], [float("inf"), float("nan")]])
def test_training_without_a_finite_loss_exits_2(work: Path, losses: list[float], monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    from lfd.learners.node import NodeLearner

    monkeypatch.setattr(NodeLearner, "fit", classmethod(
        lambda cls, module, demos, config, progress: {"loss": losses, "stopped_nonfinite": True}))
    code, out, err = _run(["train", "--demos", str(work / "demos.npz"), "--out", str(work / "n.pt"), *TINY],
                          capsys)
    assert code == 2 and out == ""
    _one_error_line(err, "node: training never reached a finite loss")
    assert not (work / "n.pt").exists()


def test_nan_weights_are_refused(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    field = lfd.load(str(work / "model.pt"))
    with torch.no_grad():
        next(field.module.parameters()).fill_(float("nan"))
    field.save(work / "nan.pt")
    code, out, err = _run(["eval", str(work / "nan.pt"), "--demos", str(work / "demos.npz")], capsys)
    assert code == 2 and out == ""
    _one_error_line(err, "nan.pt: the model's weights contain NaN or inf")
    # certify reads it on purpose, and reports it: NOT certified, exit 1
    code, out, err = _run(["certify", str(work / "nan.pt"), "--samples", "400"], capsys)
    assert code == 1 and "NOT CERTIFIED" in out and err == ""


def test_eval_refuses_huge_demos_and_subsamples_dtw(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from lfd.commands.eval import MAX_EVAL_SAMPLES
    from lfd.metrics import MAX_DTW_CELLS, dtw_step_for

    n = MAX_EVAL_SAMPLES + 1
    t = np.linspace(0.0, n * 1e-3, n)
    x = np.stack([np.cos(t), np.sin(t)], axis=-1)[None] * np.linspace(1, 0, n)[None, :, None]
    np.savez(work / "long.npz", t=t, x=x)
    code, out, err = _run(["eval", str(work / "model.pt"), "--demos", str(work / "long.npz")], capsys)
    assert code == 2 and out == ""
    _one_error_line(err, f"{n} samples per demo, lfd eval rolls out at most {MAX_EVAL_SAMPLES}")
    k = dtw_step_for(10**5, 10**5)
    assert k > 1 and (-(-10**5 // k)) ** 2 <= MAX_DTW_CELLS < (-(-10**5 // (k - 1))) ** 2
    assert dtw_step_for(1000, 1000, 4) == 4


def test_warnings_are_one_line(work: Path, monkeypatch: pytest.MonkeyPatch,
                               capsys: pytest.CaptureFixture[str]) -> None:
    import warnings

    import lfd.commands.eval

    def warn(args) -> int:  # type: ignore[no-untyped-def]
        warnings.warn("something odd\nsecond line", RuntimeWarning, stacklevel=2)
        return 0

    monkeypatch.setattr(lfd.commands.eval, "run", warn)
    code, out, err = _run(["eval", "m.pt", "--demos", "spiral"], capsys)
    assert code == 0 and err == "lfd: warning: something odd\n"


def test_help_is_plain_fast_to_import_and_lists_learners() -> None:
    """``lfd --help`` must not import torch (seconds of imports); its text has no RST markup."""
    code = ("import sys, contextlib, io\n"
            "from lfd.cli import main\n"
            "for argv in (['--help'], ['train', '--help'], ['certify', '--help'], ['--version']):\n"
            "    buf = io.StringIO()\n"
            "    with contextlib.redirect_stdout(buf):\n"
            "        assert main(argv) == 0\n"
            "    print(buf.getvalue())\n"
            "print('TORCH' if 'torch' in sys.modules else 'NO-TORCH')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.rstrip().endswith("NO-TORCH")
    assert "``" not in proc.stdout and "lfd 0." in proc.stdout
    assert "{node,contraction" in proc.stdout and "(contraction)" in proc.stdout


# ---------------------------------------------------------------- model cache and demo_arm.py

def test_cache_retrains_a_corrupt_file_and_never_stores_an_interrupted_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from lfd.cache import cached_field

    demos = spiral(n_demos=2, n_samples=20, seed=1)
    opts = {"iterations": 2, "hidden": (4,)}
    _, path, trained = cached_field("node", demos, 0, opts, directory=tmp_path)
    assert trained and path.is_file()
    path.write_bytes(path.read_bytes()[:-100])  # truncated: unreadable
    _, path2, trained = cached_field("node", demos, 0, opts, directory=tmp_path)
    assert path2 == path and trained
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "training again" in err
    lfd.load(str(path))  # replaced by a good file
    path.write_bytes(b"garbage")
    cached_field("node", demos, 0, opts, directory=tmp_path, verbose=False)
    assert capsys.readouterr().err == ""

    real = lfd.train

    def interrupted(*args, **kwargs):  # type: ignore[no-untyped-def]
        field = real(*args, **kwargs)
        field.history["interrupted"] = True
        return field

    monkeypatch.setattr(lfd, "train", interrupted)
    with pytest.raises(KeyboardInterrupt):
        cached_field("node", demos, 1, opts, directory=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


@pytest.fixture
def demo_arm(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):  # type: ignore[no-untyped-def]
    """The arm job's command line, ``sim.run.cli`` (what scripts/demo_arm.py runs), on a fresh cache."""
    monkeypatch.setenv("LFD_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    from sim.run import cli

    return cli


def test_demo_arm_checks_outputs_and_seed_first(demo_arm, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "afile").write_text("")
    (tmp_path / "nan.json").write_text('{"q_min": [-1, -1, -1, -3, -1, 0, -1], "q_max": [1, 1, 1, -0.1, 1, 3, NaN]}')
    save_file(spiral(n_demos=2, n_samples=20), tmp_path / "d.npz")
    run = ["--out", str(tmp_path / "run"), "--quiet"]
    cases = [
        ([*run, "--json", str(tmp_path / "afile" / "m.json")], "afile/m.json: cannot write"),
        ([*run, "--demos", str(tmp_path / "d.npz"), "--json", str(tmp_path / "d.npz")],
         "--json would overwrite the demo file"),
        ([*run, "--seed", str(2**64)], "argument --seed: must be between 0 and 2^63 - 1"),
        (["--out", str(tmp_path / "afile"), "--quiet"], "is not a folder"),
        ([*run, "--push-direction", "0,0,0"], "--push-direction must not be zero"),
        ([*run, "--push-force", "1e9"], "--push-force must be between 0 and 1000 N"),
        ([*run, "--robot", "planar", "--push-start", "100"], "the push ends at 100.2 s, after the run"),
        ([*run, "--robot", "planar", "--placement", "recorded"], "--placement recorded needs 3-D demos"),
        ([*run, "--robot", "planar", "--scale", "-1"], "--scale must be a positive number"),
        ([*run, "--learner", "node,nope"],
         "unknown learner 'nope'; known: node, contraction, tracking, stable_node, contracting_node, dmp"),
        ([*run, "--via", "0.1,0.2,0.3"], "--via '0.1,0.2,0.3': expected 2 finite task coordinates for 2-D demos"),
        ([*run, "--robot", "planar", "--limiter"], "'planar' has no finite joint acceleration and jerk limits"),
        ([*run, "--limits", str(tmp_path / "nan.json")], "q_max must be 7 numbers, none NaN"),
        ([*run, "--limits", str(tmp_path / "none.json")], "limits file not found"),
        ([*run, "--task", "nope"], "unknown task 'nope'; known: pour, place, lid"),
        ([*run, "--task", "lid", "--target", "0.4,-0.4"], "the lid's box stays where it was recorded"),
        ([*run, "--task", "lid", "--demos", "spiral"], "--task lid needs demos of poses (an object to turn)"),
        ([*run, "--task", "pour", "--shift", "0,0.02,0"], "--shift: the pour puts its objects in the robot's"),
        ([*run, "--held-out", "5"], "--held-out must name one of the 5 demos (0 to 4)"),
        ([*run, "--target", "0.4,0.1"], "--target places a task's object: give --task"),
        ([*run, "--demos", "spiral", "--task", "pour"],
         "--task pour needs demos of poses (an object to turn); spiral are positions"),
        ([*run, "--task", "place", "--target", "0.05,0"], "puts the shelf inside the arm's base"),
        ([*run, "--task", "place", "--target", "0.4,-0.4,-0.1"], "the shelf's top at -0.100 m is not between"),
        ([*run, "--task", "place", "--target", "0.4,-0.4,1.4"], "the shelf's top at 1.400 m is not between"),
        ([*run, "--demos", "robottasks:pouring", "--task", "pour", "--target", "0.05,0"],
         "puts the bowl inside the arm's base"),
        ([*run, "--demos", "robottasks:pouring", "--task", "pour", "--target", "1.5,0"],
         "the goal is out of the arm's reach"),
        ([*run, "--demos", "robottasks:pouring", "--task", "pour", "--target", "0.4,-0.4,0.3"],
         "the bowl stands on the table (Z = 0)"),
        ([*run, "--learner", "tracking", "--via", "40,40"], "--via: a via-point leaves the arm's reach"),
        ([*run, "--speed", "0"], "the speed must be a factor between 0.05 and 20, got 0.0"),
        ([*run, "--speed", "nan"], "the speed must be a factor between 0.05 and 20, got nan"),
        ([*run, "--speed", "1e6"], "the speed must be a factor between 0.05 and 20, got 1000000.0"),
    ]
    for argv, message in cases:
        assert demo_arm.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
        assert not (tmp_path / "run").exists() and not (tmp_path / "cache").exists()  # before training


def test_demo_arm_interrupted_training_exits_130_and_caches_nothing(
        demo_arm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,  # type: ignore[no-untyped-def]
        capsys: pytest.CaptureFixture[str]) -> None:
    real = lfd.train

    def interrupted(*args, **kwargs):  # type: ignore[no-untyped-def]
        kwargs["iterations"] = 2
        field = real(*args, **kwargs)
        field.history["interrupted"] = True  # as the learner reports a Ctrl-C mid-training
        return field

    monkeypatch.setattr(lfd, "train", interrupted)
    rc = demo_arm.main(["--robot", "planar", "--learner", "node", "--perturb", "none", "--out",
                        str(tmp_path / "run"), "--quiet"])
    assert rc == 130
    assert capsys.readouterr().err == "demo_arm: interrupted\n"  # --quiet: no cache line
    assert not (tmp_path / "run").exists()
    assert not list((tmp_path / "cache").glob("*.pt")) if (tmp_path / "cache").exists() else True


def test_train_warns_about_millisecond_times_and_self_crossing_demos(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t = np.linspace(0.0, 4 * np.pi, 200)
    loop = np.stack([t - 1.5 * np.sin(t), 1 - 1.5 * np.cos(t)], axis=-1)  # a prolate cycloid: 2 loops
    np.savez(tmp_path / "ms.npz", t=np.linspace(0.0, 5000.0, 200), x=(loop - loop[-1])[None])
    code, out, err = _run(["train", "--demos", str(tmp_path / "ms.npz"), "--out", str(tmp_path / "m.pt"),
                           *TINY], capsys)
    assert code == 0 and out.startswith("trained node")
    lines = err.splitlines()
    assert len(lines) == 2 and all(line.startswith("lfd: warning: ") for line in lines), err
    assert "divide them by 1000" in lines[0] and "demo 0 crosses itself" in lines[1]
    assert lfd.demos.demo_warnings(spiral()) == []  # noise near the goal is no crossing


def test_video_writer_removes_its_temporary_file_on_interrupt(tmp_path: Path) -> None:
    from sim.media.render import write_video

    def frames():  # type: ignore[no-untyped-def]
        for _ in range(3):
            yield np.zeros((32, 32, 3), np.uint8)
        raise KeyboardInterrupt  # Ctrl-C or SIGTERM (lfd.cli and demo_arm.py raise it) mid-video

    with pytest.raises(KeyboardInterrupt):
        write_video(tmp_path / "v" / "run.mp4", frames(), 32, 32)
    assert list((tmp_path / "v").iterdir()) == []


def test_an_output_set_discards_what_a_failed_job_staged_and_keeps_what_was_there(tmp_path: Path) -> None:
    """A job that fails after writing (e.g. metrics.json cannot be written) leaves no file of its
    own, inside or outside the output folder, and no folder it created; the files in place stay."""
    from sim.run.outputs import OutputSet

    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "old.mp4").write_bytes(b"user's file")
    run = tmp_path / "out" / "run"
    outputs = OutputSet(run, overwrite=False, inputs={})
    planned = [run / "node_none.mp4", run / "sub" / "node_push.npz", tmp_path / "new" / "v.mp4"]
    outputs.plan(planned)
    for path in planned:
        outputs.staged(path).write_bytes(b"data")
    assert not any(p.exists() for p in planned)            # nothing in place before the commit
    outputs.discard()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep"]
    assert (tmp_path / "keep" / "old.mp4").read_bytes() == b"user's file"


def test_an_output_folder_is_replaced_whole_or_not_at_all(tmp_path: Path) -> None:
    """--out reuse: refused unless --overwrite; with it, a run that is interrupted leaves the old
    run's files exactly as they were, and one that completes replaces them all (no stale file)."""
    from lfd.errors import ConfigError, OutputError
    from sim.run.outputs import OutputSet

    out = tmp_path / "D"
    first = OutputSet(out, overwrite=False, inputs={})
    first.plan([out / "a.npz", out / "metrics.json"])
    first.staged(out / "a.npz").write_bytes(b"first")
    first.staged(out / "metrics.json").write_text('{"runs": []}')
    first.commit(last=out / "metrics.json")
    with pytest.raises(ConfigError, match="--out is not empty"):
        OutputSet(out, overwrite=False, inputs={})
    with pytest.raises(OutputError, match="would remove the model file"):
        (out / "model.pt").write_bytes(b"m")
        OutputSet(out, overwrite=True, inputs={"model file": str(out / "model.pt")})
    (out / "model.pt").unlink()
    second = OutputSet(out, overwrite=True, inputs={})
    second.plan([out / "b.npz", out / "metrics.json"])
    second.staged(out / "b.npz").write_bytes(b"second")
    second.discard()                                            # Ctrl-C while the second run renders
    assert sorted(p.name for p in out.iterdir()) == ["a.npz", "metrics.json"]
    assert (out / "a.npz").read_bytes() == b"first"
    third = OutputSet(out, overwrite=True, inputs={})
    third.staged(out / "b.npz").write_bytes(b"third")
    third.staged(out / "metrics.json").write_text('{"runs": [1]}')
    third.commit(last=out / "metrics.json")
    assert sorted(p.name for p in out.iterdir()) == ["b.npz", "metrics.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]   # no staging or old folder left
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="holds other files"):
        OutputSet(tmp_path / "mine", overwrite=True, inputs={})


def test_demo_arm_interrupted_while_rendering_keeps_the_previous_run_whole(
        demo_arm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,  # type: ignore[no-untyped-def]
        capsys: pytest.CaptureFixture[str]) -> None:
    """The reported case: a run into D, then a second one into D with videos, interrupted while its
    video renders. D still holds exactly the first run's files, metrics.json and npz agreeing."""
    import sim.run.experiment

    demos = spiral(n_demos=2, n_samples=40, duration=1.0)
    save_file(demos, tmp_path / "d.npz")
    base = ["--robot", "planar", "--learner", "contraction", "--iters", "5", "--demos", str(tmp_path / "d.npz"),
            "--perturb", "none", "--out", str(tmp_path / "D"), "--quiet"]
    assert demo_arm.main([*base, "--no-video"]) == 0
    before = {p.name: p.read_bytes() for p in (tmp_path / "D").iterdir()}

    def interrupted(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise KeyboardInterrupt

    monkeypatch.setattr(sim.run.experiment.Experiment, "render", interrupted)
    monkeypatch.setattr("sim.media.gl.require_backend", lambda: None)
    assert demo_arm.main([*base, "--overwrite", "--seed", "1"]) == 130
    assert {p.name: p.read_bytes() for p in (tmp_path / "D").iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []
    capsys.readouterr()


@pytest.mark.parametrize(("learner", "options"), [
    ("node", {}), ("node", {"hidden": [7, 3, 5]}), ("contraction", {}),
    ("contraction", {"layers": 3, "hidden": 5, "damping": False}), ("tracking", {})])
@pytest.mark.parametrize("dim", [2, 3])
def test_the_size_check_counts_what_build_allocates(learner: str, options: dict[str, object], dim: int) -> None:
    """The up-front parameter count (arithmetic, no meta-device build) equals the built module's."""
    from lfd.learners import get_learner
    from lfd.learners.base import Learner

    cls = get_learner(learner)
    config = cls.make_config(**options)
    built = sum(p.numel() for p in cls.build(dim, config).parameters())
    assert cls.parameter_count(dim, config) == built
    assert Learner.parameter_count.__func__(cls, dim, config) == built      # the meta-device fallback agrees
