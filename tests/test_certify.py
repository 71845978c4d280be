"""The contraction certificate (``lfd.certify``) and the ``lfd certify`` command.

Known answers first: a linear field f(x) = A (x - g) in the identity metric has
g(x) = max eig(A + A') everywhere; a contraction model in its own metric has
g(x) = max eig(A + A') of its latent matrix (Eq. (C1) holds with equality in J_phi' J_phi).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import lfd
from lfd.certify import IDENTITY_RATE, certify, default_box, grid
from lfd.cli import main
from lfd.errors import ConfigError
from lfd.learners.contraction import ContractionField

SAMPLES = 2000


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def models(spiral: lfd.DemoSet, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Model files: contraction at weak and strong rates (short fits), and a NODE."""
    out = tmp_path_factory.mktemp("models")
    paths = {}
    for name, learner, options in (("weak", "contraction", {"rate": 0.2, "iterations": 40}),
                                   ("strong", "contraction", {"rate": 3.0, "iterations": 40}),
                                   ("node", "node", {"iters": 150})):
        field = lfd.train(learner, spiral, seed=0, progress=False, **options)
        paths[name] = str(out / f"{name}.pt")
        field.save(paths[name])
    return paths


def latent_worst(field: ContractionField) -> float:
    a = field.latent_matrix
    return float(np.linalg.eigvalsh(a + a.T).max())


# ---------------------------------------------------------------- known answers

def test_linear_field_in_identity_metric_gives_max_eig_of_a_plus_at(make_linear_field) -> None:
    goal = np.array([0.5, -0.25])
    stable = make_linear_field(np.array([[-1.0, 3.0], [-3.0, -1.0]]), goal, scale=2.0)   # A + A' = -2 I
    sheared = make_linear_field(np.array([[-1.0, 4.0], [0.0, -1.0]]), goal, scale=2.0)   # eig(A + A') = -6, 2
    lo, hi = goal - 1.0, goal + 1.0
    c = certify(stable, lo, hi, samples=SAMPLES, rate=0.9)
    assert c.certified and c.metric == "identity" and c.worst == pytest.approx(-2.0, abs=1e-12)
    assert c.metric_min_eig == c.metric_max_eig == 1.0 and c.n_points >= SAMPLES
    assert not certify(stable, lo, hi, samples=SAMPLES, rate=1.1).certified
    c = certify(sheared, lo, hi, samples=SAMPLES)
    assert not c.certified and c.rate == IDENTITY_RATE and c.worst == pytest.approx(2.0, abs=1e-12)


def test_grid_covers_the_box_corners() -> None:
    pts = grid(np.array([0.0, -1.0, 2.0]), np.array([1.0, 1.0, 3.0]), 1000)
    assert pts.shape == (1000, 3)
    assert np.array_equal(pts.min(0), [0.0, -1.0, 2.0]) and np.array_equal(pts.max(0), [1.0, 1.0, 3.0])
    assert grid(np.zeros(2), np.ones(2), 1001).shape == (32 * 32, 2)


# ---------------------------------------------------------------- contraction models

def test_trained_contraction_models_are_certified_at_their_rates(models: dict[str, str]) -> None:
    for name, rate in (("weak", 0.2), ("strong", 3.0)):
        field = lfd.load(models[name])
        c = certify(field, samples=SAMPLES)
        assert c.certified and c.metric == "learned" and c.rate == rate and c.bound == -2 * rate
        assert c.worst == pytest.approx(latent_worst(field), rel=1e-6)
        assert 0 < c.metric_min_eig <= c.metric_max_eig < np.inf and c.n_invalid == 0


def test_certificate_fails_when_asked_for_more_than_was_built(models: dict[str, str]) -> None:
    field = lfd.load(models["strong"])
    built = -latent_worst(field) / 2                # the rate the model actually has, >= 3
    assert certify(field, samples=SAMPLES, rate=0.99 * built).certified
    assert not certify(field, samples=SAMPLES, rate=1.01 * built).certified


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_randomly_initialised_contraction_models_are_certified(spiral: lfd.DemoSet, seed: int) -> None:
    field = lfd.train("contraction", spiral, seed=seed, progress=False, iterations=0, rate=0.7)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in field.module.parameters():
            p.copy_(0.1 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    c = certify(field, samples=SAMPLES)
    assert c.certified and c.worst == pytest.approx(latent_worst(field), abs=1e-7)
    assert c.metric_max_eig / c.metric_min_eig > 1.5     # a genuinely curved metric, not the identity


def test_an_expanding_field_fails_in_its_learned_metric(models: dict[str, str]) -> None:
    field = lfd.load(models["weak"])
    field.module.rate = -0.5                          # A = +0.5 I + S - P: no longer contracting
    c = certify(field, samples=SAMPLES)
    assert not c.certified and c.worst == pytest.approx(latent_worst(field), abs=1e-8) and c.worst > -0.4


def test_default_box_is_the_demo_box_grown_by_half(models: dict[str, str], spiral: lfd.DemoSet) -> None:
    field = lfd.load(models["weak"])
    lo, hi = default_box(field)
    elo, ehi = spiral.bounds(0.5)
    assert np.allclose(lo, elo, atol=1e-12) and np.allclose(hi, ehi, atol=1e-12)


# ---------------------------------------------------------------- the NODE

def test_node_is_reported_honestly(models: dict[str, str], spiral: lfd.DemoSet) -> None:
    field = lfd.load(models["node"])
    lo, hi = spiral.bounds(0.5)
    c = certify(field, lo, hi, samples=SAMPLES)
    assert c.metric == "identity" and c.rate == IDENTITY_RATE and c.metric_min_eig == 1.0
    # the reported worst value is max eig(J + J') at the reported point, J by reverse-mode autodiff
    x = torch.as_tensor(c.argmax, dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(field.torch, x).numpy()
    assert c.worst == pytest.approx(float(np.linalg.eigvalsh(jac + jac.T).max()), rel=1e-9, abs=1e-9)
    assert not c.certified and c.worst > 0.0          # the learned spiral expands somewhere in the box


# ---------------------------------------------------------------- the command

def test_cli_exit_codes_and_json(models: dict[str, str], tmp_path, capsys) -> None:
    out = tmp_path / "cert.json"
    assert main(["certify", models["weak"], "--samples", "500", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["certified"] is True and report["learner"] == "contraction" and report["rate"] == 0.2
    assert report["worst"] <= report["bound"] + report["slack"] and len(report["argmax"]) == 2
    assert main(["certify", models["node"], "--demos", "spiral", "--samples", "500"]) == 1
    assert main(["certify", models["node"], "--samples", "500"]) == 1   # box from history["demo_box"]
    assert main(["certify", models["node"], "--box=-1,1,-1,1", "--samples", "500", "--rate", "0.1"]) == 1
    assert "NOT CERTIFIED" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [
    ["certify", "{weak}", "--box", "0,1,0"],                       # malformed box
    ["certify", "{weak}", "--box=1,0,0,1"],                        # empty box
    ["certify", "{weak}", "--box=0,1,0,1,0,1"],                    # 3-D box for a 2-D model
    ["certify", "{weak}", "--demos", "spiral3d"],                  # 3-D demos for a 2-D model
    ["certify", "{weak}", "--rate", "-1"],
    ["certify", "{weak}", "--samples", "1"],
    ["certify", "/no/such/model.pt"],
])
def test_cli_bad_input_exits_2(models: dict[str, str], argv: list[str], capsys) -> None:
    argv = [a.format(**models) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lfd: error:")


def test_bad_arguments_raise_config_error(models: dict[str, str]) -> None:
    field = lfd.load(models["weak"])
    with pytest.raises(ConfigError):
        certify(field, np.array([0.0, 0.0]), np.array([1.0, np.inf]))
    with pytest.raises(ConfigError):
        certify(field, tolerance=-1.0)


def test_a_metric_that_is_not_positive_definite_is_not_certified(models: dict[str, str], tmp_path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    field = lfd.load(models["weak"])
    real = field.metric_normalized_torch

    def broken(xn: torch.Tensor) -> torch.Tensor:   # indefinite where x_n > 0.5, NaN where y_n > 0.9
        m = real(xn)
        flip = torch.where(xn[:, 0] > 0.5, -1.0, 1.0).to(m.dtype)
        m = m * torch.stack([torch.ones_like(flip), flip], -1)[:, :, None]
        return torch.where((xn[:, 1] > 0.9)[:, None, None], torch.nan, m)

    monkeypatch.setattr(field, "metric_normalized_torch", broken)
    c = certify(field, samples=SAMPLES)
    assert not c.certified and c.worst == np.inf and 0 < c.n_invalid < c.n_points
    assert np.isfinite(c.metric_min_eig) and np.isfinite(c.metric_max_eig)


def test_a_3d_contraction_model_is_certified() -> None:
    field = lfd.train("contraction", lfd.spiral3d(), seed=0, progress=False, iterations=20, rate=1.0)
    c = certify(field, samples=SAMPLES)
    assert c.certified and len(c.argmax) == 3 and c.n_points == 13 ** 3
    assert c.worst == pytest.approx(latent_worst(field), rel=1e-6)
