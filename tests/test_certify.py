"""The contraction certificate (``lfd.certify``) and the ``lfd certify`` command.

Known answers first: a linear field f(x) = A (x - g) in the identity metric has
g(x) = max eig(A + A') everywhere; a contraction model in its own metric has
g(x) = max eig(A + A') of its latent matrix (Eq. (C1) holds with equality in J_phi' J_phi).
Then the verdicts: NaN or inf anywhere, a marginal or expanding field at a tiny rate, a NODE
whose grid passes but whose bound between the grid points does not, and a field with a spurious
attractor (``lfd.equilibria``), are never "certified".
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from equilibrium_fields import bistable_field, bistable_node

import lfd
import lfd.certify
from lfd.certify import IDENTITY_RATE, MIN_PER_AXIS, certify, default_box, grid
from lfd.cli import main
from lfd.equilibria import find_equilibria
from lfd.errors import ConfigError
from lfd.learners.contraction import ContractionField

SAMPLES = 900

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def models(spiral: lfd.DemoSet, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Model files: contraction at weak and strong rates (short fits), and a NODE."""
    out = tmp_path_factory.mktemp("models")
    paths = {}
    for name, learner, options in (("weak", "contraction", {"rate": 0.2, "iterations": 30}),
                                   ("strong", "contraction", {"rate": 1.0, "iterations": 30}),
                                   ("node", "node", {"iterations": 150})):
        field = lfd.train(learner, spiral, seed=0, progress=False, **options)
        paths[name] = str(out / f"{name}.pt")
        field.save(paths[name])
    return paths


def latent_worst(field: ContractionField) -> float:
    a = field.latent_matrix
    return float(np.linalg.eigvalsh(a + a.T).max())


def small_node(spiral: lfd.DemoSet, w1: float, w2: float) -> lfd.VelocityField:
    """A NODE whose field is f(x_n) = W2 tanh(W1 x_n) - f(0) with W1 = w1 I, W2 = w2 I (one hidden layer
    of width d): J = w1 w2 diag(sech^2(w1 x_n)), so it contracts in the identity metric for w1 w2 < 0."""
    field = lfd.train("node", spiral, seed=0, progress=False, iterations=1, hidden=(2,))
    with torch.no_grad():
        first, last = field.module.linears()
        first.weight.copy_(w1 * torch.eye(2))
        first.bias.zero_()
        last.weight.copy_(w2 * torch.eye(2))
        last.bias.zero_()
    field.__dict__.pop("_point", None)
    return field


# ---------------------------------------------------------------- known answers

def test_linear_field_in_identity_metric_gives_max_eig_of_a_plus_at(make_linear_field) -> None:
    a = np.array([[-1.0, 2.0], [-3.0, -0.5]])
    field = make_linear_field(a, np.array([0.5, -0.5]), scale=2.0)
    c = certify(field, np.array([-1.0, -1.0]), np.array([1.0, 1.0]), samples=400, rate=0.1)
    assert c.metric == "identity" and c.n_points == 400 and c.per_axis == 20
    assert c.worst == pytest.approx(float(np.linalg.eigvalsh(a + a.T).max()), rel=1e-12)
    # a linear field's Jacobian is constant: with no Lipschitz bound of J_f it is "not proven" at best
    assert c.verdict == "not proven" and not c.certified


def test_grid_covers_the_box_corners_with_a_minimum_per_axis() -> None:
    pts = grid(np.array([0.0, -1.0]), np.array([2.0, 1.0]), 5)
    assert pts.shape == (MIN_PER_AXIS ** 2, 2)
    for corner in ([0, -1], [0, 1], [2, -1], [2, 1]):
        assert np.any(np.all(np.isclose(pts, corner), axis=1))


def test_trained_contraction_models_are_certified_with_their_analytic_constants(models: dict[str, str]) -> None:
    for name in ("weak", "strong"):
        field = lfd.load(models[name])
        c = certify(field, samples=SAMPLES)
        assert c.certified and c.verdict == "certified" and c.proof.startswith("structural")
        assert c.worst == pytest.approx(latent_worst(field), rel=1e-6)
        assert c.worst <= c.bound + c.slack and c.slack < 1e-8      # round-off slack, not 1e-6
        assert c.condition_bound <= 100.0 * (1 + 1e-9) and c.overshoot <= 10.0 * (1 + 1e-9)
        a, b = field.metric_bounds
        assert c.metric_bound_a == pytest.approx(a) and c.metric_bound_b == pytest.approx(b)
        # the sampled eigenvalues of M lie inside the analytic bounds
        assert a * (1 - 1e-9) <= c.sampled_metric_min_eig <= c.sampled_metric_max_eig <= b * (1 + 1e-9)
        assert c.rk4_max_step == pytest.approx(2.6 / c.lipschitz_bound)
        # the grid covers where the trajectories from the box go
        lo, hi = np.array(c.checked_box)
        blo, bhi = np.array(c.box)
        assert (lo <= blo).all() and (hi >= bhi).all() and c.n_starts >= 256


def test_certificate_fails_when_asked_for_more_than_was_built(models: dict[str, str]) -> None:
    field = lfd.load(models["weak"])
    c = certify(field, samples=SAMPLES, rate=5.0, equilibria=False)
    assert c.verdict == "not certified" and "counterexample" in c.proof


def test_a_rotation_at_a_tiny_rate_is_not_certified(make_linear_field) -> None:
    """A pure rotation has g = 0 exactly: it does not contract at any rate, however small."""
    field = make_linear_field(np.array([[0.0, 2.0], [-2.0, 0.0]]), np.zeros(2))
    c = certify(field, np.array([-1.0, -1.0]), np.array([1.0, 1.0]), samples=400, rate=1e-7)
    assert c.verdict == "not certified" and c.worst > c.bound + c.slack
    expanding = make_linear_field(np.array([[1e-7, 0.0], [0.0, -1.0]]), np.zeros(2))
    c = certify(expanding, np.array([-1.0, -1.0]), np.array([1.0, 1.0]), samples=400, rate=1e-7)
    assert c.verdict == "not certified"


def test_an_expanding_field_fails_in_its_learned_metric(models: dict[str, str]) -> None:
    field = lfd.load(models["weak"])
    field.module.rate = -0.5                          # A = +0.5 I + S - P: no longer contracting
    c = certify(field, samples=SAMPLES, equilibria=False)
    assert not c.certified and c.worst == pytest.approx(latent_worst(field), abs=1e-8) and c.worst > -0.4


def test_nan_weights_are_never_certified(models: dict[str, str], spiral: lfd.DemoSet) -> None:
    for name in ("node", "weak"):
        field = lfd.load(models[name])
        with torch.no_grad():
            for p in field.module.parameters():
                p.fill_(math.nan)
        field.__dict__.pop("_point", None)
        c = certify(field, *spiral.bounds(0.5), samples=SAMPLES)
        assert c.verdict == "not certified" and not c.certified


def test_an_overflowing_part_of_the_box_is_not_certified(make_linear_field) -> None:
    """A contracting linear field whose values overflow to inf on part of a huge box: not certified."""
    field = make_linear_field(-1e10 * np.eye(2), np.zeros(2))
    ok = certify(field, np.array([-1.0, -1.0]), np.array([1.0, 1.0]), samples=400, rate=0.1)
    assert ok.worst == pytest.approx(-2e10)                          # every finite point passes
    c = certify(field, np.array([-1.0, -1.0]), np.array([1e300, 1e300]), samples=400, rate=0.1)
    assert c.verdict == "not certified" and c.n_invalid > 0


def test_node_certified_only_with_a_bound_between_samples(spiral: lfd.DemoSet) -> None:
    """f = -tanh: g(x) = -2 sech^2(x_n) on the grid; between the grid points Lip(J_f) bounds it."""
    field = small_node(spiral, 1.0, -1.0)
    lo, hi = spiral.bounds(0.5)
    c = certify(field, lo, hi, samples=SAMPLES, rate=0.05)
    assert c.verdict == "certified" and c.worst_over_box <= c.bound
    assert c.cell_lipschitz == pytest.approx(4 / (3 * math.sqrt(3)) / field.norm.scale, rel=1e-9)
    # asked for nearly all it has: the grid passes but the bound between points does not close
    tight = -float(np.max(-2 / np.cosh(field.norm.to_norm(grid(lo, hi, SAMPLES))) ** 2)) / 2 - 1e-4
    c = certify(field, lo, hi, samples=SAMPLES, rate=tight)
    assert c.verdict == "not proven" and c.worst <= c.bound


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
    assert c.metric == "identity" and c.rate == IDENTITY_RATE and c.sampled_metric_min_eig == 1.0
    assert c.overshoot is None and c.lipschitz_bound is None
    # the reported worst value is max eig(J + J') at the reported point, J by reverse-mode autodiff
    x = torch.as_tensor(c.argmax, dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(field.torch, x).numpy()
    assert c.worst == pytest.approx(float(np.linalg.eigvalsh(jac + jac.T).max()), rel=1e-9, abs=1e-9)
    assert c.verdict == "not certified" and c.worst > 0.0    # the learned spiral expands somewhere


# ---------------------------------------------------------------- the command

def test_cli_exit_codes_and_json(models: dict[str, str], tmp_path, capsys) -> None:
    out = tmp_path / "cert.json"
    assert main(["certify", models["weak"], "--samples", "400", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "CERTIFIED" in text and "overshoot sqrt(b/a)" in text and "RK4 is stable" in text
    report = json.loads(out.read_text())
    assert report["certified"] is True and report["learner"] == "contraction" and report["rate"] == 0.2
    assert report["worst"] <= report["bound"] + report["slack"] and len(report["argmax"]) == 2
    assert report["overshoot"] <= 10.0 * (1 + 1e-9)
    assert report["equilibria"]["clean"] is True and report["equilibria"]["equilibria"] == []
    assert main(["certify", models["node"], "--demos", "spiral", "--samples", "400"]) == 1
    assert main(["certify", models["node"], "--samples", "400", "--no-equilibria"]) == 1   # box: field.demo_box
    assert "NOT CERTIFIED" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [
    ["certify", "{weak}", "--box", "0,1,0"],                       # malformed box
    ["certify", "{weak}", "--box=1,0,0,1"],                        # empty box
    ["certify", "{weak}", "--box=0,1,0,1,0,1"],                    # 3-D box for a 2-D model
    ["certify", "{weak}", "--demos", "spiral3d"],                  # 3-D demos for a 2-D model
    ["certify", "{weak}", "--rate", "-1"],
    ["certify", "{weak}", "--samples", "4"],                       # the corners only: below 10 per axis
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
    with pytest.raises(ConfigError, match="10 per axis"):
        certify(field, samples=50)


def test_a_metric_that_is_not_positive_definite_is_not_certified(models: dict[str, str],
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    field = lfd.load(models["weak"])
    real = field.metric_normalized_torch

    def broken(xn: torch.Tensor) -> torch.Tensor:   # indefinite where x_n > 0.5, NaN where y_n > 0.9
        m = real(xn)
        flip = torch.where(xn[:, 0] > 0.5, -1.0, 1.0).to(m.dtype)
        m = m * torch.stack([torch.ones_like(flip), flip], -1)[:, :, None]
        return torch.where((xn[:, 1] > 0.9)[:, None, None], torch.nan, m)

    monkeypatch.setattr(field, "metric_normalized_torch", broken)
    c = certify(field, samples=SAMPLES, equilibria=False)
    assert not c.certified and c.worst == np.inf and 0 < c.n_invalid < c.n_points
    assert np.isfinite(c.sampled_metric_min_eig) and np.isfinite(c.sampled_metric_max_eig)


def test_a_3d_contraction_model_is_certified() -> None:
    field = lfd.train("contraction", lfd.spiral3d(), seed=0, progress=False, iterations=20, rate=1.0)
    c = certify(field, samples=1000, equilibria=False)
    assert c.certified and len(c.argmax) == 3 and c.n_points == 10 ** 3
    assert c.worst == pytest.approx(latent_worst(field), rel=1e-6)


def test_the_tracking_learner_is_certified_in_its_own_sense(spiral: lfd.DemoSet) -> None:
    """The tracking field's stated property (x-subsystem contracting at rate K, a = b = 1)."""
    field = lfd.train("tracking", spiral, seed=0, progress=False, rate=3.0)
    c = certify(field, samples=SAMPLES)
    assert c.verdict == "certified" and c.overshoot == 1.0 and c.condition_bound == 1.0
    assert c.worst == pytest.approx(-6.0, abs=1e-9) and "tracking error" in c.proof
    assert "overshoot sqrt(b/a) = 1" in c.summary()


def test_cli_reports_a_nan_model_not_certified_with_exit_1(models: dict[str, str], tmp_path, capsys) -> None:
    """Other commands refuse NaN weights (exit 2); ``lfd certify`` reads them and says NOT certified."""
    field = lfd.load(models["node"])
    with torch.no_grad():
        next(field.module.parameters()).fill_(math.nan)
    path = tmp_path / "nan.pt"
    field.save(path)
    assert main(["certify", str(path), "--samples", "400"]) == 1
    assert "NOT CERTIFIED" in capsys.readouterr().out
    assert main(["eval", str(path), "--demos", "spiral"]) == 2


# ---------------------------------------------------------------- equilibria and closed orbits

def test_a_spurious_attractor_makes_a_certified_field_not_certified(models: dict[str, str],
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever the contraction check says, a spurious attractor in the box refuses the certificate."""
    field = lfd.load(models["weak"])
    clean = certify(field, samples=SAMPLES)
    assert clean.certified and clean.equilibria is not None and clean.equilibria.clean
    found = find_equilibria(bistable_field(), np.array([-3.0, -1.0]), np.array([1.0, 1.0]), duration=5.0)
    monkeypatch.setattr(lfd.certify, "find_equilibria", lambda *args, **kwargs: found)
    c = certify(field, samples=SAMPLES)
    assert c.verdict == "not certified" and not c.certified and c.worst == clean.worst
    assert c.proof.startswith("1 spurious attractor besides the goal")
    assert "attractor at (-2, " in c.summary() and json.loads(json.dumps(c.to_dict()))["equilibria"]["clean"] is False


def test_certify_reports_a_nodes_spurious_attractor(spiral: lfd.DemoSet, tmp_path, capsys) -> None:
    field = bistable_node(spiral)
    where = field.goal + field.norm.scale * np.array([-1.0, 0.0])
    c = certify(field, *spiral.bounds(0.5), samples=SAMPLES, duration=5.0)
    assert c.verdict == "not certified" and c.equilibria is not None
    (sink,) = c.equilibria.spurious_attractors
    np.testing.assert_allclose(sink.location, where, atol=1e-6)
    path, out = tmp_path / "bistable.pt", tmp_path / "cert.json"
    field.save(path)
    assert main(["certify", str(path), "--demos", "spiral", "--samples", "400", "--json", str(out)]) == 1
    text = capsys.readouterr().out
    assert "NOT CERTIFIED" in text and "attractor at (" in text and "saddle at (" in text
    report = json.loads(out.read_text())["equilibria"]
    assert report["spurious_attractors"] == 1 and report["clean"] is False
    assert report["method"]["duration_s"] == pytest.approx(5.0)
    np.testing.assert_allclose(report["equilibria"][0]["location"], where, atol=1e-6)
    assert main(["certify", str(path), "--samples", "400", "--no-equilibria", "--json", str(out)]) == 1
    assert json.loads(out.read_text())["equilibria"] is None
