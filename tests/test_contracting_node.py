"""The contracting NODE: contraction by construction (Eqs. (N1)-(N2)), checked far beyond the demos and
in the directions where it is most likely to fail; its compiled kernel, training and certificate.

One spiral model is trained per module (few iterations: the guarantees do not depend on the fit).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from cli_runs import run_main

import lfd
from lfd import metrics
from lfd.certify import _check_theorem, certify
from lfd.errors import ConfigError
from lfd.learners.contracting_node import (
    RATE_FRACTION,
    ContractingNodeField,
    ContractingNodeModule,
    monotone_speed_retime,
    retimed,
)
from lfd.learners.contraction import feasible_rate, lipschitz_bound
from lfd.transient import transient_growth

pytestmark = pytest.mark.usefixtures("one_thread")
ITERATIONS = 150


@pytest.fixture(scope="module")
def field(spiral: lfd.DemoSet) -> ContractingNodeField:
    f = lfd.train("contracting_node", spiral, seed=0, progress=False, iterations=ITERATIONS)
    assert isinstance(f, ContractingNodeField)
    return f


def random_module(dim: int, scale: float, seed: int) -> ContractingNodeModule:
    """A fresh module with large random weights: the latent skew, damping and ridge gains, and a bent flow."""
    torch.manual_seed(seed)
    field = lfd.train("contracting_node", lfd.spiral(n_demos=2, n_samples=60) if dim == 2 else
                      lfd.spiral3d(n_demos=2, n_samples=60), seed=seed, progress=False, iterations=0, rate=0.3)
    module = field.module
    with torch.no_grad():
        module.skew.normal_(std=scale)
        if module.damping is not None:
            module.damping.normal_(std=scale)
        module.ridge_w.normal_(std=scale)
        module.ridge_delta.normal_(mean=1.0, std=scale)
        module.flow.theta.normal_(std=scale)
        module.flow.w2.normal_(std=scale)
    return module


def directions_and_radii(dim: int, seed: int) -> torch.Tensor:
    """Latent points along the axes, the diagonals and random directions, at radii 1e-3 to 1e6."""
    rng = np.random.default_rng(seed)
    dirs = [np.eye(dim)[i] * s for i in range(dim) for s in (1, -1)]
    dirs += list(rng.normal(size=(16, dim)))
    dirs += [np.ones(dim), -np.ones(dim)]
    pts = [r * u / np.linalg.norm(u) for r in np.geomspace(1e-3, 1e6, 19) for u in dirs]
    return torch.tensor(np.array(pts))


# ---------------------------------------------------------------- the construction

@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("scale", [0.3, 3.0])
def test_latent_field_contracts_at_its_rate_everywhere(dim: int, scale: float) -> None:
    """sym(J_h) <= -rate I at every sampled latent point, out to 1e6, for large random weights (Eq. (N1))."""
    module = random_module(dim, scale, seed=int(10 * scale) + dim)
    with torch.no_grad():
        y_star = module.flow(torch.zeros(1, dim, dtype=torch.float64))
    h = module.latent_function(y_star.detach())
    y = y_star + directions_and_radii(dim, dim)
    jac = torch.func.vmap(torch.func.jacrev(lambda p: h(p[None])[0]))(y)
    top = torch.linalg.eigvalsh((jac + jac.transpose(1, 2)) / 2).max(1).values
    assert float(top.max()) <= -module.rate + 1e-9 * float(torch.linalg.matrix_norm(jac, ord=2).max())
    # the ridge term is used: somewhere it contracts more than the linear part alone
    a = module.latent_matrix().detach()
    assert float(top.min()) < float(torch.linalg.eigvalsh((a + a.T) / 2).max()) - 1e-3


@pytest.mark.parametrize("scale", [0.3, 3.0])
def test_lipschitz_bound_holds_far_away(scale: float) -> None:
    """|J_f(x)| <= the analytic bound of Eq. (C6) with Lip(h) for |A| (Eq. (N2)), out to 1e6."""
    module = random_module(2, scale, seed=7)
    bound = lipschitz_bound(module)
    x = directions_and_radii(2, 11)
    jf = torch.func.vmap(torch.func.jacrev(lambda p: module(p[None])[0]))(x)
    norms = torch.linalg.matrix_norm(jf, ord=2)
    assert torch.isfinite(norms).all() and math.isfinite(bound)
    assert float(norms.max()) <= bound


def test_kernel_matches_the_module_and_the_goal_is_an_equilibrium(field: ContractingNodeField) -> None:
    """The compiled single point of Eq. (N2) against the batched torch path, near and far; f(goal) = 0 exactly."""
    fast = field.single_point_evaluator()
    assert np.array_equal(fast(field.norm.goal), np.zeros(2))
    rng = np.random.default_rng(0)
    pts = np.vstack([field.norm.goal + rng.normal(size=(40, 2)) * field.norm.scale * s for s in (0.1, 1.0, 1e3)])
    batched = field(pts)
    for p, v in zip(pts, batched):
        assert np.allclose(fast(p), v, rtol=1e-9, atol=1e-9 * np.abs(batched).max())


def test_trained_field_states_its_constants_and_keeps_them(field: ContractingNodeField,
                                                           spiral: lfd.DemoSet) -> None:
    """The rate chosen from the demos is written to the config; the weights satisfy the theorem; Eq. (18)
    with sqrt(b/a) holds for pairs split along M's top eigenvector, on the box and 1000 box sizes away."""
    rate = field.config["rate"]
    assert rate == field.rate == field.module.rate and 0.05 <= rate <= 5.0
    lam = field.history["feasible_rate"]
    assert rate == pytest.approx(min(5.0, max(0.05, RATE_FRACTION * lam)))
    conditions = field.theorem_conditions()
    assert conditions is not None and conditions["holds"]
    assert conditions["flow_ratio"] <= 10.0 + 1e-9
    lo, hi = field.demo_box
    growth = transient_growth(field, lo, hi, pairs=16)
    assert growth["holds"] and growth["overshoot"] <= 10.0 + 1e-9
    assert 1.0 - 1e-6 <= growth["worst_far"] <= growth["overshoot"]


def test_certify_reports_the_theorem_and_refuses_a_broken_weight(field: ContractingNodeField) -> None:
    cert = certify(field, samples=400, equilibria=False)
    assert cert.certified and cert.structural is not None and cert.growth is not None
    assert "Eq. (18) sampled" in cert.summary() and "the theorem's conditions hold" in cert.summary()
    broken = lfd.train("contracting_node", lfd.spiral(n_demos=2, n_samples=60), seed=0, progress=False,
                       iterations=5, rate=0.5)
    with torch.no_grad():     # a skew-free A with a positive eigenvalue: no longer -rate I - P
        broken.module.damping.zero_()
        broken.module.rate = -0.5
    conditions = broken.theorem_conditions()
    assert conditions is not None and not conditions["holds"] and conditions["sym_a_max"] == pytest.approx(1.0)
    bad = _check_theorem(broken, replace(cert, structural=None, growth=None), *broken.demo_box)
    assert not bad.certified and "fails in the weights" in bad.proof and "A CONDITION FAILS" in bad.summary()


# ---------------------------------------------------------------- training

def test_fits_the_spiral_and_every_start_reaches_the_goal(field: ContractingNodeField, spiral: lfd.DemoSet) -> None:
    xs = field.rollout(spiral.x[:, 0], spiral.t[0])
    extent = float(np.ptp(spiral.x))
    dtw = np.mean([metrics.dtw(x, d) / len(d) for x, d in zip(xs, spiral.x)])
    assert dtw <= 0.05 * extent     # the mean aligned distance; the demos' own spread is larger
    lo, hi = field.demo_box
    pad = (hi - lo) / 4
    g = np.stack(np.meshgrid(*[np.linspace(a - p, b + p, 8) for a, b, p in zip(lo, hi, pad)]), -1).reshape(-1, 2)
    end = field.rollout(g, np.linspace(0.0, 3 * 6.0 / field.rate, 600))[:, -1]
    assert np.linalg.norm(end - field.norm.goal, axis=1).max() <= 1e-3 * extent


def test_same_seed_same_model(spiral: lfd.DemoSet) -> None:
    a = lfd.train("contracting_node", spiral, seed=3, progress=False, iterations=20)
    b = lfd.train("contracting_node", spiral, seed=3, progress=False, iterations=20)
    assert all(torch.equal(p, q) for p, q in zip(a.module.state_dict().values(), b.module.state_dict().values()))
    x0 = spiral.x[:, 0]
    assert np.array_equal(a.rollout(x0, spiral.t[0]), b.rollout(x0, spiral.t[0]))


def test_retiming_keeps_the_path_and_never_speeds_up(spiral: lfd.DemoSet) -> None:
    """Eq. (N4): the same points in the same order, a non-increasing speed, the same deceleration at the end."""
    t, x = spiral.t[0], spiral.x[0]
    tn = monotone_speed_retime(t, x)
    assert np.all(np.diff(tn) > 0) and tn[0] == t[0] and tn[-1] <= t[-1]
    speed = np.linalg.norm(np.diff(x, axis=0), axis=1) / np.diff(tn)
    assert np.all(np.diff(speed) <= 1e-9 * speed.max())
    assert speed[-1] == pytest.approx(np.linalg.norm(x[-1] - x[-2]) / (t[-1] - t[-2]))
    r = retimed(spiral)
    assert r.x.shape == spiral.x.shape and np.allclose(r.x[:, -1], spiral.x[:, -1])
    assert feasible_rate(r.x - r.x[:, -1:], r.t, 100.0) >= feasible_rate(spiral.x - spiral.x[:, -1:], spiral.t, 100.0)


def test_poses_train_in_the_chart_and_contract() -> None:
    """A pose task (RoboTasks9) in the chart's R^6: the theorem's conditions and the kernel hold there too."""
    demos = lfd.load_demos("robottasks:pouring")
    f = lfd.train("contracting_node", demos, seed=0, progress=False, iterations=10)
    assert f.dim == 6 and f.theorem_conditions()["holds"]
    fast = f.single_point_evaluator()
    z = f.norm.goal + np.random.default_rng(1).normal(size=(10, 6)) * f.norm.scale
    assert np.allclose(np.stack([fast(p) for p in z]), f(z), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("options", [{"rate": 0.0}, {"rate": -1.0}, {"rate": float("nan")}, {"units": -1},
                                     {"path_weight": float("nan")}, {"seg": 1}, {"seg_start": 30},
                                     {"lr": 2.0}, {"monotone_speed": "yes"}, {"max_condition": 1.0},
                                     {"no_such_option": 1}])
def test_bad_options_are_refused(options: dict, spiral: lfd.DemoSet) -> None:
    with pytest.raises(ConfigError, match="contracting_node"):
        lfd.train("contracting_node", spiral, progress=False, **options)


def test_command_line_trains_and_certifies(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from lfd.cli import main

    model = tmp_path / "m.pt"
    code, _, err = run_main(main, ["train", "--learner", "contracting_node", "--demos", "spiral", "--iterations", "20",
                                   "--out", str(model), "--quiet"], capsys)
    assert code == 0, err
    code, out, err = run_main(main, ["certify", str(model), "--samples", "400", "--no-equilibria"], capsys)
    assert code == 0, err
    assert out.startswith("CERTIFIED") and "Eq. (18) sampled" in out
