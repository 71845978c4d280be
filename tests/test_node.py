"""NODE learner: fit quality, determinism, model files, numpy path, Ctrl-C, config errors, solvers."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from reference_kernels import node_reference
from torchdiffeq import odeint

import lfd
from lfd.demos import DemoSet
from lfd.learners.node import (
    ACTIVATIONS,
    NodeConfig,
    NodeField,
    NodeLearner,
    NodeMLP,
    ScaledMLP,
    SegmentDynamics,
    Segments,
    stratified_sample,
    uniform_grid,
)
from lfd.learners.node_kernel import RK4Segments, tanh_as_sigmoid
from lfd.learners.optim import Adam
from lfd.normalization import Normalization

# A short training: 300 iterations on the default spiral, 100 samples a demo, segments 2 -> 10.
QUICK = dict(iterations=300, samples=100, seg=10, seg_start=2, batch=128, lr=1e-2, lr_final=1e-4)
# Rollouts from the demo starts vs the demos, RMSE / scale (about half of it for seeds 0-2).
QUICK_RMSE = 0.06
# The final segment-loss (10 samples), normalised units squared (a third of it for seeds 0-2).
QUICK_LOSS = 3e-4


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def demos() -> DemoSet:
    return lfd.spiral()


@pytest.fixture(scope="module")
def field(demos: DemoSet) -> lfd.VelocityField:
    return lfd.train("node", demos, seed=0, progress=False, **QUICK)


def rollout_rmse(field: lfd.VelocityField, demos: DemoSet) -> float:
    """RMSE of rollouts from the demo starts against the demos, in units of the normalisation scale."""
    y = field.rollout(demos.x[:, 0], demos.t[0])
    return float(np.sqrt(np.mean(np.sum((y - demos.x) ** 2, axis=-1))) / field.norm.scale)


def test_quick_training_fits_the_spiral(field: lfd.VelocityField, demos: DemoSet) -> None:
    assert isinstance(field, NodeField)
    assert rollout_rmse(field, demos) < QUICK_RMSE
    h = field.history
    assert len(h["loss"]) == QUICK["iterations"] and h["iterations"] == QUICK["iterations"]
    assert h["interrupted"] is False and h["stopped_nonfinite"] is False
    assert h["seg"] == QUICK["seg"]
    assert h["best_loss"] == min(h["loss"][h["best_iter"]:])
    assert h["best_loss"] < QUICK_LOSS
    # the goal is an equilibrium (goal_equilibrium=True by default): f(goal) = g(0) - g(0), two
    # evaluations whose BLAS kernels may differ (memory layout, CPU): zero up to round-off
    np.testing.assert_allclose(field(demos.goal), np.zeros(2), rtol=0, atol=1e-12)


def test_same_seed_gives_bit_identical_weights(demos: DemoSet) -> None:
    opts: dict[str, Any] = dict(QUICK, iterations=25)
    a = lfd.train("node", demos, seed=3, progress=False, **opts)
    b = lfd.train("node", demos, seed=3, progress=False, **opts)
    c = lfd.train("node", demos, seed=4, progress=False, **opts)
    sa, sb, sc = a.module.state_dict(), b.module.state_dict(), c.module.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a.history["loss"] == b.history["loss"]
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)


def test_progress_bar_only_when_asked(demos: DemoSet, capsys: pytest.CaptureFixture[str]) -> None:
    lfd.train("node", demos, progress=False, **dict(QUICK, iterations=5))
    assert capsys.readouterr().err == ""
    lfd.train("node", demos, progress=True, **dict(QUICK, iterations=5))
    assert "node:" in capsys.readouterr().err


def test_save_load_round_trip_is_bit_identical(field: lfd.VelocityField, tmp_path: Path) -> None:
    path = tmp_path / "node.pt"
    field.save(path)
    loaded = lfd.load(str(path))
    assert isinstance(loaded, NodeField)
    assert loaded.config == field.config and loaded.history == field.history
    x = np.random.default_rng(0).uniform(-1.5, 1.5, (500, 2))
    np.testing.assert_array_equal(loaded(x), field(x))
    f, g = field.single_point_evaluator(), loaded.single_point_evaluator()
    for xi in x[:50]:
        np.testing.assert_array_equal(g(xi), f(xi))
    t = np.linspace(0, 5, 50)
    np.testing.assert_array_equal(loaded.rollout(x[:3], t), field.rollout(x[:3], t))


def test_config_is_json_and_recorded(field: lfd.VelocityField) -> None:
    cfg = json.loads(json.dumps(field.config))
    assert cfg["hidden"] == [32, 32] and cfg["solver"] == "rk4" and cfg["iterations"] == QUICK["iterations"]
    assert NodeLearner.make_config(**cfg) == NodeConfig(**{**cfg, "hidden": tuple(cfg["hidden"])})


@pytest.mark.parametrize("activation", list(ACTIVATIONS))
def test_numpy_point_path_matches_torch(activation: str) -> None:
    torch.manual_seed(1)
    config = NodeLearner.make_config(activation=activation, hidden=(32, 24, 16))
    module = NodeLearner.build(3, config)
    with torch.no_grad():
        for p in module.parameters():
            p.mul_(4.0)  # push pre-activations well into every branch (softplus threshold 20 too)
    norm = Normalization(goal=np.array([0.4, -0.3, 1.2]), scale=0.35)
    f = NodeField(module, norm, "node", dataclasses.asdict(config))
    x = np.random.default_rng(2).uniform(-1.0, 2.0, (300, 3))
    ref = f(x)
    point, point_n = f.single_point_evaluator(), node_reference(module)
    got = np.stack([point(xi) for xi in x])
    got_n = np.stack([point_n(xi) for xi in norm.to_norm(x)])
    assert np.abs(ref).max() > 1.0
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
    np.testing.assert_allclose(got_n * norm.scale, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
    assert isinstance(point(x[0]), np.ndarray) and point(x[0]).shape == (3,)


def test_output_layer_is_linear(field: lfd.VelocityField) -> None:
    module = field.module
    assert isinstance(module, NodeMLP) and isinstance(module.net[-1], torch.nn.Linear)
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 15), np.linspace(-1, 1, 15)), -1).reshape(-1, 2)
    v = field(field.norm.from_norm(grid))
    for j in range(2):  # a rotation: each velocity component takes both signs
        assert (v[:, j] < -0.1).any() and (v[:, j] > 0.1).any()


@pytest.mark.parametrize("activation", list(ACTIVATIONS))
def test_fused_mlp_gradient(activation: str) -> None:
    torch.manual_seed(0)
    module = NodeMLP(3, (5, 4), activation, goal_equilibrium=True).double()
    x = (3 * torch.randn(7, 3, dtype=torch.float64)).requires_grad_()
    h = torch.rand(7, 1, dtype=torch.float64)
    c = torch.randn(1, 3, dtype=torch.float64, requires_grad=True)
    params = [p.detach().clone().requires_grad_()
              for m in module.linears() for p in (m.weight.t().contiguous(), m.bias)]
    assert torch.autograd.gradcheck(lambda x, c, *ps: ScaledMLP.apply(x, h, c, activation, *ps),
                                    (x, c, *params))
    # the fused dynamics equal the plain module path, values and parameter gradients
    fused, plain = SegmentDynamics(module, fused=True), SegmentDynamics(module, fused=False)
    fused.begin(h)
    plain.begin(h)
    y1, y2 = fused(torch.zeros(()), x), plain(torch.zeros(()), x)
    torch.testing.assert_close(y1, y2, rtol=1e-12, atol=1e-12)
    g1 = torch.autograd.grad(y1.square().sum(), list(module.parameters()))
    g2 = torch.autograd.grad(y2.square().sum(), list(module.parameters()))
    for a, b in zip(g1, g2):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize(("activation", "hidden", "substeps"),
                         [("tanh", (6, 5), 1), ("tanh", (7,), 3), ("tanh", (4, 4, 4), 2),
                          ("softplus", (6, 5), 1), ("relu", (5,), 2), ("silu", (5, 4), 1), ("elu", (4, 6), 1)])
def test_fused_rk4_segments_equal_torchdiffeq(activation: str, hidden: tuple[int, ...], substeps: int) -> None:
    """The one-node RK4 integration (tanh written as logistic layers) and its hand-written adjoint
    give torchdiffeq's rk4 states and the parameter gradients of autograd through it."""
    torch.manual_seed(1)
    module = NodeMLP(3, hidden, activation, goal_equilibrium=True).double()
    dyn = SegmentDynamics(module, fused=True)
    x0 = torch.randn(9, 3, dtype=torch.float64)
    h = 0.05 + 0.3 * torch.rand(9, 1, dtype=torch.float64)
    target = torch.randn(7, 9, 3, dtype=torch.float64)
    dyn.begin(h / substeps)
    params, act = (tanh_as_sigmoid(dyn.params), "sigmoid") if activation == "tanh" else (dyn.params, activation)
    fused = RK4Segments.apply(x0, h / substeps, dyn.offset, substeps, 7, act, *params)
    g_fused = torch.autograd.grad((fused - target).square().sum(), list(module.parameters()))
    dyn.begin(h)
    options = {"step_size": 1.0 / substeps} if substeps > 1 else {}
    ref = odeint(dyn, x0, torch.arange(7, dtype=torch.float64), method="rk4", options=options)
    g_ref = torch.autograd.grad((ref - target).square().sum(), list(module.parameters()))
    torch.testing.assert_close(fused, ref, rtol=1e-12, atol=1e-12)
    for a, b in zip(g_fused, g_ref):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)


def test_ctrl_c_keeps_the_best_module(demos: DemoSet, monkeypatch: pytest.MonkeyPatch) -> None:
    stop_at = 12
    seen: list[dict[str, torch.Tensor]] = []
    real_step = Adam.step

    def step(self: Adam, *args: Any, **kwargs: Any) -> Any:
        params = self.params
        seen.append({str(i): p.detach().clone() for i, p in enumerate(params)})
        if len(seen) == stop_at + 1:
            with torch.no_grad():
                for p in params:
                    p.fill_(float("nan"))  # a half-done step: must not survive
            raise KeyboardInterrupt
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(Adam, "step", step)
    f = lfd.train("node", demos, seed=0, progress=False, **dict(QUICK, iterations=100, seg_start=10, lr=3e-2))
    h = f.history
    assert h["interrupted"] is True
    assert h["iterations"] == len(h["loss"]) == stop_at + 1
    assert h["best_loss"] == min(h["loss"]) and h["best_iter"] == int(np.argmin(h["loss"]))
    kept = [p.detach() for p in f.module.parameters()]
    best = seen[h["best_iter"]]
    assert all(torch.equal(p, best[str(i)].double()) for i, p in enumerate(kept))
    assert np.isfinite(f(demos.x[:, 0])).all()


def test_divergence_stops_and_keeps_the_best_module(demos: DemoSet, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    real_step = Adam.step

    def step(self: Adam, *args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        out = real_step(self, *args, **kwargs)
        if len(calls) == 8:
            with torch.no_grad():
                for p in self.params:
                    p.fill_(float("inf"))
        return out

    monkeypatch.setattr(Adam, "step", step)
    with pytest.warns(RuntimeWarning, match="non-finite at iteration 8"):
        f = lfd.train("node", demos, seed=0, progress=False, **dict(QUICK, iterations=50, seg_start=10))
    h = f.history
    assert h["stopped_nonfinite"] is True and h["interrupted"] is False and h["iterations"] == 8
    assert h["best_iter"] < 8 and np.isfinite(f(demos.x[:, 0])).all()


@pytest.mark.parametrize("options, message", [
    (dict(hidden=(64, 0)), "hidden must list at least one positive integer width"),
    (dict(hidden="64"), "hidden"),
    (dict(hidden=(32.5,)), "hidden"),
    (dict(activation="sigmoid"), "unknown activation 'sigmoid'"),
    (dict(solver="rk45"), "unknown solver 'rk45'"),
    (dict(lr=-1.0), "lr must be a positive number"),
    (dict(lr=1e-3, lr_final=1e-2), "lr_final"),
    (dict(iterations=0), "iterations must be an integer >= 1"),
    (dict(iterations=2.5), "iterations must be an integer"),
    (dict(seg=1), "seg must be an integer >= 2"),
    (dict(seg=10, seg_start=12), "seg_start (12) must not exceed seg (10)"),
    (dict(batch=-1), "batch"),
    (dict(samples=5, seg=10), "samples (5) must be at least seg (10)"),
    (dict(curriculum=1.5), "curriculum must be a number in [0, 1]"),
    (dict(weight_decay="none"), "weight_decay"),
    (dict(lr=float("nan")), "lr must be a positive number"),
    (dict(dtype="float16"), "dtype"),
    (dict(adjoint="yes"), "adjoint"),
    (dict(depth=3), "unknown option(s) depth"),
])
def test_bad_config_is_a_config_error(options: dict[str, Any], message: str, demos: DemoSet) -> None:
    with pytest.raises(lfd.ConfigError, match="^node: ") as err:
        lfd.train("node", demos, progress=False, **options)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_segments_longer_than_demos_are_a_config_error() -> None:
    short = lfd.spiral(n_samples=12)
    with pytest.raises(lfd.ConfigError, match=r"seg \(15\) exceeds the 12 samples"):
        lfd.train("node", short, progress=False, iterations=5, seg=15)


def test_adaptive_solver_and_adjoint_train(demos: DemoSet) -> None:
    base = dict(QUICK, iterations=15, seg=5, seg_start=5)
    rk4 = lfd.train("node", demos, seed=0, progress=False, **base)
    dopri = lfd.train("node", demos, seed=0, progress=False,
                      **dict(base, solver="dopri5", rtol=1e-6, atol=1e-8))
    adj = lfd.train("node", demos, seed=0, progress=False, **dict(base, adjoint=True))
    for f in (dopri, adj):
        loss = f.history["loss"]
        assert len(loss) == 15 and np.isfinite(loss).all()
        assert loss[-1] < 0.5 * loss[0]
    # same start, same first batch: the first losses agree up to the solvers' errors
    assert dopri.history["loss"][0] == pytest.approx(rk4.history["loss"][0], rel=1e-3)
    assert adj.history["loss"][0] == pytest.approx(rk4.history["loss"][0], rel=1e-5)


def test_uniform_grids_and_segments() -> None:
    t = np.linspace(0.0, 1.0, 30)
    x = np.stack([np.sin(3 * t), np.cos(3 * t) - np.cos(3.0)], -1)
    fast = DemoSet(t, x)
    slow = DemoSet(2 * t ** 1.5, x)  # longer and non-uniform: resampled onto a uniform grid
    both = DemoSet(np.stack([fast.t[0], slow.t[0]]), np.stack([fast.x[0], slow.x[0]]))
    xu, h = uniform_grid(both)
    np.testing.assert_array_equal(xu[0], x)  # already uniform: untouched
    np.testing.assert_allclose(h, [1 / 29, 2 / 29])
    tn = np.linspace(0, 2, 30)
    np.testing.assert_allclose(xu[1, :, 0], np.interp(tn, slow.t[0], x[:, 0]))
    x100, h100 = uniform_grid(both, samples=100)  # a cap: shorter demos are not upsampled
    np.testing.assert_array_equal(x100, xu)
    np.testing.assert_array_equal(h100, h)
    x10, h10 = uniform_grid(both, samples=10)
    assert x10.shape == (2, 10, 2)
    np.testing.assert_allclose(h10, [1 / 9, 2 / 9])
    seg = Segments.of(torch.from_numpy(xu), torch.from_numpy(h), 4)
    assert seg.windows.shape == (4, 2 * 27, 2) and seg.h.shape == (54, 1)
    np.testing.assert_array_equal(seg.windows[:, 28].numpy(), xu[1, 1:5])
    assert float(seg.h[28]) == h[1]


def test_stratified_sample_covers_every_stratum() -> None:
    gen = torch.Generator().manual_seed(0)
    idx = stratified_sample(1000, 64, gen)
    edges = np.arange(65) * 1000 // 64
    assert ((idx.numpy() >= edges[:-1]) & (idx.numpy() < edges[1:])).all()


@pytest.mark.parametrize("weight_decay", [0.0, 1e-3])
def test_adam_is_torch_adam_with_its_cosine_schedule_bit_for_bit(weight_decay: float) -> None:
    """``lfd.learners.optim.Adam`` (no torch.optim import, which costs seconds) takes the same steps as
    torch.optim.Adam stepped with CosineAnnealingLR, past t_max too."""
    torch.manual_seed(0)
    ours = [torch.randn(5, 3, requires_grad=True), torch.randn(3, requires_grad=True)]
    theirs = [p.detach().clone().requires_grad_(True) for p in ours]
    opt = Adam(ours, lr=2e-2, lr_final=1e-4, t_max=40, weight_decay=weight_decay)
    ref = torch.optim.Adam(theirs, lr=2e-2, weight_decay=weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(ref, T_max=40, eta_min=1e-4)
    for _ in range(50):
        x = torch.randn(7, 5)
        for params, o in ((ours, opt), (theirs, ref)):
            o.zero_grad()
            ((x @ params[0] + params[1]).tanh() ** 2).sum().backward()
            o.step()
        sched.step()
        assert all(torch.equal(a, b) for a, b in zip(ours, theirs))
        assert opt.lr == ref.param_groups[0]["lr"]
