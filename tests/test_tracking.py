"""The tracking learner: convergence onto the reference in phase (Eq. (T5)), phase stopping,
imitation accuracy, model files, the CLI and the numerical contraction check."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from reference_kernels import nearest_point_reference, phase_point_reference

import lfd
from lfd.cli import main
from lfd.demos import save_file
from lfd.errors import ConfigError
from lfd.evaluation import reproduce
from lfd.learners.tracking import PHASE_END, TrackingConfig, TrackingField, check_tracking_contraction
from lfd.metrics import rmse

pytestmark = pytest.mark.usefixtures("one_thread")

NODE_RMSE_SPIRAL = 0.0174   # the NODE's RMSE on lfd.spiral() from the demo starts (reports/comparison.md)


@pytest.fixture(scope="module")
def fields(spiral: lfd.DemoSet) -> dict[str, TrackingField]:
    out = {f"K={k:g}": lfd.train("tracking", spiral, rate=k) for k in (0.5, 3.0)}   # start-conditioned
    out["mean"] = lfd.train("tracking", spiral, rate=3.0, condition_start=False)
    return out  # type: ignore[return-value]


def time_to_path(traj: np.ndarray, t: np.ndarray, path: np.ndarray, tol: float) -> float:
    """First time after which every trajectory, shape (B, T, d), stays within tol of the polyline
    ``path`` (P, d) (distance to its nearest vertex; the path is dense)."""
    dist = np.linalg.norm(traj[:, :, None, :] - path[None, None], axis=-1).min(-1).max(0)   # (T,)
    outside = np.nonzero(dist > tol)[0]
    return 0.0 if len(outside) == 0 else float(t[min(outside[-1] + 1, len(t) - 1)])


def test_five_starts_converge_faster_at_a_higher_rate(spiral: lfd.DemoSet,
                                                      fields: dict[str, TrackingField]) -> None:
    """The convergence target: 5 starts within 10% of the extent around the true spiral's start reach
    5% of the extent of the true path within 1 s (K = 3) and 5 s (K = 0.5), strong strictly first."""
    true = lfd.spiral(n_demos=1, start_spread=0.0, noise=0.0, n_samples=2000).x[0]
    extent = spiral.extent
    rng = np.random.default_rng(0)
    ang, rad = rng.uniform(0, 2 * np.pi, 5), 0.1 * extent * np.sqrt(rng.uniform(0, 1, 5))
    starts = true[0] + rad[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    t = np.linspace(0.0, 8.0, 401)
    times = {k: time_to_path(fields[k].rollout(starts, t), t, true, 0.05 * extent) for k in ("K=0.5", "K=3")}
    assert times["K=3"] <= 1.0
    assert times["K=0.5"] <= 5.0
    assert times["K=3"] < times["K=0.5"]


def test_error_decays_exactly_at_rate_k(fields: dict[str, TrackingField]) -> None:
    """Eq. (T5): |x(t) - r(s(t))| = |x(0) - r(0)| exp(-K t) whatever the phase does."""
    f = fields["K=3"]
    x0 = np.array([[1.5, 0.5], [-0.5, -1.0]])
    t = np.linspace(0.0, 2.0, 201)
    xs, ss = f.rollout_with_phase(x0, t, substeps=2)
    e = np.stack([np.linalg.norm(x - f.reference(s, p), axis=-1) for x, s, p in zip(xs, ss, x0)])
    np.testing.assert_allclose(e, e[:, :1] * np.exp(-3.0 * t), rtol=1e-4, atol=1e-7)
    assert np.all(np.diff(ss, axis=1) >= 0) and np.all(ss <= 1.0)


def test_rollout_ends_at_the_goal_with_the_phase_at_one(fields: dict[str, TrackingField]) -> None:
    f = fields["K=0.5"]
    xs, ss = f.rollout_with_phase(np.array([[2.0, 2.0], [0.3, -0.2]]), np.linspace(0.0, 25.0, 501))
    assert np.all(np.abs(ss[:, -1] - 1.0) < 1e-9)
    assert np.linalg.norm(xs[:, -1] - f.goal, axis=-1).max() < 1e-3


def test_imitation_rmse(spiral: lfd.DemoSet, fields: dict[str, TrackingField]) -> None:
    """From the demo starts: the start-conditioned reference (Eq. (T2), the default) beats the NODE's
    RMSE at K = 3 (reports/comparison.md); the mean reference cannot go below the demos'
    spread around their mean (its floor)."""
    r = {k: np.mean([rmse(y, x) for y, x in zip(reproduce(f, spiral), spiral.x)]) for k, f in fields.items()}
    assert r["K=3"] <= NODE_RMSE_SPIRAL
    floor = np.mean(np.sqrt(np.mean(np.sum((spiral.x - spiral.x.mean(0)) ** 2, -1), 1)))
    assert floor * 0.9 <= r["mean"] <= floor * 1.3


def test_start_offset_is_clamped_outside_the_demos_spread(spiral: lfd.DemoSet,
                                                           fields: dict[str, TrackingField]) -> None:
    """Eq. (T2a): every demo start keeps its own offset; a start far out is pulled onto the
    ellipsoid |delta|_P = rho, whatever its distance; a file without P (older) never clamps."""
    f = fields["K=3"]
    mod = f.module
    r0 = mod.ref[0].numpy()
    raw = f.norm.to_norm(spiral.x[:, 0]) - r0
    np.testing.assert_allclose(f.start_offset(spiral.x[:, 0]), raw, rtol=1e-12, atol=1e-15)
    far = f.norm.from_norm(r0 + np.array([[0.5, 0.0], [0.0, -3.0], [40.0, 40.0]]))
    d = f.start_offset(far)
    prec = mod.start_precision.numpy()
    np.testing.assert_allclose(np.sqrt(np.einsum("bi,ij,bj->b", d, prec, d)), mod.start_radius, rtol=1e-9)
    raw_far = f.norm.to_norm(far) - r0
    cos = (d * raw_far).sum(1) / np.linalg.norm(d, axis=1) / np.linalg.norm(raw_far, axis=1)
    np.testing.assert_allclose(cos, 1.0, rtol=1e-12)                     # same direction, shorter
    state = {k: v for k, v in mod.state_dict().items() if k != "start_precision"}
    old = type(mod)(f.dim, TrackingConfig(**f.config))
    old.double().load_state_dict(state)
    assert float(old.start_precision.abs().max()) == 0.0
    np.testing.assert_allclose(old.clamp_offset(raw_far), raw_far)


def test_phase_waits_while_the_arm_is_held(fields: dict[str, TrackingField]) -> None:
    """Held at the start for 1 s the phase advances less than a quarter of what it does free
    (0.2 of the motion; the reference waits near the held arm)."""
    f = fields["K=3"]
    step = f.phase_point_fn()
    x, dt = f.reference(0.0)[0], 0.002
    s_held = f.initial_phase()
    for _ in range(500):
        s_held += step(x, s_held)[1] * dt
    free = 1.0 / f.duration
    assert s_held < 0.25 * free
    # released, it moves on along the path again
    xs, _ = f.rollout_with_phase(x, np.linspace(0.0, 1.0, 101))
    assert np.linalg.norm(xs[-1] - x) > 0.5


def test_phase_point_fn_agrees_with_velocity(spiral: lfd.DemoSet, fields: dict[str, TrackingField]) -> None:
    for f in fields.values():
        x0 = spiral.x[1, 0]
        fn = f.phase_point_fn(x0)
        for x, s in zip(spiral.x[1, ::37], np.linspace(0.0, 1.0, 6)):
            v, sd = fn(x, float(s))
            v2, sd2 = f.velocity(x, s, x0=x0)
            np.testing.assert_allclose(v, v2, rtol=1e-10, atol=1e-12)
            assert abs(sd - sd2) < 1e-12
        np.testing.assert_allclose(f.single_point_evaluator()(x0), f(x0), rtol=1e-9, atol=1e-12)


def _numpy_twin(f: TrackingField, x0: np.ndarray | None, clock_weight=None):
    """The numpy (x, s) -> (dx/dt, ds/dt) of Eqs. (T3)-(T4b) on the same tables as ``phase_point_fn(x0)``
    (tests/reference_kernels.py)."""
    mod = f.module
    ref, dref = mod.ref.numpy().copy(), mod.dref.numpy().copy()
    delta = None if x0 is None else f.start_offset(x0)
    if delta is not None:
        ref, dref = ref + mod.gain.numpy() @ delta[0], dref + mod.dgain.numpy() @ delta[0]
    return phase_point_reference(ref, dref, f.norm.goal, float(f.norm.scale), mod.rate, mod.eps ** 2,
                                 1.0 / float(mod.duration), mod.phase_stop, PHASE_END, clock_weight)


@pytest.mark.parametrize("dim", [2, 3, 6])
def test_compiled_point_paths_equal_their_numpy_twins(spiral: lfd.DemoSet, dim: int) -> None:
    """The compiled (x, s) -> (dx/dt, ds/dt) (``phase_point_fn``, the runner's call) and autonomous
    view (``field(x)``, the nearest tabulated phase) against the numpy versions, to 1e-12, at points
    on and off the demos, phases outside [0, 1] included; every variant of Eq. (T4), and Eq. (T4b)
    with a clock weight that varies with x."""
    demos = spiral if dim == 2 else lfd.spiral3d() if dim == 3 else lfd.DemoSet(
        spiral.t, np.concatenate([spiral.x, 0.5 * spiral.x[..., ::-1], spiral.x ** 2], -1))
    rng = np.random.default_rng(dim)
    pts = demos.x.reshape(-1, dim)[::23]
    pts = np.concatenate([pts, pts + 0.2 * demos.extent * rng.normal(size=pts.shape)])
    def clock(x: np.ndarray) -> float:
        return float(0.5 + 0.5 * np.tanh(x[0] - demos.goal[0]))

    for options in ({}, {"condition_start": False}, {"phase_stop": False}):
        f = lfd.train("tracking", demos, **options)
        for x0, weight in ((demos.x[1, 0], None), (None, None), (demos.x[1, 0], clock)):
            fn, twin = f.phase_point_fn(x0, weight), _numpy_twin(f, x0 if f.conditioned else None, weight)
            for x in pts:
                for s in (0.0, float(rng.uniform()), 0.995, 1.0, 1.3, -0.1):
                    v, sd = fn(x, s)
                    v2, sd2 = twin(x, s)
                    np.testing.assert_allclose(v, v2, rtol=1e-12, atol=1e-12)
                    assert abs(sd - sd2) <= 1e-12
        mod = f.module
        auto = f.single_point_evaluator()
        twin_n = nearest_point_reference(mod.ref.numpy().copy(), mod.dref.numpy().copy(), mod.rate, mod.eps ** 2,
                                         1.0 / f.duration, mod.phase_stop, PHASE_END)
        for x in pts:
            want = twin_n((x - f.norm.goal) / f.norm.scale) * f.norm.scale
            np.testing.assert_allclose(auto(x), want, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(f(x), want, rtol=1e-12, atol=1e-12)
        runner = f.runner(demos.x[0, 0], 0.002)
        np.testing.assert_allclose(runner(pts[3], 0.0), f.phase_point_fn(demos.x[0, 0])(pts[3], 0.0)[0], rtol=1e-15)
    with pytest.raises(ValueError, match="dimension"):
        f.phase_point_fn()(np.zeros(dim + 1), 0.2)
    with pytest.raises(ValueError, match="dimension"):
        f.single_point_evaluator()(np.zeros(dim + 1))


def test_clock_weight_blends_the_phase_stopping_toward_the_clock(spiral: lfd.DemoSet,
                                                                 fields: dict[str, TrackingField]) -> None:
    """Eq. (T4b): omega = 0 is Eq. (T4) to round-off, omega = 1 runs the phase at the clock c(s) / T
    however far the tool is from the reference, and Eq. (T3) takes the blended rate."""
    f = fields["K=3"]
    x0 = spiral.x[0, 0]
    plain, zero, one = (f.phase_point_fn(x0), f.phase_point_fn(x0, clock_weight=lambda x: 0.0),
                        f.phase_point_fn(x0, clock_weight=lambda x: 1.0))
    far = x0 + 0.5 * spiral.extent                     # h of Eq. (T4) far below 1
    for s in (0.1, 0.3, 0.995):
        v, sd = plain(far, s)
        v0, sd0 = zero(far, s)
        v1, sd1 = one(far, s)
        assert abs(sd0 - sd) <= 1e-15 and np.allclose(v0, v, rtol=1e-12, atol=1e-15)
        assert sd < 0.5 * sd1
        assert abs(sd1 - min(1.0, (1.0 - s) / 0.01) / f.duration) < 1e-12
        h = 1e-5   # Eq. (T3): only s_dot r'(s) changes, r' by central differences of r(s | x0)
        dr = (f.reference(np.array([s + h]), x0)[0] - f.reference(np.array([s - h]), x0)[0]) / (2.0 * h)
        np.testing.assert_allclose(v1 - v, (sd1 - sd) * dr, rtol=1e-4, atol=1e-9)


def test_certificate_constants_and_check(fields: dict[str, TrackingField]) -> None:
    f = fields["K=3"]
    assert f.rate == 3.0 and f.metric_bounds == (1.0, 1.0) and f.condition_bound <= 10.0
    assert 3.0 < f.lipschitz_bound < 100.0 and "exp(-K t)" in f.contraction_property
    out = check_tracking_contraction(f, n_points=500, n_starts=6, horizon=2.0, steps=200)
    assert out["certified"] and out["condition_number"] == 1.0
    assert abs(out["worst_eig"] + 3.0) < 1e-9
    assert out["worst_error_excess"] < 1e-5


def test_save_load_round_trip_and_determinism(tmp_path: Path, spiral: lfd.DemoSet,
                                              fields: dict[str, TrackingField]) -> None:
    f = fields["K=3"]
    f.save(tmp_path / "m.pt")
    g = lfd.load(str(tmp_path / "m.pt"))
    assert isinstance(g, TrackingField) and g.config == f.config
    t = np.linspace(0.0, 5.0, 101)
    np.testing.assert_allclose(g.rollout(spiral.x[:, 0], t), f.rollout(spiral.x[:, 0], t), atol=1e-10)
    again = lfd.train("tracking", spiral, rate=3.0, seed=5)
    np.testing.assert_allclose(again.module.ref.numpy(), f.module.ref.numpy(), atol=1e-12)


def test_three_d(fields: dict[str, TrackingField]) -> None:
    demos = lfd.spiral3d()
    f = lfd.train("tracking", demos, rate=3.0)
    ys = reproduce(f, demos)
    assert ys.shape == demos.x.shape
    assert np.linalg.norm(ys[:, -1] - demos.goal, axis=-1).max() < 0.02
    assert check_tracking_contraction(f, n_points=200, n_starts=4, horizon=1.0, steps=100)["certified"]


@pytest.mark.parametrize("options", [{"rate": -1.0}, {"rate": 0}, {"knots": 0}, {"table": 4},
                                     {"phase_stop": "yes"}, {"phase_tolerance": float("nan")},
                                     {"gain": 3.0}])
def test_bad_config(spiral: lfd.DemoSet, options: dict) -> None:
    with pytest.raises(ConfigError):
        lfd.train("tracking", spiral, **options)


def test_cli_train_eval_plot(tmp_path: Path) -> None:
    save_file(lfd.spiral(n_demos=3, n_samples=50), tmp_path / "d.npz")
    model, demos = str(tmp_path / "m.pt"), str(tmp_path / "d.npz")
    assert main(["train", "--learner", "tracking", "--rate", "2", "--demos", demos, "--out", model,
                 "--quiet"]) == 0
    assert lfd.load(model).rate == 2.0
    assert main(["eval", model, "--demos", demos, "--json", str(tmp_path / "e.json")]) == 0
    assert main(["plot", model, "--demos", demos, "--out", str(tmp_path / "p.png"), "--perturbed", "2"]) == 0
    assert (tmp_path / "p.png").stat().st_size > 1000


def test_arm_loop_carries_the_phase(fields: dict[str, TrackingField]) -> None:
    """The field's runner (what the arm's loop calls) waits while the measured tool is held, and its
    single-start trajectory (the arm's reference) agrees with the field's own rollout."""
    f = fields["K=3"]
    held = f.reference(0.0)[0]
    loop = f.runner(held, 0.002)
    for k in range(500):
        loop(held, k * 0.002)
    phases = loop.phases()
    assert phases is not None and len(phases) == 501 and phases[-1] < 0.25 * 1.0 / f.duration
    t = np.linspace(0.0, 2.0, 401)
    x0 = held + 0.05
    xs, ss = f.trajectory(x0, t)
    assert ss is not None
    xr, sr = f.rollout_with_phase(x0, t)
    np.testing.assert_allclose(xs, xr, atol=1e-6)
    np.testing.assert_allclose(ss, sr, atol=1e-8)


def test_bench_model_integrates_the_phase(spiral: lfd.DemoSet) -> None:
    """``lfd bench``'s wrapper rolls the tracking field out with its phase, on irregular grids too."""
    from lfd.bench.fields import PhaseFieldModel
    from lfd.bench.spaces import fit

    model = fit("tracking", spiral.subset([0, 1]), 0, {"rate": 3.0})
    assert isinstance(model, PhaseFieldModel)
    t = spiral.t[:2].copy()
    t[1] = t[1] * 1.07                                     # a second demo on another time grid
    demos = lfd.DemoSet(t, spiral.x[:2])
    y, _ = model.reproduce(demos.x, demos.t)
    ref = np.stack([model.field.rollout(x[0], ti - ti[0], substeps=2) for x, ti in zip(demos.x, demos.t)])
    assert np.abs(y - ref).max() < 1e-3


@pytest.mark.parametrize("step", [None, 0.013])
def test_pointwise_rollouts_are_torchdiffeqs_rk4_to_round_off(spiral: lfd.DemoSet, fields: dict[str, TrackingField],
                                                              step: float | None) -> None:
    """A few starts run point by point through the compiled field (``lfd.integrate.rk38_phase_grid``);
    many run batched through torchdiffeq: the same 3/8-rule steps, grid and cubic output
    interpolation, so the two agree to round-off, from any phase and start."""
    import torch

    from lfd import integrate

    f = fields["K=3"]
    x0 = spiral.x[:3, 0] + np.array([[0.02, -0.01], [0.0, 0.03], [-0.04, 0.0]])
    t = np.linspace(0.0, 1.2 * float(f.duration), 157)
    xs, ss = f.rollout_with_phase(x0, t, step=step, s0=np.array([0.0, 0.3, 0.9]))
    assert len(x0) <= integrate.POINTWISE_MAX
    opts = integrate.odeint_kwargs("rk4", step=step, t=t, interp=None if step is None else "cubic")
    delta = f.start_offset(x0)
    with torch.no_grad():
        xt, st = f._rollout_torch(torch.tensor(x0), torch.tensor(t), None if delta is None else torch.tensor(delta),
                                  "rk4", opts.get("options"), torch.tensor([0.0, 0.3, 0.9], dtype=torch.float64))
    size = float(np.abs(xt.numpy()).max())
    np.testing.assert_allclose(xs, xt.numpy(), rtol=0, atol=1e-11 * size)
    np.testing.assert_allclose(ss, st.numpy(), rtol=0, atol=1e-11)
    assert ss[:, -1].min() > 0.99 and np.linalg.norm(xs[:, -1] - f.goal, axis=1).max() < 0.05 * spiral.extent
