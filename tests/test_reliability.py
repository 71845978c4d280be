"""Faults injected on purpose: corrupt cache files (bench cells, converted meshes, models), a full
disk, a motionless demo and broken GL back-ends. Each test checks the exit code, the one-line
message and what is left on disk. (Dead workers and killed programs: tests/test_workers.py.)
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from records import numbers

import lfd
from lfd.bench.lasa import LasaSuite
from lfd.bench.protocol import LasaProtocol
from lfd.bench.report import write_report
from lfd.bench.runner import load_arrays, run_cells
from lfd.cli import main

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
# the LASA suite on a cheap protocol: few starts and a tiny grid (the cache logic does not depend on its size)
SMALL = LasaSuite(LasaProtocol(ring_points=1, box_points=2, spurious_grid=2, grid=4, keep_points=10, timing_calls=5))


def _no_temporaries(folder: Path) -> None:
    left = [p.name for p in folder.rglob("*") if ".tmp" in p.name]
    assert not left, left


# ---------------------------------------------------------------- corruptions of a file
def _truncate(p: Path) -> None:
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _flip(p: Path) -> None:
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x5A
    p.write_bytes(bytes(data))


def _empty(p: Path) -> None:
    p.write_bytes(b"")


def _garbage(p: Path) -> None:
    p.write_bytes(b"not a cache file\n" * 8)


def _edit_number(p: Path) -> None:
    """A valid JSON record with one number changed (a number nobody could tell is wrong)."""
    entry = json.loads(p.read_text())
    entry["metrics"]["rmse"] *= 0.5
    p.write_text(json.dumps(entry, indent=2))


CORRUPTIONS: dict[str, Callable[[Path], None]] = {
    "truncated": _truncate, "flipped": _flip, "empty": _empty, "garbage": _garbage}


# ---------------------------------------------------------------- bench cache
@pytest.fixture(scope="module")
def bench_clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One DMP cell on the small protocol, computed into a fresh cache."""
    cache = tmp_path_factory.mktemp("bench_cache")
    cells = [SMALL.cell("dmp", "Angle", 0, None, {})]
    result = run_cells(cells, cache, progress=False)
    assert result.computed == ["dmp__Angle__seed0"] and not result.failed
    return {"cache": cache, "cells": cells, "records": result.records}


@pytest.mark.parametrize("kind, target", [("truncated", "npz"), ("flipped", "npz"), ("empty", "npz"),
                                          ("edited", "json"), ("truncated", "json"), ("missing", "npz")])
def test_bad_bench_cache_entry_is_recomputed_with_one_warning(bench_clean: dict[str, Any], kind: str, target: str,
                                                              tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    shutil.copytree(bench_clean["cache"], cache)
    victim = cache / f"dmp__Angle__seed0.{target}"
    if kind == "missing":
        victim.unlink()
    else:
        (_edit_number if kind == "edited" else CORRUPTIONS[kind])(victim)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_cells(bench_clean["cells"], cache, progress=False)
    said = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(said) == 1, said
    assert said[0].startswith(f"bench cache: {cache / 'dmp__Angle__seed0'}.json: ")
    assert said[0].endswith("; computing the cell again") and "\n" not in said[0]
    assert result.computed == ["dmp__Angle__seed0"] and result.cached == []
    clean, again = bench_clean["records"][0], result.records[0]
    assert numbers(again) == numbers(clean)                 # the same numbers as the clean run
    assert "checksum" not in again and "npz_sha256" not in again
    _no_temporaries(cache)
    with warnings.catch_warnings(record=True) as caught:      # the entry is whole again: used, silently
        warnings.simplefilter("always")
        third = run_cells(bench_clean["cells"], cache, progress=False)
    assert third.cached == ["dmp__Angle__seed0"] and not caught
    arrays = load_arrays(cache, SMALL.record_stem(third.records[0]))
    assert arrays["rollouts"].size > 0


def test_entry_of_other_inputs_is_recomputed_silently(bench_clean: dict[str, Any], tmp_path: Path) -> None:
    """A changed option gives another key: computed without a warning (nothing is wrong)."""
    cache = tmp_path / "cache"
    shutil.copytree(bench_clean["cache"], cache)
    other = [SMALL.cell("dmp", "Angle", 0, None, {"n_weights_per_dim": 20})]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_cells(other, cache, progress=False)
    assert result.computed == ["dmp__Angle__seed0"] and not caught


def test_two_reports_in_one_folder_keep_their_own_figures(bench_clean: dict[str, Any], tmp_path: Path) -> None:
    records, cache = bench_clean["records"], bench_clean["cache"]
    run = {"command": "test", "seeds": [0], "workers": 1, "cpus": 1, "wall_s": 1.0, "computed": 1, "cached": 0,
           "load_start": "0", "load_end": "0"}
    paths = {}
    for name in ("quick", "full"):
        figs = write_report(tmp_path / f"{name}.md", SMALL, records, ["dmp"], ["Angle"], run,
                            lambda r: load_arrays(cache, SMALL.record_stem(r)))
        assert figs == [tmp_path / "figures" / f"{name}_dmp.png"]
        paths[name] = figs[0]
    for name, fig in paths.items():
        assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"![LASA dmp](figures/{name}_dmp.png)" in (tmp_path / f"{name}.md").read_text()
    assert sorted(p.name for p in (tmp_path / "figures").iterdir()) == ["full_dmp.png", "quick_dmp.png"]


@pytest.mark.slow
def test_bench_command_recomputes_a_truncated_cell_with_one_warning_line(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """``lfd bench lasa --quick --cache C`` with a truncated cell NPZ: exit 0, one warning line,
    the JSON written, the same numbers as the clean run."""
    cache = tmp_path / "C"
    argv = ["bench", "lasa", "--learner", "dmp", "--quick", "--shapes", "Angle", "--split", "in-sample", "--workers",
            "1", "--ring-points", "2", "--box-points", "16", "--cache", str(cache), "--json", str(tmp_path / "r.json"),
            "--report", str(tmp_path / "r.md")]
    assert main(argv) == 0
    clean = json.loads((tmp_path / "r.json").read_text())["results"]
    capsys.readouterr()
    _truncate(cache / "dmp__Angle__seed0.npz")
    assert main(argv) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lfd: warning: bench cache: ") and "computing the cell again" in err[0]
    again = json.loads((tmp_path / "r.json").read_text())
    assert again["run"]["computed"] == 1
    assert numbers(again["results"]) == numbers(clean)


# ---------------------------------------------------------------- mesh cache
@pytest.fixture
def mesh_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A small PLY mesh (a box and a sphere) and an empty mesh cache of its own."""
    trimesh = pytest.importorskip("trimesh")
    monkeypatch.setenv("LFD_ROBOTS_CACHE", str(tmp_path / "mesh_cache"))
    mesh = trimesh.util.concatenate([trimesh.creation.box((0.1, 0.1, 0.1)),
                                     trimesh.creation.icosphere(subdivisions=2, radius=0.05)])
    path = tmp_path / "part.ply"
    path.write_bytes(mesh.export(file_type="ply"))
    return path


@pytest.mark.parametrize("kind", sorted(CORRUPTIONS))
def test_bad_mesh_cache_file_is_rebuilt_with_one_warning(mesh_file: Path, kind: str) -> None:
    from robots import visual

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        clean = visual.convert_mesh(mesh_file)
    assert not caught
    (cached,) = visual.cache_dir().iterdir()
    good = cached.read_bytes()
    assert good.startswith(b"PK\x03\x04")                        # an NPZ (a zip archive)
    CORRUPTIONS[kind](cached)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = visual.convert_mesh(mesh_file)
    said = [str(w.message) for w in caught]
    assert len(said) == 1 and said[0].startswith(f"robots: mesh cache file {cached} is "), said
    assert said[0].endswith(f"; converting {mesh_file.name} again")
    assert again == clean
    assert cached.read_bytes() == good                       # rebuilt, whole
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert visual.convert_mesh(mesh_file) == clean
    assert not caught
    _no_temporaries(visual.cache_dir())


def test_mesh_cache_is_fsynced_before_its_rename(mesh_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from robots import visual

    calls: list[str] = []
    fsync, replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (calls.append("fsync"), fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (calls.append("replace"), replace(a, b))[1])
    visual.convert_mesh(mesh_file)
    assert calls[:2] == ["fsync", "replace"]


# ---------------------------------------------------------------- model cache, full disk
@pytest.mark.parametrize("kind", sorted(CORRUPTIONS))
def test_bad_model_cache_file_is_trained_again_with_one_line(kind: str, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    from lfd.cache import cached_field

    demos = lfd.spiral()
    field, path, trained = cached_field("tracking", demos, directory=tmp_path)
    assert trained
    x0 = demos.x[:, 0]
    clean = field.rollout(x0, demos.t[0])
    CORRUPTIONS[kind](path)
    capsys.readouterr()
    again, path2, trained = cached_field("tracking", demos, directory=tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert trained and path2 == path
    assert len(err) == 1 and err[0].startswith(f"cache: {path}: ") and err[0].endswith("; training again"), err
    np.testing.assert_array_equal(again.rollout(x0, demos.t[0]), clean)
    reread, _, trained = cached_field("tracking", demos, directory=tmp_path)
    assert not trained and not capsys.readouterr().err
    _no_temporaries(tmp_path)


class _FullDisk:
    """A binary file that takes ``room`` bytes, then fails like a full disk (ENOSPC)."""

    def __init__(self, path: str | os.PathLike, mode: str, room: int = 512) -> None:
        self._f = open(path, mode)  # noqa: SIM115
        self._room = room

    def write(self, data: Any) -> int:
        data = bytes(data)
        if len(data) > self._room:
            self._f.write(data[: self._room])
            self._room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= len(data)
        return self._f.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)

    def __enter__(self) -> _FullDisk:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._f.close()


@pytest.mark.parametrize("learner, options", [("node", ["--iterations", "5", "--hidden", "8"]),
                                              ("tracking", [])])
def test_training_onto_a_full_disk_is_one_line_exit_2_and_leaves_no_file(
        learner: str, options: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    import lfd.io

    out = tmp_path / "out" / "model.pt"
    monkeypatch.setattr(lfd.io, "open", _FullDisk, raising=False)
    code = main(["train", "--learner", learner, "--demos", "spiral", "--out", str(out), *options])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"lfd: error: {out}: {os.strerror(errno.ENOSPC)}"], err
    assert not out.exists() and list(out.parent.iterdir()) == []


@pytest.fixture
def tiny_tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs, nearly full (needs the right to mount: root in a container)."""
    where = tmp_path / "tmpfs"
    where.mkdir()
    if shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        (where / "fill").write_bytes(b"\0" * 60 * 1024)
        yield where
    finally:
        subprocess.run(["umount", str(where)], capture_output=True)


def test_node_training_onto_a_real_full_disk(tiny_tmpfs: Path) -> None:
    out = tiny_tmpfs / "m.pt"
    r = subprocess.run([PYTHON, "-m", "lfd.cli", "train", "--learner", "node", "--demos", "spiral",
                        "--iterations", "5", "--out", str(out)], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"lfd: error: {out}: {os.strerror(errno.ENOSPC)}"], r.stderr
    assert sorted(p.name for p in tiny_tmpfs.iterdir()) == ["fill"]


# ---------------------------------------------------------------- a motionless demo
@pytest.mark.parametrize("learner", ["node", "contraction", "tracking"])
def test_motionless_demo_is_refused_by_every_learner(learner: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    demo = tmp_path / "still.csv"
    demo.write_text("demo,t,x1,x2\n" + "".join(f"0,{k * 0.01:.2f},0.5,0.25\n" for k in range(50)))
    out = tmp_path / "m.pt"
    code = main(["train", "--learner", learner, "--demos", str(demo), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"lfd: error: {demo}: demo 0 does not move (all its 50 samples are at one "
                                 "point); a demonstration must move to its goal"], err
    assert not out.exists()


def test_motion_check_takes_a_moving_demo() -> None:
    from lfd.demos import check_motion

    check_motion(lfd.spiral().x)
    check_motion(np.array([[[1e3, 0.0], [1e3 + 1e-3, 0.0]]]))   # a millimetre-scale move, in mm


# ---------------------------------------------------------------- GL back-ends
_GL_SCRIPT = """
import sim
from sim.errors import RenderError
from sim.media.gl import require_backend
print("imported")
try:
    require_backend()
except RenderError as e:
    print("render error:", e)
    raise SystemExit(2)
print("renders")
"""


def _gl_run(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([PYTHON, "-c", _GL_SCRIPT], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, **env}, timeout=300)


@pytest.mark.parametrize("value, message", [
    ("invalid", "MUJOCO_GL=invalid is not an OpenGL back-end for offscreen rendering; set MUJOCO_GL=egl "
                "(or osmesa), or unset it"),
    ("disable", "MUJOCO_GL=disable turns rendering off; unset it or set MUJOCO_GL=egl to render videos "
                "(or run without videos)"),
])
def test_a_bad_gl_value_is_no_error_at_import_and_one_line_before_rendering(value: str, message: str) -> None:
    r = _gl_run({"MUJOCO_GL": value})
    assert r.returncode == 2, r.stderr
    assert r.stdout.splitlines() == ["imported", f"render error: {message}"]
    assert "Traceback" not in r.stderr


def test_osmesa_not_installed_is_no_error_at_import() -> None:
    from sim.media.gl import library_found

    if library_found("osmesa"):
        pytest.skip("libOSMesa is installed here")
    r = _gl_run({"MUJOCO_GL": "osmesa"})
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout.splitlines() == ["imported", "render error: MUJOCO_GL=osmesa: libOSMesa is not installed; "
                                     "install libosmesa6 (apt install libosmesa6), or unset MUJOCO_GL to "
                                     "render with EGL"]


def test_broken_egl_is_no_error_at_import() -> None:
    """glvnd's libEGL with no vendor library: as a broken driver (no EGL display can be made)."""
    from sim.media.gl import library_found

    if not library_found("egl"):
        pytest.skip("libEGL is not installed here")
    r = _gl_run({"MUJOCO_GL": "egl", "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent.json"})
    if r.returncode == 0:
        pytest.skip("this libEGL does not use glvnd vendor files")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "imported" and len(lines) == 2
    assert lines[1].startswith("render error: MUJOCO_GL=egl: cannot open an OpenGL context (")
    assert lines[1].endswith("; install libegl1 (apt install libegl1 libgl1-mesa-dri) with a working driver, "
                             "or libosmesa6 and set MUJOCO_GL=osmesa")


def test_dm_control_physics_still_renders_on_first_use() -> None:
    """dm_control is imported with rendering off; ``Physics.render`` picks the back-end when called."""
    import sim
    from sim.errors import RenderError
    from sim.media.gl import require_backend

    try:
        require_backend()
    except RenderError as e:
        pytest.skip(str(e))
    env = sim.make_environment("planar", demos="spiral", learner_field=None, seed=0)
    image = env.physics.render(48, 64)
    assert image.shape == (48, 64, 3) and image.std() > 1


def test_sweep_help_needs_no_gl() -> None:
    r = subprocess.run([PYTHON, str(ROOT / "scripts" / "sweep_arm.py"), "--help"], capture_output=True, text=True,
                       env={**os.environ, "MUJOCO_GL": "invalid"}, timeout=300)
    assert r.returncode == 0 and r.stdout.startswith("usage:") and not r.stderr
