"""Demo sets (generators, LASA, files, validation) and model files (round trip, corruption)."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import lfd
from lfd.demos import DemoSet, lasa, load_demos, load_file, save_file, spiral, spiral3d
from lfd.demos.smoothing import savgol
from lfd.errors import DemoError, ModelError
from lfd.modelfile import FORMAT_VERSION, atomic_write, load_payload, payload_checksum, save_payload

# ---------------------------------------------------------------- generators and LASA

def test_spiral_shapes_goal_and_determinism() -> None:
    d = spiral(n_demos=4, n_samples=150, seed=3)
    assert d.x.shape == (4, 150, 2) and d.t.shape == (4, 150) and d.xd.shape == (4, 150, 2)
    assert np.allclose(d.x[:, -1], 0.0) and np.allclose(d.goal, 0.0)
    assert np.array_equal(d.x, spiral(n_demos=4, n_samples=150, seed=3).x)
    assert not np.allclose(d.x, spiral(n_demos=4, n_samples=150, seed=4).x)
    r0 = np.linalg.norm(d.x[:, 0], axis=1)
    assert np.all((r0 > 0.85) & (r0 < 1.15))  # radius 1, spread 10%, noise 1%


def test_spiral3d_shapes_goal_and_determinism() -> None:
    goal = (0.2, -0.1, 0.5)
    d = spiral3d(n_demos=3, n_samples=120, goal=goal, seed=1)
    assert d.x.shape == (3, 120, 3) and d.dim == 3
    assert np.allclose(d.goal, goal) and np.allclose(d.x[:, -1], goal)
    assert np.array_equal(d.x, spiral3d(n_demos=3, n_samples=120, goal=goal, seed=1).x)
    assert np.all(d.x[:, 0, 2] - goal[2] > 0.8)  # starts about one height above the goal
    with pytest.raises(DemoError, match="3 coordinates"):
        spiral3d(goal=(0.0, 0.0))


def test_every_lasa_shape_loads() -> None:
    assert len(lfd.demos.LASA_SHAPES) == 30
    for name in lfd.demos.LASA_SHAPES:
        d = lasa(name)
        assert d.x.shape == (7, 1000, 2), name
        assert d.name == f"lasa:{name}"
        assert np.isfinite(d.xd).all()
    with pytest.raises(DemoError, match="lasa:Nope: unknown LASA shape"):
        lasa("Nope")


def test_load_demos_specs() -> None:
    assert load_demos("spiral").dim == 2
    assert load_demos("spiral3d").dim == 3
    assert load_demos("lasa:Angle").n_demos == 7
    with pytest.raises(DemoError, match="unknown demo spec"):
        load_demos("spirale")


# ---------------------------------------------------------------- the package

@pytest.mark.parametrize("window,order", [(5, 2), (9, 3), (21, 3), (51, 3), (11, 1)])
def test_savgol_gives_scipys_values(window: int, order: int) -> None:
    """lfd.demos.smoothing.savgol against scipy.signal.savgol_filter (mode "interp"), 1e-12 relative,
    on random walks and on the shipped data."""
    from scipy.signal import savgol_filter

    rng = np.random.default_rng(window)
    samples = [np.cumsum(rng.normal(size=(T, 3)), axis=0) * 10.0 ** rng.uniform(-3, 3)
               for T in (window, window + 1, 200)]
    samples += [lasa("Angle").x[0], lfd.demos.robottasks("pouring").x[4]]
    for x in samples:
        want = savgol_filter(x, window, order, axis=0)
        np.testing.assert_allclose(savgol(x, window, order), want, rtol=0, atol=1e-12 * float(np.abs(want).max()))


def test_importing_the_demos_stays_cheap() -> None:
    """lfd.demos imports no scipy.signal, matplotlib, torch, pinocchio or rosbags; no module of lfd
    imports scipy.signal."""
    import ast

    code = ("import sys, lfd.demos; print(sorted(m for m in ('scipy.signal', 'matplotlib', 'torch', 'pinocchio', "
            "'rosbags') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "[]", proc.stderr
    for path in Path(lfd.__file__).parent.rglob("*.py"):
        names = [a.name for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.Import)
                 for a in node.names]
        names += [node.module or "" for node in ast.walk(ast.parse(path.read_text()))
                  if isinstance(node, ast.ImportFrom)]
        assert not any(n == "scipy.signal" or n.startswith("scipy.signal.") for n in names), path


def test_the_demos_rotations_and_poses_import_no_cycle() -> None:
    """No module of lfd.demos, lfd.pose or lfd.rotations imports itself through others (function-level
    imports included), and lfd.rotations imports nothing of lfd."""
    import grimp

    graph = grimp.build_graph("lfd")
    ours = [m for m in graph.modules if m.startswith(("lfd.demos", "lfd.pose", "lfd.rotations"))]
    assert "lfd.demos.recording" in ours and "lfd.rotations" in ours
    for module in ours:
        for imported in graph.find_modules_directly_imported_by(module):
            assert not graph.find_shortest_chain(imported, module), (module, imported)
    assert graph.find_modules_directly_imported_by("lfd.rotations") == set()
    assert not graph.find_shortest_chains("lfd.demos", "lfd.pose")


# ---------------------------------------------------------------- files

@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("make", [lambda: spiral(n_demos=3, n_samples=40), lambda: spiral3d(n_demos=2, n_samples=30)])
def test_file_round_trip(tmp_path: Path, suffix: str, make) -> None:  # type: ignore[no-untyped-def]
    d = make()
    path = tmp_path / f"demos{suffix}"
    save_file(d, path)
    back = load_file(path)
    assert np.array_equal(back.x, d.x) and np.array_equal(back.t, d.t)  # repr() keeps every bit
    assert back.name == str(path)
    assert np.array_equal(load_demos(str(path)).x, d.x)


def test_csv_demos_of_different_lengths_are_resampled(tmp_path: Path) -> None:
    rows = ["demo,t,x1,x2"]
    for i, T in enumerate((20, 35)):
        t = np.linspace(0, 1, T)
        rows += [f"{i},{tk},{1 - tk},{(1 - tk) * 2}" for tk in t]
    path = tmp_path / "two.csv"
    path.write_text("\n".join(rows) + "\n")
    d = load_file(path)
    assert d.x.shape == (2, 35, 2)
    assert np.allclose(d.x[0], d.x[1])  # both are the same straight line


def _write_npz(path: Path, **arrays: np.ndarray) -> Path:
    np.savez(path, **arrays)
    return path


def _csv(path: Path, x: np.ndarray, t: np.ndarray | None = None) -> Path:
    """x : (N, T, d) -> CSV in the demo,t,x1..xd format."""
    N, T, d = x.shape
    t = np.linspace(0, 1, T) if t is None else t
    lines = ["demo,t," + ",".join(f"x{j + 1}" for j in range(d))]
    lines += [f"{i},{t[k]}," + ",".join(str(v) for v in x[i, k]) for i in range(N) for k in range(T)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _good(N: int = 2, T: int = 20, d: int = 2) -> np.ndarray:
    """N straight lines to the origin, shape (N, T, d)."""
    s = np.linspace(1, 0, T)[:, None]
    return np.stack([s * (np.arange(d) + 1 + i) for i in range(N)])


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("case,pattern", [
    ("nan", "NaN or inf in demo 1"),
    ("inf", "NaN or inf in demo 1"),
    ("short", "at least 10 are needed"),
    ("time", "time is not increasing in demo"),
])
def test_validation_errors_name_file_and_problem(tmp_path: Path, suffix: str, case: str,
                                                 pattern: str) -> None:
    x, t = _good(), np.linspace(0, 1, 20)
    if case == "nan":
        x[1, 5, 0] = np.nan
    elif case == "inf":
        x[1, 3, 1] = np.inf
    elif case == "short":
        x, t = x[:, :9], t[:9]
    elif case == "time":
        t = t.copy()
        t[7] = t[6]
    path = tmp_path / f"bad{suffix}"
    if suffix == ".csv":
        _csv(path, x, t)
    else:
        _write_npz(path, t=t, x=x)
    with pytest.raises(DemoError) as e:
        load_file(path)
    assert str(e.value).startswith(str(path)) and pattern in str(e.value)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_demos_that_end_apart_are_accepted_with_a_note(tmp_path: Path, suffix: str) -> None:
    """Ends 0.5 apart (17 % of the extent, beyond the 5 % that once refused them): the set keeps every
    demo's end, the goal is their mean, and one note says so."""
    x, t = _good(), np.linspace(0, 1, 20)
    x[1] += [0.5, 0.0]
    path = tmp_path / f"apart{suffix}"
    if suffix == ".csv":
        _csv(path, x, t)
    else:
        _write_npz(path, t=t, x=x)
    d = load_file(path)
    np.testing.assert_array_equal(d.ends, [[0.0, 0.0], [0.5, 0.0]])
    np.testing.assert_array_equal(d.goal, [0.25, 0.0])
    assert d.notes == (f"{path}: demos end up to 0.5 apart (17% of the extent); each demo is learned relative "
                       "to its own end",)
    assert d.subset([1, 0]).notes == d.notes and d.end_q is None
    memory = DemoSet(t, x, end_tolerance=0.01)          # built in memory: accepted, nothing noted
    assert memory.notes == () and np.array_equal(memory.ends, d.ends)


def test_csv_specific_errors(tmp_path: Path) -> None:
    path = _csv(tmp_path / "mixed.csv", _good())
    lines = path.read_text().splitlines()
    lines[5] += ",0.5"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DemoError, match=r"mixed\.csv: line 6 has 5 columns, expected 4 \(mixed dimensions\)"):
        load_file(path)
    (tmp_path / "head.csv").write_text("id,time,x,y\n0,0,1,1\n")
    with pytest.raises(DemoError, match=r"head\.csv: header must be demo,t,x1\.\.xd"):
        load_file(tmp_path / "head.csv")
    (tmp_path / "word.csv").write_text("demo,t,x1,x2\n0,0,one,1\n")
    with pytest.raises(DemoError, match=r"word\.csv: line 2 has a value that is not a number"):
        load_file(tmp_path / "word.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DemoError, match=r"empty\.csv: empty file"):
        load_file(tmp_path / "empty.csv")
    with pytest.raises(DemoError, match=r"demos must have 2 to 32 dimensions, got d=1"):
        load_file(_csv(tmp_path / "one.csv", _good(d=1)))


def test_npz_shape_errors(tmp_path: Path) -> None:
    x = _good()
    cases = {
        "flat.npz": ({"t": np.linspace(0, 1, 20), "x": x[0]}, r"x must have shape \(N, T, d\), got \(20, 2\)"),
        "len.npz": ({"t": np.linspace(0, 1, 19), "x": x}, "t has 19 samples but x has 20"),
        "t2d.npz": ({"t": np.zeros((3, 20)), "x": x}, r"t must have shape \(T,\) or \(2, 20\)"),
        "nox.npz": ({"t": np.linspace(0, 1, 20)}, r"missing array\(s\) x"),
    }
    for name, (arrays, pattern) in cases.items():
        path = _write_npz(tmp_path / name, **arrays)
        with pytest.raises(DemoError, match=f"{name.replace('.', r'[.]')}: {pattern}"):
            load_file(path)
    (tmp_path / "junk.npz").write_bytes(b"not a zip file at all")
    with pytest.raises(DemoError, match=r"junk\.npz: not an NPZ file"):
        load_file(tmp_path / "junk.npz")


def test_npz_demos_of_their_own_lengths(tmp_path: Path) -> None:
    """t0, x0, t1, x1, ...: demos of different lengths, resampled to the longest; bad layouts refused."""
    x = _good(N=1, T=30)[0]
    t = np.linspace(0, 1, 30)
    d = load_file(_write_npz(tmp_path / "own.npz", t0=t, x0=x, t1=t[::2], x1=x[::2] + 0.01))
    assert d.x.shape == (2, 30, 2) and np.array_equal(d.x[0], x)
    assert d.notes == (f"{tmp_path / 'own.npz'}: demos resampled to 30 samples each, evenly in time (they had 15 "
                       "to 30, at 14.5 to 29 Hz)",)
    cases = {
        "holes.npz": ({"t0": t, "x0": x, "t2": t, "x2": x}, r"numbered from 0 without holes; missing t1, x1$"),
        "both.npz": ({"t": t, "x": x[None], "t0": t, "x0": x}, "holds both t, x and per-demo arrays t0, x0"),
        "dims.npz": ({"t0": t, "x0": x, "t1": t, "x1": np.ones((30, 3))},
                     r"t1 has shape \(30,\) and x1 \(30, 3\); expected \(T,\) and \(T, d\) with one d"),
        "noq.npz": ({"t0": t, "x0": np.ones((30, 3)), "q0": np.ones((30, 4)), "t1": t, "x1": np.ones((30, 3))},
                    "missing q1"),
    }
    for name, (arrays, pattern) in cases.items():
        with pytest.raises(DemoError, match=f"{name.replace('.', '[.]')}: .*{pattern}") as info:
            load_file(_write_npz(tmp_path / name, **arrays))
        assert len(str(info.value).splitlines()) == 1


def test_missing_file_and_unknown_suffix(tmp_path: Path) -> None:
    with pytest.raises(DemoError, match=r"nowhere\.csv: no such file"):
        load_file(tmp_path / "nowhere.csv")
    (tmp_path / "demos.txt").write_text("demo,t,x1,x2\n")
    with pytest.raises(DemoError, match=r"demos\.txt: unknown demo file type '\.txt'"):
        load_file(tmp_path / "demos.txt")
    with pytest.raises(DemoError, match="unknown demo file type"):
        save_file(spiral(), tmp_path / "demos.json")


def test_demoset_validation_in_memory() -> None:
    x = _good()
    with pytest.raises(DemoError, match=r"mine: 9 samples per demo, at least 10"):
        DemoSet(np.linspace(0, 1, 9), x[:, :9], name="mine")
    with pytest.raises(DemoError, match=r"mine: times have shape"):
        DemoSet(np.zeros((3, 20)), x, name="mine")
    one = DemoSet(np.linspace(0, 1, 20), x[0])  # a single (T, d) demo is promoted to (1, T, d)
    assert one.x.shape == (1, 20, 2)
    assert one.subset([0]).x.shape == (1, 20, 2)
    lo, hi = DemoSet(np.linspace(0, 1, 20), x).bounds(grow=0.5)
    assert np.allclose(lo, [-0.5, -0.75]) and np.allclose(hi, [2.5, 3.75])


# ---------------------------------------------------------------- model files

def _payload() -> dict:
    g = torch.Generator().manual_seed(0)
    return {"learner": "node", "dim": 2, "config": {"hidden": [8, 8], "lr": 1e-3},
            "normalization": {"goal": [0.0, 1.0], "scale": 2.5},
            "state_dict": {"w": torch.randn(8, 2, generator=g, dtype=torch.float64),
                           "b": torch.randn(8, generator=g, dtype=torch.float64)},
            "history": {"loss": [1.0, 0.5], "train_time_s": 0.1}}


def test_model_payload_round_trip_is_bit_for_bit(tmp_path: Path) -> None:
    payload = _payload()
    save_payload(payload, tmp_path / "a.pt")
    back = load_payload(tmp_path / "a.pt")
    assert back["format_version"] == FORMAT_VERSION
    for k, v in payload["state_dict"].items():
        assert torch.equal(back["state_dict"][k], v) and back["state_dict"][k].dtype == torch.float64
    assert back["config"] == payload["config"] and back["history"] == payload["history"]
    save_payload({k: v for k, v in back.items() if k != "format_version"}, tmp_path / "b.pt")
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic write left no temporary file


def test_field_save_round_trip(tmp_path: Path, spiral_field_2d) -> None:  # type: ignore[no-untyped-def]
    spiral_field_2d.save(tmp_path / "f.pt")
    back = load_payload(tmp_path / "f.pt")
    assert back["learner"] == "linear" and back["dim"] == 2
    assert torch.equal(back["state_dict"]["weight"], spiral_field_2d.module.weight)
    assert back["normalization"] == spiral_field_2d.norm.to_dict()


class _Evil:
    def __reduce__(self):  # type: ignore[no-untyped-def]
        return (print, ("this must never run",))


def test_bad_model_files(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match=r"none\.pt: no such model file"):
        load_payload(tmp_path / "none.pt")
    (tmp_path / "junk.pt").write_bytes(b"\x00garbage" * 100)
    with pytest.raises(ModelError, match=r"junk\.pt: not a readable model file"):
        load_payload(tmp_path / "junk.pt")
    save_payload(_payload(), tmp_path / "cut.pt")
    data = (tmp_path / "cut.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match=r"cut\.pt: not a readable model file"):
        load_payload(tmp_path / "cut.pt")
    torch.save({"learner": "node"}, tmp_path / "keys.pt")
    with pytest.raises(ModelError, match=r"keys\.pt: not a model file \(missing keys\)"):
        load_payload(tmp_path / "keys.pt")
    torch.save({**_payload(), "format_version": 99}, tmp_path / "v99.pt")
    with pytest.raises(ModelError, match=r"v99\.pt: model format version 99 is not supported"):
        load_payload(tmp_path / "v99.pt")
    (tmp_path / "evil.pt").write_bytes(pickle.dumps({"x": _Evil()}, protocol=2))
    with pytest.raises(ModelError, match=r"evil\.pt: not a readable model file"):
        load_payload(tmp_path / "evil.pt")
    who = {**_payload(), "format_version": FORMAT_VERSION, "learner": "nope"}
    torch.save({**who, "checksum": payload_checksum(who)}, tmp_path / "who.pt")
    with pytest.raises(ModelError, match=r"who\.pt: unknown learner 'nope'"):
        lfd.load(str(tmp_path / "who.pt"))


def _signed(payload: dict) -> dict:
    """A crafted payload with a valid checksum, as an attacker who knows the format would write."""
    payload = {"format_version": FORMAT_VERSION, **payload}
    return {**payload, "checksum": payload_checksum(payload)}


def test_flipped_weight_byte_fails_the_checksum(tmp_path: Path) -> None:
    payload = _payload()
    save_payload(payload, tmp_path / "m.pt")
    data = bytearray((tmp_path / "m.pt").read_bytes())
    at = bytes(data).find(payload["state_dict"]["w"].numpy().tobytes())
    assert at > 0
    data[at + 13] ^= 0x10  # one bit of one weight: still a readable archive
    (tmp_path / "m.pt").write_bytes(bytes(data))
    with pytest.raises(ModelError, match=r"m\.pt: checksum mismatch: the model file is corrupt"):
        load_payload(tmp_path / "m.pt")


def test_crafted_payloads_are_model_errors(tmp_path: Path) -> None:
    nan = _payload()
    nan["state_dict"]["w"][0, 0] = float("nan")
    cases = {
        "norm.pt": ({**_payload(), "normalization": {}}, "normalization must hold goal and scale"),
        "scale.pt": ({**_payload(), "normalization": {"goal": [0.0, 1.0], "scale": -1.0}},
                     "a positive scale"),
        "goal.pt": ({**_payload(), "normalization": {"goal": [0.0], "scale": 1.0}}, "2 finite goal"),
        "nan.pt": (nan, "the model's weights contain NaN or inf"),
        "dim.pt": ({**_payload(), "dim": 40}, "dim must be an integer from 2 to 32"),
        "box.pt": ({**_payload(), "demo_box": [[0.0], [1.0]]}, "demo_box"),
        "oldbox.pt": ({**_payload(), "history": {"demo_box": [[0.0], [1.0]]}}, "demo_box"),
    }
    for name, (payload, message) in cases.items():
        torch.save(_signed(payload), tmp_path / name)
        with pytest.raises(ModelError, match=f"{name.replace('.', '[.]')}: .*{message}"):
            lfd.load(str(tmp_path / name))
    torch.save({**_payload(), "state_dict": {"w": [1.0]}, "format_version": FORMAT_VERSION,
                "checksum": "0" * 64}, tmp_path / "sd.pt")
    with pytest.raises(ModelError, match=r"sd\.pt: cannot checksum .* 'w' is not a dense tensor"):
        lfd.load(str(tmp_path / "sd.pt"))
    old = {**_payload(), "format_version": 1}
    torch.save(old, tmp_path / "v1.pt")
    with pytest.raises(ModelError, match=r"v1\.pt: model format version 1 has no checksum .* train the model again"):
        load_payload(tmp_path / "v1.pt")
    torch.save(_signed({**_payload(), "config": {"hidden": "wide"}}), tmp_path / "cfg.pt")
    with pytest.raises(ModelError, match=r"cfg\.pt: model does not match its learner 'node'"):
        lfd.load(str(tmp_path / "cfg.pt"))


def _trained_payload(tmp_path: Path) -> tuple[dict, DemoSet]:
    """The payload of a freshly trained tiny NODE file, without its checksum, and its demos."""
    demos = spiral(n_demos=2, n_samples=40)
    lfd.train("node", demos, iterations=2, hidden=(4,)).save(tmp_path / "fresh.pt")
    payload = load_payload(tmp_path / "fresh.pt")
    return {k: v for k, v in payload.items() if k not in ("checksum", "format_version")}, demos


def _saved(path: Path, payload: dict) -> Path:
    torch.save(_signed(payload), path)
    return path


def test_demo_box_is_its_own_entry_of_the_model_file(tmp_path: Path) -> None:
    payload, demos = _trained_payload(tmp_path)
    lo, hi = demos.bounds()
    assert payload["demo_box"] == [lo.tolist(), hi.tolist()] and "demo_box" not in payload["history"]
    field = lfd.load(str(tmp_path / "fresh.pt"))
    assert field.demo_box is not None and "demo_box" not in field.history
    assert np.array_equal(field.demo_box[0], lo) and np.array_equal(field.demo_box[1], hi)
    no_box = {k: v for k, v in payload.items() if k != "demo_box"}
    assert lfd.load(str(_saved(tmp_path / "none.pt", no_box))).demo_box is None


def test_old_files_with_demo_box_in_history_still_load(tmp_path: Path) -> None:
    payload, demos = _trained_payload(tmp_path)
    box = payload.pop("demo_box")
    old = {**payload, "history": {**payload["history"], "demo_box": box}}
    field = lfd.load(str(_saved(tmp_path / "old.pt", old)))
    assert field.demo_box is not None and [c.tolist() for c in field.demo_box] == box
    assert field.history == payload["history"]          # the box left the training record


def test_old_node_files_with_iters_still_load(tmp_path: Path) -> None:
    payload, _ = _trained_payload(tmp_path)
    config = {("iters" if k == "iterations" else k): v for k, v in payload["config"].items()}
    field = lfd.load(str(_saved(tmp_path / "old.pt", {**payload, "config": config})))
    assert field.config == lfd.load(str(tmp_path / "fresh.pt")).config
    assert field.config["iterations"] == 2 and "iters" not in field.config
    both = {**payload, "config": {**config, "iterations": 2}}    # never written: not mapped, refused
    with pytest.raises(ModelError, match=r"both\.pt: model does not match its learner 'node' .*iters"):
        lfd.load(str(_saved(tmp_path / "both.pt", both)))


def test_never_shows_torchs_weights_only_advice(tmp_path: Path) -> None:
    (tmp_path / "m.json").write_text('{"learner": "node"}')
    (tmp_path / "evil.pt").write_bytes(pickle.dumps({"x": _Evil()}, protocol=2))
    for name in ("m.json", "evil.pt"):
        with pytest.raises(ModelError) as info:
            lfd.load(str(tmp_path / name))
        assert "weights_only" not in str(info.value) and len(str(info.value).splitlines()) == 1


def test_atomic_write_names_the_users_path_and_cleans_up(tmp_path: Path) -> None:
    def fail(f) -> None:  # type: ignore[no-untyped-def]
        f.write(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "m.pt", fail)
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("")
    with pytest.raises(OSError) as info:  # the parent is a file: mkdir/mkstemp fail
        atomic_write(tmp_path / "file" / "m.pt", lambda f: f.write(b"x"))
    assert info.value.filename == str(tmp_path / "file" / "m.pt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


# ---------------------------------------------------------------- hostile demo files

def test_hostile_demo_files(tmp_path: Path) -> None:
    d = spiral(n_demos=2, n_samples=60, seed=1)
    save_file(d, tmp_path / "d.npz")
    save_file(d, tmp_path / "d.csv")
    data = (tmp_path / "d.npz").read_bytes()
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    (tmp_path / "zip.npz").write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    np.savez(tmp_path / "complex.npz", t=d.t, x=d.x.astype(complex))
    np.savez(tmp_path / "text.npz", t=d.t, x=np.full(d.x.shape, "a"))
    np.savez(tmp_path / "tiny.npz", t=d.t * 1e-300, x=d.x)
    np.savez(tmp_path / "huge.npz", t=d.t, x=d.x * 1e306)
    np.savez(tmp_path / "long.npz", t=d.t * 1e300, x=d.x)
    cases = {
        "empty.npz": "not an NPZ file", "cut.npz": "not an NPZ file", "zip.npz": "not an NPZ file",
        "complex.npz": "x holds complex numbers", "text.npz": "x must hold numbers",
        "tiny.npz": "time step of .* below 1e-09 s; times must be in seconds",
        "huge.npz": "the velocities of demo 0 overflow",
        "long.npz": "a demo lasts .* s, more than 1e[+]06 s; times must be in seconds",
    }
    for name, message in cases.items():
        with pytest.raises(DemoError, match=f"{name.replace('.', '[.]')}: {message}") as info:
            load_file(tmp_path / name)
        assert len(str(info.value).splitlines()) == 1
    bom = tmp_path / "bom.csv"  # a spreadsheet's "CSV UTF-8": a byte-order mark before the header
    bom.write_bytes(b"\xef\xbb\xbf" + (tmp_path / "d.csv").read_bytes())
    np.testing.assert_allclose(load_file(bom).x, d.x, rtol=1e-15, atol=0)
