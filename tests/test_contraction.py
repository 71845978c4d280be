"""The contraction learner: its flow and analytic bounds, its field, training, and its guarantees.

Two spiral models are trained once per module (weak rate 0.5/s and strong rate 1/s at the default
condition bound KAPPA = 100; the strong rate is the largest the spiral allows within it, see
``feasible_rate``). The bounds claimed for all x are checked far from the data, along the axes, the
diagonals and the coordinate strips, and for randomly initialised flows at several weight scales.
"""

from __future__ import annotations

import json
import math
import os
import warnings

import numpy as np
import pytest
import torch
from reference_kernels import bounded_flow_reference

import lfd
from lfd.errors import ConfigError
from lfd.learners.contraction import (
    ContractionConfig,
    ContractionField,
    ContractionModule,
    RateFeasibilityWarning,
    feasible_rate,
    lipschitz_bound,
)
from lfd.learners.flow_kernel import flow_point
from lfd.learners.flows import FACTORED_MIN_DIM, BoundedFlow

WEAK, STRONG = 0.5, 1.0

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def weak(spiral: lfd.DemoSet) -> ContractionField:
    return lfd.train("contraction", spiral, seed=0, progress=False, rate=WEAK)


@pytest.fixture(scope="module")
def strong(spiral: lfd.DemoSet) -> ContractionField:
    return lfd.train("contraction", spiral, seed=0, progress=False, rate=STRONG)


def random_flow(dim: int, seed: int, scale: float, max_condition: float = 100.0, hidden: int = 16) -> BoundedFlow:
    """A flow with random raw parameters of size ``scale`` (the budget still bounds it)."""
    torch.manual_seed(seed)
    flow = BoundedFlow(dim, 3, hidden, 1.5, max_condition).double()
    with torch.no_grad():
        flow.theta.normal_(std=scale)
        flow.w2.normal_(std=scale)
        flow.w1.mul_(scale)
        flow.split.normal_(std=1.0)
        flow.center.normal_(std=0.5)
    return flow


def far_points(dim: int) -> torch.Tensor:
    """Points along the axes, the diagonals and the strips (one coordinate small, another large),
    at radii from 0.1 to 1e6: where a windowed flow is most likely to break its bounds."""
    dirs = [np.eye(dim)[i] * s for i in range(dim) for s in (1, -1)]
    dirs += [np.array(v, dtype=float) / np.linalg.norm(v) for v in
             ([1, 1], [1, -1], [-1, 1], [-1, -1]) if dim == 2]
    dirs += [np.array(v, dtype=float) / np.linalg.norm(v) for v in
             ([1, 1, 1], [1, -1, 1], [-1, -1, 1], [1, 1, -1]) if dim == 3]
    pts = [r * u for r in np.geomspace(0.1, 1e6, 29) for u in dirs]
    for r in np.geomspace(1.0, 1e6, 13):       # strips: x_0 in [-0.3, 0.3], another coordinate large
        for small in (-0.3, 0.0, 0.3):
            for k in range(1, dim):
                p = np.zeros(dim)
                p[0], p[k] = small, r
                pts += [p, -p]
    rng = np.random.default_rng(dim)
    pts += list(rng.normal(size=(200, dim)) * 1.5)
    return torch.as_tensor(np.array(pts))


# ---------------------------------------------------------------- the flow phi and its bounds

@pytest.mark.parametrize("dim", [2, 3])
def test_flow_jacobian_inverse_compiled_and_numpy_paths_agree(dim: int) -> None:
    """J_phi against autograd, phi^-1, and the compiled phi and J_phi (``flow_point``) and the tests'
    numpy reference against the torch flow."""
    flow = random_flow(dim, seed=dim, scale=1.0)
    x = torch.randn(7, dim, dtype=torch.float64)
    y, jac = (t.detach() for t in flow.forward_with_jacobian(x))
    auto = torch.stack([torch.autograd.functional.jacobian(lambda p: flow(p[None])[0], xi) for xi in x])
    scale = float(jac.abs().max())
    assert float((jac - auto).abs().max()) <= 1e-10 * scale
    assert float((flow.inverse(y) - x).abs().max()) <= 1e-10 * (1 + float(y.abs().max()))
    params = flow.numpy_params()
    for xi, yi, ji in zip(x.numpy(), y.numpy(), jac.numpy()):
        for yn, jn in (bounded_flow_reference(params, xi), flow_point(params, xi)):
            assert np.allclose(yn, yi, rtol=1e-12, atol=1e-12)
            assert np.allclose(jn, ji, rtol=1e-10, atol=1e-10 * scale)


def test_fresh_flow_is_the_identity() -> None:
    torch.manual_seed(0)
    flow = BoundedFlow(2, 3, 8, 1.5, 100.0).double()
    x = torch.randn(5, 2, dtype=torch.float64)
    with torch.no_grad():
        y, jac = flow.forward_with_jacobian(x)
    assert float((y - x).abs().max()) < 1e-12
    assert float((jac - torch.eye(2, dtype=torch.float64)).abs().max()) < 1e-12


@pytest.mark.parametrize("scale", [0.1, 1.0, 3.0])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kappa", [4.0, 100.0, 1e4])
def test_analytic_singular_value_bounds_hold_everywhere(dim: int, scale: float, kappa: float) -> None:
    """s_lo <= sigma(J_phi(x)) <= s_hi at points out to |x| = 1e6, for random weights of any size,
    and (s_hi / s_lo)^2 <= KAPPA by construction (Eq. (F4))."""
    flow = random_flow(dim, seed=int(10 * scale) + dim, scale=scale, max_condition=kappa)
    s_lo, s_hi = flow.singular_value_bounds()
    assert (s_hi / s_lo) ** 2 <= kappa * (1 + 1e-9)
    with torch.no_grad():
        _, jac = flow.forward_with_jacobian(far_points(dim))
    sv = torch.linalg.svdvals(jac)
    assert torch.isfinite(sv).all()
    assert float(sv.max()) <= s_hi * (1 + 1e-9)
    assert float(sv.min()) >= s_lo * (1 - 1e-9)
    # the bound is not vacuous: the random flow uses a good part of it somewhere
    assert float(sv.max() / sv.min()) > 1.0 + 0.05 * min(scale, 1.0)


@pytest.mark.parametrize("scale", [0.1, 1.0, 3.0])
def test_field_lipschitz_bound_holds_far_away(spiral: lfd.DemoSet, scale: float) -> None:
    """|J_f(x)| <= Lip bound (Eq. (C6)) at the same far points, for randomly initialised models."""
    torch.manual_seed(int(scale * 10))
    field = lfd.train("contraction", spiral, seed=int(scale * 10), progress=False, iterations=0)
    module = field.module
    with torch.no_grad():
        module.flow.theta.normal_(std=scale)
        module.flow.w2.normal_(std=scale)
        module.flow.center.normal_(std=0.5)
    bound = lipschitz_bound(module)
    x = far_points(2)
    jf = torch.func.vmap(torch.func.jacrev(lambda p: module(p[None])[0]))(x)
    norms = torch.linalg.matrix_norm(jf, ord=2)
    assert torch.isfinite(norms).all()
    assert float(norms.max()) <= bound
    # far away the field is the latent linear map: |J_f| -> |A|
    a_norm = float(torch.linalg.matrix_norm(module.latent_matrix(), ord=2))
    assert float(norms[-400:-200].max()) <= bound and a_norm <= bound


# ---------------------------------------------------------------- options

@pytest.mark.parametrize("options", [{"rate": 0.0}, {"rate": -1.0}, {"rate": float("nan")}, {"rate": True},
                                     {"rate": 1e300}, {"layers": 0}, {"hidden": 2.5}, {"max_condition": 1.0},
                                     {"max_condition": float("nan")}, {"damping": "yes"}, {"no_such_option": 1},
                                     {"speed_weight": -0.1}, {"path_samples": 1}, {"traj_points": 1},
                                     {"speed_weight": 0.0, "traj_weight": 0.0}])
def test_bad_options_are_config_errors(spiral: lfd.DemoSet, options: dict) -> None:
    with pytest.raises(ConfigError):
        lfd.train("contraction", spiral, progress=False, **options)


def test_an_infeasible_rate_warns_and_names_the_largest_feasible_one(spiral: lfd.DemoSet) -> None:
    lam = feasible_rate(spiral.x - spiral.goal, spiral.t, 100.0)
    assert 1.0 < lam < 2.0                  # the spiral at KAPPA = 100 (the warning below names it)
    r = np.linalg.norm(spiral.x - spiral.goal, axis=-1)
    growth = r * np.exp(lam * (spiral.t - spiral.t[:, :1])) / r[:, :1]
    assert growth.max() == pytest.approx(10.0, rel=1e-9)     # exactly sqrt(KAPPA) at the binding sample
    with pytest.warns(RateFeasibilityWarning, match=r"largest feasible rate is 1\.2"):
        lfd.train("contraction", spiral, progress=False, rate=3.0, iterations=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RateFeasibilityWarning)
        lfd.train("contraction", spiral, progress=False, rate=1.0, iterations=2)


# ---------------------------------------------------------------- the construction, Eq. (C2)

def test_latent_matrix_is_contracting_with_the_requested_rate(weak: ContractionField,
                                                              strong: ContractionField) -> None:
    for field, rate in ((weak, WEAK), (strong, STRONG)):
        a = field.latent_matrix
        assert field.rate == rate
        assert np.linalg.eigvalsh(a + a.T).max() <= -2 * rate + 1e-12


def test_metric_is_jphi_t_jphi_in_user_units_and_within_its_bounds(weak: ContractionField,
                                                                   spiral: lfd.DemoSet) -> None:
    x = spiral.x[0, ::25]
    s, goal = weak.norm.scale, weak.norm.goal
    flow = weak.module.flow

    def phi_user(p: torch.Tensor) -> torch.Tensor:
        return flow(((p - torch.as_tensor(goal)) / s)[None])[0]

    for xi, mi in zip(x, weak.metric(x)):
        j = torch.autograd.functional.jacobian(phi_user, torch.as_tensor(xi)).numpy()
        assert np.allclose(mi, j.T @ j, rtol=1e-10, atol=1e-10 * np.abs(mi).max())
    a, b = weak.metric_bounds
    assert weak.condition_bound == pytest.approx(b / a) and weak.condition_bound <= 100.0 * (1 + 1e-9)
    far = spiral.goal + s * far_points(2).numpy()
    eig = np.linalg.eigvalsh(weak.metric(far))
    assert eig.min() >= a * (1 - 1e-9) and eig.max() <= b * (1 + 1e-9)


# ---------------------------------------------------------------- fit quality and guarantees

def test_weak_model_reproduces_the_spiral(weak: ContractionField, spiral: lfd.DemoSet) -> None:
    xs = weak.closed_form_rollout(spiral.x[:, 0], spiral.t[0])     # the spiral's demos share their times
    rmse = float(np.sqrt(((xs - spiral.x) ** 2).sum(-1).mean()))
    assert rmse < 0.2           # at KAPPA = 100, a tenth of the spiral's extent (far smaller at KAPPA = inf)
    assert np.linalg.norm(xs[:, -1] - spiral.goal, axis=1).max() < 0.2


def test_the_path_is_fitted_where_the_timing_cannot_be() -> None:
    """LASA GShape starts from rest and speeds up, which no field with |f(x(t))| <= sqrt(b/a)
    e^(-lambda t) |f(x(0))| can follow in time (training warns: the feasible rate is 0.43/s < 0.5/s).
    Eq. (C5) fits directions and paths instead: the rollouts from the demo starts follow the demos'
    paths (a loss that matched speeds and times gave several times the DTW) and arrive."""
    from lfd.metrics import dtw

    demos = lfd.lasa("GShape")
    with pytest.warns(RateFeasibilityWarning):
        field = lfd.train("contraction", demos, seed=0, progress=False)
    ys = [field.closed_form_rollout(demos.x[i, :1], demos.t[i] - demos.t[i, 0])[0] for i in range(demos.n_demos)]
    assert np.mean([dtw(y, x, step=4) for y, x in zip(ys, demos.x)]) < 1000.0
    extent = demos.extent
    assert max(np.linalg.norm(y[-1] - demos.goal) for y in ys) < 0.1 * extent    # about half of it in practice


def test_demos_that_rest_train_to_a_finite_model(spiral: lfd.DemoSet) -> None:
    """Samples at rest have no direction: Eq. (C5) gives them weight 0 instead of a NaN gradient."""
    x = np.concatenate([np.repeat(spiral.x[:, :1], 20, axis=1), spiral.x], axis=1)
    t = np.broadcast_to(np.linspace(0.0, 5.0, x.shape[1]), x.shape[:2])
    demos = lfd.DemoSet(t, x, name="resting")
    assert (np.linalg.norm(demos.xd, axis=-1) < 1e-12).any()
    field = lfd.train("contraction", demos, seed=0, progress=False, iterations=20)
    h = field.history
    assert not h["stopped_nonfinite"] and np.isfinite(h["loss"]).all() and h["loss"][-1] < h["loss"][0]
    assert np.isfinite(field(spiral.x[:, 0])).all()


def test_rk4_at_the_control_step_tracks_the_exact_flow(strong: ContractionField, spiral: lfd.DemoSet) -> None:
    """RK4 at 2 ms (500 Hz) from starts all over the 1.5x box stays within 1e-3 of the extent of Eq. (C4)."""
    lo, hi = spiral.bounds(0.5)
    corners = np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]]])
    starts = np.vstack([corners, np.random.default_rng(3).uniform(lo, hi, size=(12, 2))])
    t = np.arange(0.0, 3.0 + 1e-9, 0.002)
    exact = strong.closed_form_rollout(starts, t)
    rk4 = strong.rollout(starts, t, method="rk4")
    extent = spiral.extent
    assert np.abs(exact - rk4).max() < 1e-3 * extent


def test_strong_rate_converges_measurably_faster(weak: ContractionField, strong: ContractionField,
                                                 spiral: lfd.DemoSet) -> None:
    """Distances to the goal obey |x(t) - g| <= sqrt(b/a) e^(-lambda t) |x(0) - g| and decay faster
    under the strong model."""
    t = np.linspace(0.0, 8.0, 81)
    lo, hi = spiral.bounds(0.5)
    starts = np.random.default_rng(5).uniform(lo, hi, size=(10, 2))
    fitted = {}
    for field in (weak, strong):
        d = np.linalg.norm(field.closed_form_rollout(starts, t) - spiral.goal, axis=-1)     # (10, T)
        bound = math.sqrt(field.condition_bound) * np.exp(-field.rate * t) * d[:, :1]
        assert (d <= bound * (1 + 1e-6)).all()
        fitted[field.rate] = -np.polyfit(t[20:], np.log(d[:, 20:]).T, 1)[0]
    assert fitted[STRONG].min() > fitted[WEAK].max()


def test_worst_transient_growth_stays_below_the_analytic_constant(weak: ContractionField,
                                                                  strong: ContractionField,
                                                                  spiral: lfd.DemoSet) -> None:
    """A seeded random search for the largest |dx(t)| / |dx(0)| between neighbours starting in the
    1.5x box never exceeds sqrt(b/a) e^(-lambda t) (Eq. (C1) with the analytic a, b)."""
    lo, hi = spiral.bounds(0.5)
    rng = np.random.default_rng(11)
    t = np.linspace(0.0, 6.0, 121)
    for field in (weak, strong):
        x0 = rng.uniform(lo, hi, size=(200, 2))
        u = rng.normal(size=(200, 2))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        eps = 1e-6 * float((hi - lo).max())
        xs = field.closed_form_rollout(np.vstack([x0, x0 + eps * u]), t)
        growth = np.linalg.norm(xs[200:] - xs[:200], axis=-1) / eps             # (200, T)
        assert np.isfinite(growth).all()
        bound = math.sqrt(field.condition_bound) * np.exp(-field.rate * t)
        assert (growth <= bound * (1 + 1e-3)).all()
        assert growth.max() <= 10.0 * (1 + 1e-3)


def test_every_start_around_the_demos_converges(weak: ContractionField, strong: ContractionField,
                                                spiral: lfd.DemoSet) -> None:
    lo, hi = spiral.bounds(0.5)
    starts = np.random.default_rng(7).uniform(lo, hi, size=(100, 2))
    for field in (weak, strong):
        end = field.closed_form_rollout(starts, np.array([0.0, 10.0, 40.0]))
        dist = np.linalg.norm(end - spiral.goal, axis=-1)
        assert np.isfinite(dist).all()
        assert dist[:, 2].max() < 1e-3


# ---------------------------------------------------------------- compiled path, files, determinism

@pytest.mark.parametrize("spec", ["spiral", "spiral3d"])
def test_single_point_call_uses_the_compiled_path_and_equals_the_torch_path(spec: str, weak: ContractionField) -> None:
    demos = lfd.load_demos(spec)
    field = weak if spec == "spiral" else lfd.train("contraction", demos, progress=False, iterations=20)
    f = field.single_point_evaluator()
    pts = np.random.default_rng(1).uniform(*demos.bounds(1.0), size=(50, demos.dim))
    ref = field(pts)                                   # batched: the torch path
    got = np.stack([f(p) for p in pts])
    one = np.stack([field(p) for p in pts])           # one point: dispatched to the compiled path
    tol = 1e-10 * max(1.0, np.abs(ref).max())
    assert np.abs(got - ref).max() <= tol and np.abs(one - ref).max() <= tol


def test_model_file_round_trips(weak: ContractionField, tmp_path) -> None:
    path = tmp_path / "c.pt"
    weak.save(path)
    back = lfd.load(str(path))
    assert isinstance(back, ContractionField) and back.rate == WEAK
    assert back.config == weak.config
    sd, sd2 = weak.module.state_dict(), back.module.state_dict()
    assert sd.keys() == sd2.keys() and all(torch.equal(sd[k], sd2[k]) for k in sd)
    x = np.random.default_rng(2).uniform(-1, 1, size=(20, 2))
    assert np.allclose(back(x), weak(x), rtol=1e-13, atol=1e-13)
    assert back.metric_bounds == pytest.approx(weak.metric_bounds, rel=1e-12)


def test_training_is_deterministic_for_a_seed(spiral: lfd.DemoSet) -> None:
    a = lfd.train("contraction", spiral, seed=3, progress=False, iterations=15)
    b = lfd.train("contraction", spiral, seed=3, progress=False, iterations=15)
    c = lfd.train("contraction", spiral, seed=4, progress=False, iterations=15)
    sa, sb, sc = (f.module.state_dict() for f in (a, b, c))
    assert all(torch.equal(sa[k], sb[k]) for k in sa)          # the same computation, one process
    assert a.history["loss"] == b.history["loss"]
    assert not torch.equal(sa["flow.w1"], sc["flow.w1"])
    assert len(a.history["loss"]) >= 15 and a.history["loss"][-1] < a.history["loss"][0]


def test_ctrl_c_keeps_the_best_model(spiral: lfd.DemoSet, monkeypatch: pytest.MonkeyPatch) -> None:
    states: list[dict[str, torch.Tensor]] = []
    real = ContractionModule.velocity_and_latent

    def interrupting(self: ContractionModule, x: torch.Tensor):  # type: ignore[no-untyped-def]
        if len(states) == 12:
            raise KeyboardInterrupt
        states.append({k: v.detach().clone() for k, v in self.state_dict().items()})
        return real(self, x)

    monkeypatch.setattr(ContractionModule, "velocity_and_latent", interrupting)
    field = lfd.train("contraction", spiral, progress=False, iterations=100)
    monkeypatch.undo()
    h = field.history
    assert h["interrupted"] is True and h["iterations"] == 12 == len(h["loss"])
    best = int(np.argmin(h["loss"]))
    assert h["best_loss"] == h["loss"][best] < h["loss"][0]
    kept = field.module.state_dict()
    assert all(torch.equal(kept[k], states[best][k]) for k in kept)



def test_the_initial_latent_matrix_does_not_depend_on_memory_alignment() -> None:
    """The least-squares start of A (Eq. (C2)) from the same data at 8 byte offsets: one result.
    Without the aligned copy, MKL's lstsq gave 2 distinct results, and processes whose numpy
    buffers happened to be aligned differently trained different models."""
    demos = lfd.lasa("Angle").subset(list(range(7)))
    x0, v0 = torch.tensor(demos.x.reshape(-1, 2)), torch.tensor(demos.xd.reshape(-1, 2))
    results = set()
    for offset in range(8):
        bx, bv = torch.zeros(x0.numel() + 16, dtype=torch.float64), torch.zeros(v0.numel() + 16, dtype=torch.float64)
        x, v = bx[offset:offset + x0.numel()].view(-1, 2), bv[offset:offset + v0.numel()].view(-1, 2)
        x.copy_(x0)
        v.copy_(v0)
        module = ContractionModule(2, ContractionConfig())
        module.init_latent_from_data(x, v)
        results.add(module.latent_matrix().detach().numpy().tobytes())
    assert len(results) == 1


def test_the_same_seed_gives_the_same_models_in_other_processes() -> None:
    """Three processes with different hash seeds (so different heap layouts and numpy buffer
    alignments), each training a contraction and a NODE model. Before the learners copied their
    input into aligned torch memory, hash seed 7 changed a contraction fit by 3e-8 relative (60
    iterations). Across processes, so a tolerance."""
    import subprocess
    import sys

    code = ("import json, torch, lfd; torch.set_num_threads(1); d = lfd.lasa('Angle').subset(list(range(7))); "
            "fs = [lfd.train('contraction', d, seed=0, iterations=20), lfd.train('node', d, seed=0, iterations=30)]; "
            "print(json.dumps([torch.cat([v.flatten() for _, v in sorted(f.module.state_dict().items())]).tolist() "
            "for f in fs]))")
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONHASHSEED": seed}) for seed in ("1", "7", "3")]
    runs = []
    for proc in procs:
        out, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-2000:]
        runs.append([np.array(x) for x in json.loads(out.strip().splitlines()[-1])])
    for k in range(2):   # contraction, NODE
        assert runs[0][k].size > 10
        for other in runs[1:]:
            np.testing.assert_allclose(other[k], runs[0][k], rtol=1e-6, atol=1e-12)


# ---------------------------------------------------------------- the factored path (d >= FACTORED_MIN_DIM)

def _flow_outputs(flow: BoundedFlow, x: torch.Tensor, v: torch.Tensor, factored: bool
                  ) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    """phi(x), J_phi(x)^-1 v and the parameter gradients of a random linear functional of both."""
    if factored:
        y, solve = flow.forward_with_inverse_jacobian(x)
        f = solve(v)
    else:
        y, jac = flow.forward_with_jacobian(x)
        assert jac is not None
        f = torch.linalg.solve(jac, v)
    gen = torch.Generator().manual_seed(1)
    u, w = (torch.randn(x.shape, generator=gen, dtype=x.dtype) for _ in range(2))
    params = [p for p in flow.parameters() if p.requires_grad]
    grads = torch.autograd.grad((y * u).sum() + (f * w).sum(), params, allow_unused=True)
    return y.detach(), f.detach(), [torch.zeros_like(p) if g is None else g for p, g in zip(params, grads)]


# (d, H): 2 d <= H + 1 solves each block's d x d Jacobian, otherwise Woodbury's (H + 1) x (H + 1) system
@pytest.mark.parametrize("dim, hidden", [(8, 16), (8, 6), (12, 16), (16, 40), (16, 16)])
@pytest.mark.parametrize("scale", [0.1, 1.0, 3.0])
def test_the_factored_inverse_jacobian_agrees_with_the_dense_path(dim: int, hidden: int, scale: float) -> None:
    """phi(x), J_phi(x)^-1 v and their parameter gradients, layer by layer against the dense J_phi
    and its solve, to 1e-9 relative in float64: random weights of several sizes, points out to
    |x| = 1e6 (``far_points``) and near the centres."""
    for seed in range(2):
        flow = random_flow(dim, seed=100 * seed + dim + hidden, scale=scale, hidden=hidden)
        x = torch.cat([far_points(dim), flow.center.detach() + 1e-3, torch.zeros(1, dim, dtype=torch.float64)])
        v = torch.randn(x.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        y0, f0, g0 = _flow_outputs(flow, x, v, factored=False)
        y1, f1, g1 = _flow_outputs(flow, x, v, factored=True)
        assert float((y1 - y0).abs().max()) <= 1e-9 * float(y0.abs().max())
        assert float((f1 - f0).abs().max()) <= 1e-9 * float(f0.abs().max())
        for a, b in zip(g0, g1):
            assert float((b - a).abs().max()) <= 1e-9 * max(float(a.abs().max()), 1e-300)
        assert float(f0.abs().max()) > 0 and any(float(a.abs().max()) > 0 for a in g0)


def test_the_factored_path_needs_a_plane_generator() -> None:
    with pytest.raises(ValueError, match="d >= 4"):
        random_flow(3, seed=0, scale=1.0).forward_with_inverse_jacobian(torch.zeros(1, 3, dtype=torch.float64))


def test_only_large_dimensions_take_the_factored_path() -> None:
    config = ContractionConfig()
    assert FACTORED_MIN_DIM == 8
    assert not ContractionModule(FACTORED_MIN_DIM - 1, config).factored
    assert ContractionModule(FACTORED_MIN_DIM, config).factored


@pytest.mark.parametrize("samples", [2, 3, 8, 50, 65])
def test_the_latent_path_by_powers_equals_one_matrix_exponential_per_time(samples: int) -> None:
    torch.manual_seed(samples)
    module = ContractionModule(8, ContractionConfig()).double()
    with torch.no_grad():
        module.skew.normal_()
        assert module.damping is not None
        module.damping.normal_(std=0.5)
    y0, y_star = torch.randn(3, 8, dtype=torch.float64), torch.randn(1, 8, dtype=torch.float64)
    step = torch.tensor([0.01, 0.2, 0.05], dtype=torch.float64)
    t = step[:, None] * torch.arange(samples, dtype=torch.float64)
    with torch.no_grad():
        dense = module.latent_trajectory(y0, y_star, t)
        powers = module.latent_path(y0, y_star, step, samples)
    assert powers.shape == dense.shape == (3, samples, 8)
    assert float((powers - dense).abs().max()) <= 1e-12 * float(dense.abs().max())


@pytest.mark.parametrize("dim", [8, 16])
def test_the_factored_field_rollouts_and_loss_agree_with_the_dense_path(dim: int) -> None:
    """Eq. (C3)'s field at the data and far away, the latent rollouts of Eq. (C5) and the parameter
    gradients of both (flow, S and P), with ``factored`` on and off, after a few steps of training
    (so phi is not the identity), to 1e-9 relative; and the loss itself."""
    from lfd.bench.scaling import stacked_lasa
    from lfd.learners import normalize_demos
    from lfd.learners.contraction import _FitData

    demos = stacked_lasa(dim, n_demos=3, n_samples=200)
    config = ContractionConfig(iterations=8)
    field = lfd.train("contraction", demos, seed=0, progress=False, iterations=8)
    module = field.module.requires_grad_(True)              # a trained field's parameters are frozen
    assert module.factored
    torch.manual_seed(0)
    data = _FitData.of(normalize_demos(demos, field.norm), config, torch.float64)
    x = torch.cat([data.x_in, far_points(dim)[::7]])
    gen = torch.Generator().manual_seed(dim)
    w = torch.randn(x.shape, generator=gen, dtype=torch.float64)
    u = torch.randn(data.n0, data.n_path, dim, generator=gen, dtype=torch.float64)
    params = list(module.parameters())
    results = []
    for factored in (False, True):
        module.factored = factored
        f, y, y_star, jac = module.velocity_and_latent(x)
        assert (jac is None) == factored
        y0 = y[data.nv:data.nv + data.n0]
        if factored:
            path = module.latent_path(y0, y_star, data.tk[:, 1], data.n_path)
        else:
            path = module.latent_trajectory(y0, y_star, data.tk)[:, :data.n_path]
        grads = torch.autograd.grad((f * w).sum() + (path * u).sum(), params)
        loss = float(data.loss(module, config).detach())
        results.append((f.detach(), path.detach(), grads, loss))
    module.factored = True
    (f0, p0, g0, l0), (f1, p1, g1, l1) = results
    assert float((f1 - f0).abs().max()) <= 1e-9 * float(f0.abs().max())
    assert float((p1 - p0).abs().max()) <= 1e-9 * float(p0.abs().max())
    for a, b in zip(g0, g1):
        assert float((b - a).abs().max()) <= 1e-9 * max(float(a.abs().max()), 1e-300)
    # the loss's direction term divides by |f|, which is tiny at demo points near the goal, so rounding
    # alone moves the loss far more than the field (the dense path with and without gradients differs
    # by as much): a looser tolerance
    assert abs(l1 - l0) <= 1e-6 * abs(l0)


def test_training_in_large_dimensions_is_deterministic_for_a_seed() -> None:
    from lfd.bench.scaling import stacked_lasa

    demos = stacked_lasa(8, n_demos=3, n_samples=200)
    a, b = (lfd.train("contraction", demos, seed=3, progress=False, iterations=10) for _ in range(2))
    assert a.module.factored
    sa, sb = a.module.state_dict(), b.module.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a.history["loss"] == b.history["loss"]


# ---------------------------------------------------------------- the cache of the scaled parameters

def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k].detach(), b[k].detach()) for k in a)


def test_scaled_parameters_are_cached_without_gradients_and_invalidated_by_changes() -> None:
    flow = random_flow(4, seed=5, scale=1.0)
    x = torch.randn(30, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    with torch.no_grad():
        first = flow.scaled()
        assert flow.scaled()["w2"] is first["w2"]                 # cached
        y_cached, jac_cached = flow.forward_with_jacobian(x)
        flow.clear_cache()
        assert _same(flow.scaled(), first)                         # computed again: the same bits
        assert flow.scaled()["w2"] is not first["w2"]
        y_again, jac_again = flow.forward_with_jacobian(x)
        assert jac_cached is not None and jac_again is not None
        assert torch.equal(y_again, y_cached) and torch.equal(jac_again, jac_cached)
    # gradients needed: computed on every call (eigvalsh then also finds eigenvectors, so the last bits
    # may differ from the gradient-free values)
    live = flow.scaled()
    assert live["w2"] is not first["w2"] and live["w2"].requires_grad and live["w2"] is not flow.scaled()["w2"]
    assert all(torch.allclose(live[k].detach(), first[k], rtol=1e-12, atol=0) for k in first)
    y_live, jac_live = flow.forward_with_jacobian(x)
    assert jac_live is not None
    assert torch.allclose(y_live.detach(), y_cached, rtol=1e-12, atol=1e-14)
    assert torch.allclose(jac_live.detach(), jac_cached, rtol=1e-12, atol=1e-14)
    before = {k: v.clone() for k, v in flow.state_dict().items()}

    # an optimiser step invalidates it
    opt = torch.optim.SGD(flow.parameters(), lr=0.05)
    opt.zero_grad()
    (y_live ** 2).sum().backward()
    opt.step()
    with torch.no_grad():
        stepped = flow.scaled()
        assert not _same(stepped, first)
        assert _same(stepped, flow._scaled())
        assert flow.scaled()["w2"] is stepped["w2"]

    # so does load_state_dict
    flow.load_state_dict(before)
    with torch.no_grad():
        restored = flow.scaled()
        assert restored["w2"] is not stepped["w2"]
        assert _same(restored, first)
        y_back, _ = flow.forward_with_jacobian(x)
    assert torch.equal(y_back, y_cached)

    # and so do an in-place write, a dtype conversion and clear_cache
    with torch.no_grad():
        flow.theta.mul_(0.5)
        assert _same(flow.scaled(), flow._scaled()) and not _same(flow.scaled(), first)
        flow.float()
        assert flow.scaled()["w2"].dtype == torch.float32
        cached = flow.scaled()
        flow.clear_cache()
        assert flow.scaled()["w2"] is not cached["w2"]


def test_a_trained_model_gives_the_same_field_with_and_without_the_cache(weak: ContractionField) -> None:
    module = weak.module
    x = torch.tensor(weak.norm.to_norm(np.random.default_rng(0).normal(size=(50, 2)) * 30.0))
    with torch.no_grad():
        module.flow.clear_cache()
        fresh = module(x)
        assert "_scaled_cache" in module.flow.__dict__
        cached = module(x)
        params = module.flow._scaled()
    assert torch.equal(cached, fresh)
    assert _same(module.flow.scaled(), params)    # frozen parameters need no gradient: cached
