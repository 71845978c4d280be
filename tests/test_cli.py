"""The ``lfd`` command: train, eval and plot in-process, error paths, one run as a subprocess."""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from matplotlib.image import imread

import lfd
import lfd.commands.eval
from lfd.cli import build_parser, main
from lfd.commands.train import learner_options
from lfd.demos import save_file, spiral, spiral3d
from lfd.plotting import field_figure

TINY = ["--iterations", "4", "--hidden", "8,8", "--quiet"]


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with small demo files and a tiny NODE model trained through the CLI."""
    d = tmp_path_factory.mktemp("cli")
    save_file(spiral(n_demos=2, n_samples=60, seed=1), d / "demos.npz")
    save_file(spiral3d(n_demos=2, n_samples=40), d / "demos3d.csv")
    assert main(["train", "--learner", "node", "--demos", str(d / "demos.npz"),
                 "--out", str(d / "model.pt"), "--seed", "3", *TINY]) == 0
    return d


def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_train_passes_only_given_options(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["train", "--demos", str(work / "demos.npz"), "--out",
                               str(work / "again.pt"), "--seed", "3", *TINY], capsys)
    assert code == 0 and err == ""
    assert out.startswith("trained node on ") and "final loss" in out and "again.pt" in out
    field, first = lfd.load(str(work / "again.pt")), lfd.load(str(work / "model.pt"))
    assert tuple(field.config["hidden"]) == (8, 8) and field.config["iterations"] == 4
    defaults = dataclasses.asdict(lfd.get_learner("node").Config())
    assert field.config["lr"] == defaults["lr"] and field.config["solver"] == defaults["solver"]
    assert len(field.history["loss"]) == 4
    for k, v in first.module.state_dict().items():  # same seed, same model
        assert torch.equal(v, field.module.state_dict()[k])


def test_eval_writes_finite_metrics(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["eval", str(work / "model.pt"), "--demos", str(work / "demos.npz"),
                               "--json", str(work / "m.json")], capsys)
    assert code == 0 and err == ""
    report = json.loads((work / "m.json").read_text())
    names = ["rmse", "dtw", "chamfer_dtwd", "frechet", "swept_area", "velocity_rmse",
             "cosine_error", "final_goal_distance"]
    assert report["metrics"] == names and report["learner"] == "node" and report["n_demos"] == 2
    assert len(report["per_demo"]) == 2
    for name in names:
        values = [row[name] for row in report["per_demo"]]
        assert all(isinstance(v, float) and math.isfinite(v) and v >= 0 for v in values), name
        assert report["mean"][name] == pytest.approx(np.mean(values), rel=1e-12)
    assert 0 <= report["mean"]["cosine_error"] <= 2
    lines = out.splitlines()
    assert lines[0].split() == ["demo", *names] and lines[3].startswith("mean")
    assert not list(work.glob(".m.json.*"))  # written atomically, no temporary left


def test_plot_2d_png(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = work / "fig.png"
    code, out, _ = run_main(["plot", str(work / "model.pt"), "--demos", str(work / "demos.npz"),
                             "--out", str(png), "--perturbed", "3", "--dpi", "60"], capsys)
    assert code == 0 and out.strip() == f"wrote {png}"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    img = imread(png)
    assert img.shape[0] >= 300 and img.shape[1] >= 700
    assert img[..., :3].std() > 0.1  # streamlines, curves and text, not a blank canvas


def test_plot_3d_figure(spiral_field_2d, make_linear_field) -> None:  # type: ignore[no-untyped-def]
    demos = spiral3d(n_demos=2, n_samples=40)
    field = make_linear_field(np.array([[-1.0, 2.0, 0.0], [-2.0, -1.0, 0.0], [0.0, 0.0, -1.0]]), demos.goal)
    fig = field_figure(field, demos, n_perturbed=2)
    ax3d, loss_ax = fig.axes[0], fig.axes[1]
    assert ax3d.name == "3d" and loss_ax.get_yscale() == "log"
    assert len(ax3d.lines) == 2 + 2 + 2  # demos, rollouts from their starts, perturbed rollouts
    with pytest.raises(ValueError, match="3-D"):
        field_figure(spiral_field_2d, demos)


def _nan_csv(path: Path) -> Path:
    t = np.linspace(0, 1, 12)
    rows = ["demo,t,x1,x2"] + [f"0,{tk},{1 - tk},{'nan' if k == 4 else 0.0}" for k, tk in enumerate(t)]
    path.write_text("\n".join(rows) + "\n")
    return path


def error_cases(w: Path) -> dict[str, tuple[list[str], str]]:
    model, demos = str(w / "model.pt"), str(w / "demos.npz")
    (w / "corrupt.pt").write_bytes(b"PK\x03\x04 not really a zip")
    return {
        "missing model": (["eval", str(w / "nope.pt"), "--demos", demos], "nope.pt: no such model file"),
        "corrupt model": (["plot", str(w / "corrupt.pt"), "--demos", demos, "--out", str(w / "x.png")],
                          "corrupt.pt: not a readable model file"),
        "missing demos": (["eval", model, "--demos", str(w / "none.csv")], "none.csv: no such file"),
        "nan demos": (["train", "--demos", str(_nan_csv(w / "nan.csv")), "--out", str(w / "o.pt")],
                      "nan.csv: NaN or inf in demo 0"),
        "unknown spec": (["eval", model, "--demos", "spirals"], "spirals: unknown demo spec"),
        "unknown learner": (["train", "--learner", "dmp2", "--demos", demos, "--out", str(w / "o.pt")],
                            "unknown learner 'dmp2'"),
        "bad hidden": (["train", "--demos", demos, "--out", str(w / "o.pt"), "--hidden", "64,x"],
                       "argument --hidden: expected comma-separated positive integers"),
        "option of another learner": (["train", "--demos", demos, "--out", str(w / "o.pt"),
                                       "--rate", "0.5"], "node: unknown option(s) rate"),
        "bad option value": (["train", "--demos", demos, "--out", str(w / "o.pt"),
                              "--activation", "sigmoidal"], "node: unknown activation 'sigmoidal'"),
        "bad KEY=VALUE": (["train", "--demos", demos, "--out", str(w / "o.pt"), "--option", "seg"],
                          "expected KEY=VALUE, got 'seg'"),
        "dimension mismatch": (["eval", model, "--demos", str(w / "demos3d.csv")],
                               "demos are 3-D but the model"),
        "image type": (["plot", model, "--demos", demos, "--out", str(w / "f.gif")],
                       "unknown image type '.gif'"),
        "unknown command": (["fly"], "invalid choice: 'fly'"),
        "no command": ([], "the following arguments are required: COMMAND"),
        "missing --demos": (["eval", model], "the following arguments are required: --demos"),
    }



@pytest.mark.parametrize("case", [
    "missing model", "corrupt model", "missing demos", "nan demos", "unknown spec",
    "unknown learner", "bad hidden", "option of another learner", "bad option value",
    "bad KEY=VALUE", "dimension mismatch", "image type", "unknown command", "no command",
    "missing --demos",
])
def test_error_exits_2_with_one_line(work: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    argv, message = error_cases(work)[case]
    code, out, err = run_main(argv, capsys)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lfd: error: ") and message in lines[0], err
    assert "Traceback" not in err


def test_help_and_interrupt_and_bugs(monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_main(["--help"], capsys)
    assert code == 0 and all(c in out for c in ("train", "eval", "plot"))

    def interrupted(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(lfd.commands.eval, "run", interrupted)
    code, _, err = run_main(["eval", "m.pt", "--demos", "spiral"], capsys)
    assert code == 130 and err == "lfd: interrupted\n"

    def buggy(args: argparse.Namespace) -> int:
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(lfd.commands.eval, "run", buggy)
    with pytest.raises(ZeroDivisionError):  # a bug is not dressed up as a user error
        main(["eval", "m.pt", "--demos", "spiral"])


def test_option_names_and_types_follow_the_learner(monkeypatch: pytest.MonkeyPatch) -> None:
    @dataclasses.dataclass
    class Config:
        iterations: int = 10
        hidden: int = 32
        widths: tuple[int, ...] = (4, 4)
        damping: bool = True
        lr: float = 0.1
        name: str = "a"

    class Fake:
        pass

    Fake.Config = Config  # type: ignore[attr-defined]
    monkeypatch.setattr("lfd.learners.get_learner", lambda name: Fake)

    def parse(*argv: str) -> dict:
        ns = build_parser().parse_args(["train", "--demos", "d", "--out", "o", *argv])
        return learner_options("fake", ns)

    assert parse() == {}
    assert parse("--iterations", "7", "--hidden", "16", "--lr", "0.5") == {"iterations": 7, "hidden": 16, "lr": 0.5}
    assert parse("--option", "widths=8,2", "--option", "damping=false", "--option", "name=b") == {
        "widths": (8, 2), "damping": False, "name": "b"}
    assert parse("--option", "other=1") == {"other": "1"}  # the learner's make_config rejects it
    with pytest.raises(lfd.ConfigError, match="fake: bad value \\(16, 16\\) for --hidden"):
        parse("--hidden", "16,16")
    with pytest.raises(lfd.ConfigError, match="bad value 'maybe' for damping"):
        parse("--option", "damping=maybe")


def test_subprocess_exit_code(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "lfd.cli", "plot", str(tmp_path / "absent.pt"),
                           "--demos", "spiral", "--out", str(tmp_path / "f.png")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [f"lfd: error: {tmp_path / 'absent.pt'}: no such model file"]


def test_broken_pipe_ends_quietly(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``lfd eval ... | head -1``: the reader leaves, the command ends with no message, exit 141."""

    class ClosedPipe(io.TextIOBase):
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

    def prints(args: argparse.Namespace) -> int:
        print("a table")
        return 0

    monkeypatch.setattr(lfd.commands.eval, "run", prints)
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["eval", "m.pt", "--demos", "spiral"]) == 141
    assert capsys.readouterr().err == ""


def test_ctrl_c_during_startup_imports_is_no_traceback(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    import builtins

    real_import = builtins.__import__

    def ctrl_c_in_import(name: str, *args, **kwargs):  # type: ignore[no-untyped-def]
        if name == "torch":  # Ctrl-C lands while torch is being imported
            os.kill(os.getpid(), signal.SIGINT)
        return real_import(name, *args, **kwargs)  # ... and the import itself goes on unharmed

    monkeypatch.setattr(builtins, "__import__", ctrl_c_in_import)
    code = main(["eval", "m.pt", "--demos", "spiral"])
    monkeypatch.undo()
    assert code == 130 and capsys.readouterr().err == "lfd: interrupted\n"

    def raises_in_import(name: str, *args, **kwargs):  # type: ignore[no-untyped-def]
        if name == "torch":  # an import that was interrupted before main could defer it
            raise KeyboardInterrupt
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", raises_in_import)
    code = main(["eval", "m.pt", "--demos", "spiral"])
    monkeypatch.undo()
    assert code == 130 and capsys.readouterr().err == "lfd: interrupted\n"


# ---------------------------------------------------------------- lfd.io, the tree-wide writers

def test_write_json_is_strict_and_atomic(tmp_path: Path) -> None:
    from lfd.io import json_text, write_json

    obj = {"a": math.inf, "b": [1.0, -math.inf, math.nan], "c": np.float64(np.nan), "d": np.arange(3),
           "e": (np.int64(2), "x"), "f": {"g": np.array([0.5, np.inf])}}
    write_json(tmp_path / "out" / "r.json", obj, indent=1)
    assert json.loads((tmp_path / "out" / "r.json").read_text()) == {
        "a": None, "b": [1.0, None, None], "c": None, "d": [0, 1, 2], "e": [2, "x"], "f": {"g": [0.5, None]}}
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["r.json"]   # no temporary left
    with pytest.raises(TypeError):   # not JSON-able: refused, never written as something else
        json_text({"x": object()})


def test_atomic_path_replaces_only_on_success(tmp_path: Path) -> None:
    from lfd.io import atomic_path

    target = tmp_path / "v.mp4"
    target.write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target, suffix=".mp4") as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".mp4"
            tmp.write_bytes(b"partial")
            raise KeyboardInterrupt
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    with atomic_path(target, suffix=".mp4") as tmp:
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]
    assert (target.stat().st_mode & 0o777) == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_kept_section_is_the_hand_written_tail_of_a_report(tmp_path: Path) -> None:
    from lfd.io import kept_section

    report = tmp_path / "r.md"
    assert kept_section(report, "## Notes") == []                       # no report yet
    report.write_text("# Title\n\n| a |\n\n## Notes\n\nwritten by hand\n")
    assert kept_section(report, "## Notes") == ["## Notes", "", "written by hand"]
    assert kept_section(report, "## Other") == []
