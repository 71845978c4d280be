"""``lfd export``: TorchScript, ONNX and an NPZ grid reproduce ``field(x)``, for the NODE
and the contraction learner (whatever ``lfd.train`` returns), with clean errors otherwise."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator

import lfd
from lfd.cli import main
from lfd.commands.export import GridField

pytestmark = [pytest.mark.usefixtures("one_thread"),
              pytest.mark.filterwarnings(r"ignore:`torch\.jit\.load` is deprecated:DeprecationWarning")]

TOL = 1e-6     # the export reproduces field(x) to 1e-6 (user units/s)
LEARNERS = {"node": {"iterations": 10, "hidden": (16, 16)}, "contraction": {"iterations": 5},
            "stable_node": {"iterations": 10, "hidden": (16, 16), "lyapunov_iterations": 5},
            "contracting_node": {"iterations": 10}}


@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, lfd.VelocityField]]:
    demos = lfd.spiral(n_demos=2, n_samples=60, duration=1.0)
    out = {}
    root = tmp_path_factory.mktemp("models")
    for name, options in LEARNERS.items():
        field = lfd.train(name, demos, seed=0, **options)
        path = root / f"{name}.pt"
        field.save(path)
        out[name] = (path, lfd.load(str(path)))
    field3 = lfd.train("contraction", lfd.spiral3d(n_demos=2, n_samples=40), seed=0, iterations=5)
    field3.save(root / "c3.pt")
    out["contraction3d"] = (root / "c3.pt", lfd.load(str(root / "c3.pt")))
    return out


def points(field: lfd.VelocityField, n: int = 500, grow: float = 1.5) -> np.ndarray:
    """n seeded points over the demos' box grown by ``grow`` times its size (outside the demos too)."""
    assert field.demo_box is not None
    lo, hi = field.demo_box
    pad = (hi - lo) * grow / 2
    return np.random.default_rng(3).uniform(lo - pad, hi + pad, size=(n, field.dim))


def export(model: Path, fmt: str, out: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str]:
    code = main(["export", str(model), "--format", fmt, "--out", str(out), *extra])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("learner", ["node", "contraction", "contraction3d", "stable_node", "contracting_node"])
def test_torchscript_reproduces_the_field(learner: str, models, tmp_path: Path, capsys) -> None:
    path, field = models[learner]
    code, err = export(path, "torchscript", tmp_path / "f.ts", capsys)
    assert code == 0 and err == ""
    ts = torch.jit.load(str(tmp_path / "f.ts"))
    for n in (1, 7, 500):                      # batch sizes other than the traced one (8)
        x = points(field, n)
        with torch.no_grad():
            got = ts(torch.from_numpy(x)).numpy()
        assert got.shape == (n, field.dim)
        assert np.abs(got - field(x)).max() <= TOL   # round-off in practice


@pytest.mark.slow
@pytest.mark.parametrize("learner", ["node", "stable_node"])
def test_onnx_reproduces_the_node_fields_and_refuses_what_onnx_cannot_express(
        learner: str, models, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both NODEs export (the stable NODE on its frozen flow parameters: no eigen-decomposition, so
    ONNX expresses the flow, V, grad V and the correction of Eq. (L2))."""
    pytest.importorskip("onnxscript")
    from onnx.reference import ReferenceEvaluator

    path, field = models[learner]
    code, err = export(path, "onnx", tmp_path / "f.onnx", capsys)
    assert code == 0 and err == ""
    x = points(field)
    got = ReferenceEvaluator(str(tmp_path / "f.onnx")).run(None, {"x": x})[0]
    ref = field(x)
    # a float64 graph run by onnx's pure-Python reference evaluator: less exact than round-off (its
    # kernels sum in another order), bounded like every export by 1e-6 x max(1, max |f|)
    assert np.abs(got - ref).max() <= TOL * max(1.0, np.abs(ref).max())
    # What the exporter cannot convert ends in one line. The real contraction field fails with
    # "no ONNX operator for aten._linalg_eigh", after a slow conversion attempt; here the exporter's
    # error is replayed instead of paying for that conversion.
    def unconvertible(*args, **kwargs):
        raise torch.onnx.OnnxExporterError("Failed to convert the exported program to an ONNX model.\n"
                              "No ONNX function found for <OpOverload(op='aten._linalg_eigh', "
                              "overload='default')>.")

    monkeypatch.setattr(torch.onnx, "export", unconvertible)
    code, err = export(models["contraction"][0], "onnx", tmp_path / "c.onnx", capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert ("ONNX cannot express the contraction field (no ONNX operator for aten._linalg_eigh); "
            "use --format torchscript or npz-grid") in err
    assert not (tmp_path / "c.onnx").exists()


def test_onnx_without_the_package_is_a_clean_error(models, tmp_path: Path, capsys,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "onnx", None)        # import onnx -> ImportError
    code, err = export(models["node"][0], "onnx", tmp_path / "f.onnx", capsys)
    assert code == 2 and "pip install 'lfd-arm[export]'" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("learner, n", [("node", 101), ("contraction", 101), ("contraction3d", 15),
                                        ("contracting_node", 101)])
def test_npz_grid_reproduces_the_field(learner: str, n: int, models, tmp_path: Path, capsys) -> None:
    path, field = models[learner]
    code, err = export(path, "npz-grid", tmp_path / "g.npz", capsys, "--grid", str(n))
    assert code == 0 and err == ""
    with np.load(tmp_path / "g.npz") as z:
        assert z["axes"].shape == (field.dim, n) and z["v"].shape == (n,) * field.dim + (field.dim,)
        assert str(z["interpolation"]) == "multilinear" and str(z["learner"]) == field.learner
        np.testing.assert_allclose(z["goal"], field.goal, rtol=0, atol=0)
    grid = GridField.load(str(tmp_path / "g.npz"))
    nodes = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, field.dim)[::7]
    assert np.abs(grid(nodes) - field(nodes)).max() <= TOL       # at the nodes: the field's own values
    lo, hi = grid.axes[:, 0], grid.axes[:, -1]
    x = np.random.default_rng(5).uniform(lo, hi, size=(400, field.dim))
    scipy_linear = RegularGridInterpolator(tuple(grid.axes), grid.v)(x)
    assert np.abs(grid(x) - scipy_linear).max() <= 1e-12 * max(1.0, np.abs(grid.v).max())
    # between nodes: O(h^2), far below this bound at the default grid
    assert np.abs(grid(x) - field(x)).max() <= 0.02 * np.abs(field(x)).max()
    outside = hi + 10.0 * (hi - lo)                                # clamped to the box's corner
    np.testing.assert_allclose(grid(outside), grid(hi), rtol=0, atol=1e-12)


def test_export_rejects_bad_input(models, tmp_path: Path, capsys) -> None:
    path, _ = models["node"]
    for extra, message in ((("--grid", "5"), "npz-grid only"),):
        code, err = export(path, "torchscript", tmp_path / "f.ts", capsys, *extra)
        assert code == 2 and message in err
    code, err = export(path, "torchscript", path, capsys)
    assert code == 2 and "overwrite" in err
    code, err = export(path, "npz-grid", tmp_path / "g.npz", capsys, "--grid", "1")
    assert code == 2 and "--grid" in err and len(err.strip().splitlines()) == 1
    code, err = export(path, "npz-grid", tmp_path / "g.npz", capsys, "--box=1,0,0,1")
    assert code == 2 and "box" in err
    code = main(["export", str(path), "--format", "pmml", "--out", str(tmp_path / "x")])
    assert code == 2 and "invalid choice" in capsys.readouterr().err
