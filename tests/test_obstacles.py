"""Obstacle avoidance by modulation (lfd.obstacles) and moving goals (lfd.goal).

What the modulation preserves, checked numerically from seeded starts:
impenetrability (Gamma >= 1 along every trajectory), convergence to the goal, and no new attractor
outside the obstacles (only the saddle on a convex obstacle's far side). Unit tests use linear
stable fields (least-squares fits to the demos) so the file runs in seconds; the one check with a
trained learner is marked ``slow``.
"""

from __future__ import annotations

import numpy as np
import pytest
from known_fields import linear_field

import lfd
from lfd.errors import ConfigError
from lfd.goal import follow_goal_path, load_goal_path, parse_goal_shift, shift_goal
from lfd.obstacles import AvoidingField, Box, Capsule, Obstacle, Sphere, avoid, parse_obstacle, starts_outside

pytestmark = pytest.mark.usefixtures("one_thread")

N_STARTS = 100


def fitted_linear(demos: lfd.DemoSet) -> lfd.VelocityField:
    """f(x) = A (x - goal), A the least-squares fit to the demos' velocities, made stable
    (eigenvalues' real parts <= -0.5/s, in the demos' time scale)."""
    X = (demos.x - demos.goal).reshape(-1, demos.dim)
    V = demos.xd.reshape(-1, demos.dim)
    A = np.linalg.lstsq(X, V, rcond=None)[0].T
    worst = np.max(np.linalg.eigvals(A).real)
    rate = 3.0 / float(demos.t[0, -1])
    if worst > -rate:
        A = A - (worst + rate) * np.eye(demos.dim)
    return linear_field(A, demos.goal)


def on_path_obstacle(demos: lfd.DemoSet, fraction: float = 0.45, radius: float = 0.08,
                     field: lfd.VelocityField | None = None) -> Sphere:
    """A sphere centred on the mean demo at ``fraction`` of its arc length, radius ``radius`` x
    extent; with ``field``, on the field's own path from the mean demo start instead (a linear fit
    does not follow a LASA shape, so the demonstrated path would miss its trajectories)."""
    x = demos.x.mean(axis=0)
    if field is not None:
        x = field.rollout(x[0], np.linspace(0.0, 3.0 * float(demos.t[0, -1]), 600))
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    c = x[np.searchsorted(s, fraction * s[-1])]
    extent = demos.extent
    return Sphere(c, radius * extent)


def seeded_starts(field: AvoidingField, demos: lfd.DemoSet, n: int = N_STARTS, seed: int = 0) -> np.ndarray:
    """n starts: demo starts plus uniform noise of +-0.15 x extent, outside every obstacle."""
    starts = starts_outside(field, demos, n, seed)
    assert starts.shape == (n, demos.dim) and all(field.gamma(x) > 1.05 for x in starts)
    return starts


def path_length(y: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(y, axis=-2), axis=-1).sum(axis=-1)


def check_avoids_and_converges(field: AvoidingField, starts: np.ndarray, t: np.ndarray,
                               goal_tol: float) -> tuple[np.ndarray, float]:
    y = field.rollout(starts, t)
    gam = np.stack([field.gamma(y[:, j], float(tj)) for j, tj in enumerate(t)], axis=1)
    assert gam.min() >= 1.0, f"penetration: min Gamma {gam.min():.6f}"
    err = np.linalg.norm(y[:, -1] - field.goal, axis=1)
    assert np.all(err < goal_tol), f"{np.sum(err >= goal_tol)} of {len(err)} starts miss the goal (max {err.max():.3g})"
    return y, float(gam.min())


# ---------------------------------------------------------------- shapes and parsing
@pytest.mark.parametrize("text, kind, dim", [
    ("sphere:0.1,0.2,0.3", "sphere", 2), ("sphere:0,0,0,0.5", "sphere", 3),
    ("box:0,0,1,2", "box", 2), ("box:0,0,0,1,2,3", "box", 3),
    ("capsule:0,0,1,0,0.2", "capsule", 2), ("capsule:0,0,0,1,0,0,0.2", "capsule", 3),
    ("Sphere: 1, 2, 3 ;margin=0.1", "sphere", 2), ("sphere:0,0,1;velocity=0.1,0", "sphere", 2),
])
def test_parse_obstacle(text: str, kind: str, dim: int) -> None:
    o = parse_obstacle(text)
    assert (o.kind, o.dim) == (kind, dim)


@pytest.mark.parametrize("text", [
    "sphere", "cone:0,0,1", "sphere:0,0", "sphere:0,0,-1", "sphere:a,b,c", "box:0,0,0,1,-2,3",
    "capsule:0,0,1", "sphere:0,0,nan", "sphere:0,0,1;margin=-1", "sphere:0,0,1;speed=2",
    "sphere:0,0,1;velocity=1,2,3", "box:0,0,0,0,1",
])
def test_parse_obstacle_errors_are_one_line(text: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_obstacle(text)
    assert "\n" not in str(e.value) and "obstacle" in str(e.value)


def test_parse_obstacle_checks_dimension() -> None:
    with pytest.raises(ConfigError, match="3-D sphere for a 2-D field"):
        parse_obstacle("sphere:0,0,0,1", dim=2)


SHAPES = [Sphere([0.1, -0.2, 0.3], 0.4), Box([0.0, 0.1, -0.1], [0.3, 0.2, 0.5], margin=0.05),
          Capsule([0.0, 0.0, 0.0], [0.5, 0.2, -0.1], 0.15), Box([0.2, 0.1], [0.4, 0.1]),
          Capsule([0.0, 0.0], [0.3, 0.4], 0.1, margin=0.02)]


@pytest.mark.parametrize("obs", SHAPES, ids=lambda o: f"{o.kind}{o.dim}")
def test_gamma_is_one_on_the_surface_and_its_normal_is_the_gradient(obs: Obstacle) -> None:
    surface = obs.surface_points(200)
    np.testing.assert_allclose(obs.gamma(surface), 1.0, atol=1e-9)
    assert obs.gamma(obs.reference) < 1.0
    rng = np.random.default_rng(1)
    outside = surface + rng.uniform(0.05, 0.5, (200, 1)) * obs.normal(surface)
    assert np.all(obs.gamma(outside) > 1.0)
    h = 1e-6
    grad = np.stack([(obs.gamma(outside + h * e) - obs.gamma(outside - h * e)) / (2 * h)
                     for e in np.eye(obs.dim)], axis=1)
    grad /= np.linalg.norm(grad, axis=1, keepdims=True)
    assert np.min(np.sum(grad * obs.normal(outside), axis=1)) > 1 - 1e-6


def test_point_path_agrees_with_batch_path_2d_and_3d() -> None:
    rng = np.random.default_rng(2)
    for dim, obs in ((2, [Sphere([0.5, 0.3], 0.15), Box([-0.5, 0.2], [0.1, 0.2]),
                          Capsule([0.2, -0.5], [0.5, -0.6], 0.08, velocity=[0.1, 0.0])]),
                     (3, [SHAPES[0], Sphere([-0.8, 0.5, 0.0], 0.2, path=lambda t: [0.1 * np.sin(t), 0, 0]),
                          Capsule([0.9, 0.9, 0.0], [0.9, 0.9, 0.5], 0.1)])):
        A = -np.eye(dim) + 0.5 * rng.normal(size=(dim, dim)) * 0.3
        f = avoid(linear_field(A, np.full(dim, -1.5)), obs)
        pf = f.single_point_evaluator()
        X = rng.uniform(-1.2, 1.2, (300, dim))
        for t in (0.0, 0.7):
            X_ok = X[f.gamma(X, t) > 1.0]
            batch = f(X_ok, t)
            single = np.array([pf(x, t) for x in X_ok])
            np.testing.assert_allclose(single, batch, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("convergence,reactivity", [(True, 0.5), (False, 1.0), (True, 0.7)])
def test_compiled_point_modulator_equals_the_python_one(convergence: bool, reactivity: float) -> None:
    """The numba modulation (static spheres, boxes, capsules, a merged group, 2-D and 3-D, 1 to 4
    units) gives the Python closure's velocities to 1e-12, at points outside, on and inside the
    obstacles; moving obstacles keep the Python closure."""
    rng = np.random.default_rng(5)
    scenes = {2: [[Sphere([0.5, 0.3], 0.15)],
                  [Sphere([0.5, 0.3], 0.15), Box([-0.5, 0.2], [0.1, 0.2], margin=0.03)],
                  [Sphere([0.5, 0.3], 0.15), Box([0.6, 0.45], [0.1, 0.1]), Capsule([-0.4, -0.5], [0.0, -0.6], 0.08),
                   Sphere([-0.6, 0.6], 0.1)]],
              3: [[SHAPES[0], SHAPES[2]], [SHAPES[1], Sphere([0.9, 0.9, 0.6], 0.1), Capsule([-0.9, 0.9, 0.0],
                                                                                         [-0.9, 0.9, 0.5], 0.1)]]}
    for dim, cases in scenes.items():
        for obs in cases:
            A = -np.eye(dim) + 0.3 * rng.normal(size=(dim, dim)) * 0.3
            f = avoid(linear_field(A, np.full(dim, -1.5)), obs, convergence=convergence, reactivity=reactivity)
            compiled, python = f.point_modulator(), f.point_modulator(compiled=False)
            assert compiled.__code__ is not python.__code__
            X = np.concatenate([rng.uniform(-1.3, 1.3, (400, dim)),
                                np.concatenate([o.surface_points(20) for o in obs])])
            for x in X:
                v = rng.normal(size=dim)
                want = python(x, v, 0.0)
                np.testing.assert_allclose(compiled(x, v, 0.0), want, rtol=1e-12, atol=1e-12)
    moving = avoid(linear_field(-np.eye(2), np.full(2, -1.5)), [Sphere([0.5, 0.3], 0.15, velocity=[0.1, 0.0])])
    assert moving.point_modulator().__code__ is moving.point_modulator(compiled=False).__code__


# ---------------------------------------------------------------- what the modulation preserves
def test_velocity_never_points_into_the_surface_and_is_unchanged_far_away(spiral_field_2d) -> None:
    obs = Sphere([0.9, 0.1], 0.2)
    f = avoid(spiral_field_2d, [obs])
    surface = obs.surface_points(100)
    v = f(surface)
    n = obs.normal(surface)
    # on the surface Eq. (O2) has turned f fully toward the goal: b = |f| (g - x) / |g - x|
    normal_speed, nominal = np.sum(v * n, axis=1), np.sum((spiral_field_2d.goal - surface) * n, axis=1)
    tol = 1e-9 * np.max(np.linalg.norm(v, axis=1))
    inward = nominal < 0
    assert inward.sum() > 10 and np.max(np.abs(normal_speed[inward])) < tol   # tangent where b points in
    assert np.all(normal_speed[~inward] >= -tol)                             # outward where b points out
    plain = avoid(spiral_field_2d, [obs], convergence=False)(surface)       # [1]'s modulation: f itself
    inward_f = np.sum(spiral_field_2d(surface) * n, axis=1) < 0
    assert inward_f.sum() > 10 and np.max(np.abs(np.sum(plain * n, axis=1)[inward_f])) < tol
    far = np.array([[30.0, -40.0], [-50.0, 20.0]])
    np.testing.assert_allclose(f(far), spiral_field_2d(far), rtol=0.02)


def test_no_tail_effect_behind_the_obstacle() -> None:
    """Where f points away from the obstacle the radial component is left unchanged."""
    field = linear_field(-np.eye(2), np.array([0.0, 0.0]))
    obs = Sphere([1.0, 0.0], 0.3)
    f = avoid(field, [obs])
    x = np.array([[0.6, 0.05], [0.5, -0.2], [0.65, 0.3]])   # between obstacle and goal: f points away
    v, v0 = f(x), field(x)
    r = (x - obs.center) / np.linalg.norm(x - obs.center, axis=1, keepdims=True)
    n = obs.normal(x)
    a, a0 = np.sum(n * v, axis=1) / np.sum(n * r, axis=1), np.sum(n * v0, axis=1) / np.sum(n * r, axis=1)
    assert np.all(a0 > 0)
    np.testing.assert_allclose(a, a0, rtol=1e-9)


def test_no_new_attractor_only_the_saddle_behind_a_convex_obstacle() -> None:
    """f = -(x - g) with a sphere on the way: from 150 seeded starts all end at the goal; the only
    other equilibrium is the saddle on the far side (start exactly on the line, it stops on the
    surface); 1e-3 off the line it escapes. On a grid no other zero of M f exists outside."""
    goal = np.array([0.0, 0.0])
    obs = Sphere([1.0, 0.0], 0.3)
    f = avoid(linear_field(-np.eye(2), goal), [obs])
    rng = np.random.default_rng(3)
    starts = rng.uniform(-2.5, 2.5, (300, 2))
    starts = starts[f.gamma(starts) > 1.02][:150]
    t = np.linspace(0.0, 18.0, 301)
    y = f.rollout(starts, t)
    end = np.linalg.norm(y[:, -1] - goal, axis=1)
    assert np.all(end < 1e-4), f"{np.sum(end >= 1e-4)} starts end away from the goal"
    assert f.gamma(y.reshape(-1, 2)).min() >= 1.0
    saddle = f.rollout(np.array([[2.0, 0.0]]), t)[0, -1]
    assert abs(float(obs.gamma(saddle)) - 1.0) < 1e-3 and np.linalg.norm(f(saddle)) < 1e-3
    escaped = f.rollout(np.array([[2.0, 1e-3]]), t)[0, -1]
    assert np.linalg.norm(escaped - goal) < 1e-3
    gx = np.stack(np.meshgrid(np.linspace(-2.5, 2.5, 121), np.linspace(-2.5, 2.5, 121)), -1).reshape(-1, 2)
    keep = (f.gamma(gx) > 1.01) & (np.linalg.norm(gx - goal, axis=1) > 0.05)
    ratio = np.linalg.norm(f(gx[keep]), axis=1) / np.linalg.norm(gx[keep] - goal, axis=1)
    assert ratio.min() > 5e-3, f"near-zero of the modulated field outside the obstacle: {ratio.min():.2e}"


@pytest.mark.parametrize("spec", ["spiral", "lasa:Angle", "lasa:Sshape"])
def test_obstacle_on_the_demonstrated_path(spec: str) -> None:
    """100 seeded starts: 100% reach the goal, 0 penetrations; the path-length overhead is printed."""
    demos = lfd.load_demos(spec)
    field = fitted_linear(demos)
    obs = on_path_obstacle(demos, field=field)
    f = avoid(field, [obs])
    starts = seeded_starts(f, demos)
    extent = demos.extent
    t = np.linspace(0.0, 4.0 * float(demos.t[0, -1]), 401)
    y, gmin = check_avoids_and_converges(f, starts, t, goal_tol=0.01 * extent)
    nominal = field.rollout(starts, t)
    overhead = path_length(y) / path_length(nominal) - 1
    hit = np.any(obs.gamma(nominal) < 1.0, axis=1)
    assert hit.sum() >= 10, "the obstacle must lie on the nominal paths"
    print(f"{spec}: min Gamma {gmin:.4f}, {hit.sum()} nominal paths cross the obstacle, "
          f"path-length overhead mean {overhead.mean():.1%} (crossing ones {overhead[hit].mean():.1%})")


def test_two_overlapping_obstacles_are_merged_and_never_entered() -> None:
    demos = lfd.load_demos("spiral")
    field = fitted_linear(demos)
    a = on_path_obstacle(demos, 0.4, 0.06)
    b = Box(a.center + np.array([0.08, 0.05]), [0.07, 0.05])
    f = avoid(field, [a, b])
    assert len(f.units) == 1 and np.all([o.gamma(f.units[0].reference) < 1 for o in (a, b)])
    nested = avoid(avoid(field, [a]), [b])         # one modulation of both, not one inside another
    assert type(nested) is AvoidingField and nested.field is field and len(nested.units) == 1
    starts = seeded_starts(f, demos)
    np.testing.assert_allclose(nested(starts), f(starts), rtol=1e-12, atol=1e-12)
    t = np.linspace(0.0, 16.0, 321)
    y, _ = check_avoids_and_converges(f, starts, t, goal_tol=0.01)
    for o in (a, b):
        assert o.gamma(y).min() >= 1.0


def test_moving_obstacle_is_avoided_in_its_own_frame() -> None:
    """A sphere sweeping across the spiral at 0.18 units/s, on the nominal path when the robot gets
    there, plus a static one: never entered, goal reached once it left."""
    demos = lfd.load_demos("spiral")
    field = fitted_linear(demos)
    tc = 0.3 * float(demos.t[0, -1])                       # it reaches the nominal path with the robot
    meet = field.rollout(demos.x[:, 0].mean(axis=0), np.linspace(0.0, tc, 200))[-1]
    v = np.array([-0.15, 0.1])
    moving = Sphere(meet - tc * v, 0.07, velocity=v)
    f = avoid(field, [moving, on_path_obstacle(demos, 0.7, 0.04)])
    starts = seeded_starts(f, demos)
    t = np.linspace(0.0, 20.0, 401)
    y = f.rollout(starts, t)
    gam = np.array([moving.gamma(y[:, j], float(tj)) for j, tj in enumerate(t)])
    assert gam.min() >= 1.0, f"moving obstacle entered: min Gamma {gam.min():.5f}"
    assert gam.min() < 1.3, "the moving obstacle must come close to the trajectories"
    assert np.linalg.norm(y[:, -1] - f.goal, axis=1).max() < 0.01


def test_goal_inside_or_too_close_is_reported(spiral_field_2d) -> None:
    g = spiral_field_2d.goal
    with pytest.raises(ConfigError, match="goal lies inside obstacle sphere"):
        avoid(spiral_field_2d, [Sphere(g + 0.01, 0.1)])
    with pytest.raises(ConfigError, match="goal lies inside obstacle .*clearance"):
        avoid(spiral_field_2d, [Sphere(g + [0.1005, 0.0], 0.1)])
    with pytest.raises(ConfigError, match="is 3-D but the field is 2-D"):
        avoid(spiral_field_2d, [Sphere([5.0, 5.0, 5.0], 1.0)])
    with pytest.raises(ConfigError, match="3-D sphere for a 2-D field"):
        avoid(spiral_field_2d, ["sphere:5,5,5,1"])
    moved = shift_goal(spiral_field_2d, 1.0, [1.0, 0.0])
    with pytest.raises(ConfigError, match="goal lies inside"):
        avoid(moved, [Sphere(g + [1.0, 0.0], 0.2)])


# ---------------------------------------------------------------- moving goal
def test_parse_goal_shift_and_goal_path_files(tmp_path) -> None:
    t, dx = parse_goal_shift("1.5:0.1,-0.2")
    assert t == 1.5 and np.allclose(dx, [0.1, -0.2])
    for bad in ("0.1,0.2", "x:1,2", "1:1", "-1:1,2", "1:1,2,3,4", "1:nan,0"):
        with pytest.raises(ConfigError, match="bad goal shift"):
            parse_goal_shift(bad)
    csv = tmp_path / "g.csv"
    csv.write_text("t,x,y\n0,0,0\n1,0.5,0\n2,0.5,0.5\n")
    times, goals = load_goal_path(csv)
    assert goals.shape == (3, 2)
    np.savez(tmp_path / "g.npz", t=times, x=goals)
    assert np.allclose(load_goal_path(tmp_path / "g.npz")[1], goals)
    (tmp_path / "bad.csv").write_text("0,0,0\n0,1,1\n")
    for p in (tmp_path / "bad.csv", tmp_path / "missing.csv"):
        with pytest.raises(ConfigError, match="goal path"):
            load_goal_path(p)


def test_goal_shift_is_reached_without_a_velocity_spike() -> None:
    """The goal moves by 20% of the extent mid-run: reached to 1e-3 of the extent; the speed never
    exceeds the nominal peak plus |A| |dx| plus the blend's 15/8 |dx| / T, and changes smoothly."""
    demos = lfd.load_demos("spiral")
    field = fitted_linear(demos)
    extent = demos.extent
    dx = np.array([0.2 * extent, 0.0])
    moved = shift_goal(field, 2.5, dx, blend=0.5)
    t = np.linspace(0.0, 14.0, 1401)
    y = moved.rollout(demos.x[:, 0], t)
    y0 = field.rollout(demos.x[:, 0], t)
    assert np.linalg.norm(y[:, -1] - (field.goal + dx), axis=1).max() < 1e-3 * extent
    v, v0 = np.diff(y, axis=1) / np.diff(t)[:, None], np.diff(y0, axis=1) / np.diff(t)[:, None]
    speed, speed0 = np.linalg.norm(v, axis=2), np.linalg.norm(v0, axis=2)
    A = field.module.weight.numpy()
    bound = speed0.max() + 15 / 8 * np.linalg.norm(dx) / 0.5 + np.linalg.norm(A, 2) * np.linalg.norm(dx)
    assert speed.max() <= bound
    accel, accel0 = np.linalg.norm(np.diff(v, axis=1), axis=2).max(), np.linalg.norm(np.diff(v0, axis=1), axis=2).max()
    assert accel <= 5 * accel0 + 1e-9, "velocity jump at the goal shift"
    pf = moved.single_point_evaluator()
    for tt in (0.0, 2.6, 2.8, 9.0):
        np.testing.assert_allclose(pf(demos.x[0, 0], tt), moved(demos.x[:1, 0], tt)[0], rtol=1e-9)


def test_goal_path_is_followed_around_an_obstacle() -> None:
    demos = lfd.load_demos("spiral")
    field = fitted_linear(demos)
    times = np.array([0.0, 3.0, 6.0])
    goals = field.goal + np.array([[0.0, 0.0], [0.1, 0.1], [0.25, 0.0]])
    moved = follow_goal_path(field, times, goals, blend=0.5)
    obs = on_path_obstacle(demos, 0.45, 0.06)
    f = moved.avoiding([obs])
    starts = seeded_starts(f, demos, n=30)
    t = np.linspace(0.0, 16.0, 401)
    y = f.rollout(starts, t)
    assert f.gamma(y.reshape(-1, 2)).min() >= 1.0
    assert np.linalg.norm(y[:, -1] - goals[-1], axis=1).max() < 1e-3


# ---------------------------------------------------------------- a trained learner (end to end)
@pytest.mark.slow
def test_trained_contraction_field_avoids_an_obstacle_on_lasa_angle() -> None:
    """END TO END (~10-20 s): the contraction learner on LASA Angle, a sphere on the demonstrated
    path, 100 seeded starts: all reach the goal, none enters the obstacle."""
    demos = lfd.load_demos("lasa:Angle")
    field = lfd.train("contraction", demos, seed=0, iterations=100)
    f = avoid(field, [on_path_obstacle(demos)])
    starts = seeded_starts(f, demos)
    extent = demos.extent
    t = np.linspace(0.0, 4.0 * float(demos.t[0, -1]), 201)
    check_avoids_and_converges(f, starts, t, goal_tol=0.01 * extent)


# ---------------------------------------------------------------- lfd plot --obstacle
@pytest.mark.slow
def test_lfd_plot_draws_obstacles_and_rejects_bad_ones(tmp_path, capsys) -> None:
    """END TO END (the streamline grid): ``lfd plot --obstacle ... --goal-shift ...``."""
    from matplotlib.image import imread

    from lfd.cli import main
    from lfd.demos import save_file, spiral

    save_file(spiral(n_demos=2, n_samples=60, seed=1), tmp_path / "demos.npz")
    assert main(["train", "--learner", "node", "--demos", str(tmp_path / "demos.npz"), "--out",
                 str(tmp_path / "m.pt"), "--iterations", "4", "--hidden", "8,8", "--quiet"]) == 0
    common = [str(tmp_path / "m.pt"), "--demos", str(tmp_path / "demos.npz"), "--perturbed", "2"]
    assert main(["plot", *common, "--out", str(tmp_path / "p.png"), "--obstacle", "sphere:0.4,0.3,0.1",
                 "--obstacle", "box:-0.5,-0.2,0.1,0.1;margin=0.02", "--goal-shift", "1:0.05,0"]) == 0
    assert imread(tmp_path / "p.png").shape[0] > 100
    capsys.readouterr()
    for bad, msg in ((["--obstacle", "sphere:1,2"], "bad obstacle"),
                     (["--obstacle", "sphere:0,0,0.2"], "goal lies inside obstacle"),
                     (["--goal-shift", "1:1,2,3"], "goal shift")):
        assert main(["plot", *common, "--out", str(tmp_path / "q.png"), *bad]) == 2
        err = capsys.readouterr().err
        assert msg in err and err.count("\n") == 1
    assert not (tmp_path / "q.png").exists()


# ---------------------------------------------------------------- convergence kept, Eqs. (O1)-(O3)
WINDING = np.array([[-0.3, 3.0], [-3.0, -0.3]])   # a focus that turns 1.6 times per e-fold


@pytest.mark.parametrize("centre, radius", [((0.12, 0.0), 0.08), ((0.25, 0.1), 0.2)])
def test_a_winding_field_stalls_on_the_plain_modulation_and_reaches_its_goal_with_eqs_o2_o3(centre, radius) -> None:
    """An obstacle beside the goal of a fast-winding focus: [KB]'s modulation leaves every start
    stuck on the obstacle; Eqs. (O1)-(O3) bring every start within 1e-3 of the goal, none enters."""
    f = linear_field(WINDING, np.zeros(2))
    ob = Sphere(centre, radius)
    ang = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    starts = 1.2 * np.c_[np.cos(ang), np.sin(ang)]
    t = np.linspace(0.0, 30.0, 1501)
    plain = avoid(f, [ob], convergence=False).rollout(starts, t)
    assert np.all(np.linalg.norm(plain[:, -1], axis=1) > 1e-2)                # stalled on the surface
    kept = avoid(f, [ob])
    y = kept.rollout(starts, t)
    assert float(kept.gamma(y).min()) >= 1.0
    assert np.all(np.linalg.norm(y[:, -1], axis=1) < 1e-3)


def test_steering_leaves_the_field_alone_far_from_obstacles_and_fades_the_modulation_at_the_goal() -> None:
    """omega = 0 beyond half an obstacle's size (Eq. (O2)), and within r_k of the goal M = I (Eq. (O3)),
    so there x_dot = b; the goal stays an equilibrium."""
    f = linear_field(WINDING, np.zeros(2))
    ob = Sphere([0.12, 0.0], 0.08)
    a = avoid(f, [ob])
    plain = avoid(f, [ob], convergence=False)
    far = np.array([[-0.5, 0.3], [0.0, -0.6]])                                  # Gamma > 1.5
    assert np.all(ob.gamma(far) > 1.5)
    np.testing.assert_allclose(a(far), plain(far), rtol=1e-12)
    # eta = s(|x - g| / r), r = 0.5 l (Gamma(g) - 1) = 0.02: next to the goal x_dot -> b
    near = np.array([[-1e-4, 0.0], [0.0, 5e-5], [3e-5, -4e-5]])
    gam = ob.gamma(near)
    u = np.clip((1.5 - gam) / 0.5, 0, 1)
    omega = u * u * (3 - 2 * u)
    fx = f(near)
    b = (1 - omega)[:, None] * fx + (omega * np.linalg.norm(fx, axis=1))[:, None] * (
        -near / np.linalg.norm(near, axis=1)[:, None])
    np.testing.assert_allclose(a(near), b, rtol=1e-3)
    assert not np.allclose(plain(near), b, rtol=1e-2)                           # the plain modulation is not faded
    np.testing.assert_allclose(a(np.zeros(2)), 0.0, atol=1e-15)


def test_a_goal_contracting_field_gets_no_equilibrium_off_the_surfaces() -> None:
    """A field with a quadratic Lyapunov function never points straight away from its goal, so
    b != 0 and M b != 0 at every point outside the obstacle (docs/equations.md)."""
    f = linear_field(WINDING, np.zeros(2))
    ob = Sphere([0.12, 0.0], 0.08)
    a = avoid(f, [ob])
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.4, 0.4, (20000, 2))
    x = x[(ob.gamma(x) > 1.0 + 1e-6) & (np.linalg.norm(x, axis=1) > 1e-3)]
    speed = np.linalg.norm(a(x), axis=1) / np.linalg.norm(x, axis=1)
    assert speed.min() > 1e-3


def test_rollout_never_ends_a_step_inside_and_push_out_reaches_the_surface() -> None:
    f = linear_field(WINDING, np.zeros(2))
    a = avoid(f, [Sphere([0.12, 0.0], 0.08), Box([-0.2, 0.1], [0.05, 0.03])])
    inside = np.array([[0.12, 0.01], [0.1, -0.02], [-0.2, 0.1]])
    out = a.push_out(inside)
    assert np.all(a.gamma(out) >= 1.0) and np.all(a.gamma(out) < 1.0 + 1e-6)
    coarse = a.rollout(np.array([[0.6, 0.0], [-0.5, 0.4]]), np.linspace(0.0, 10.0, 41))   # 0.25 s steps
    assert float(a.gamma(coarse).min()) >= 1.0


def test_tracking_field_avoids_obstacles_and_its_phase_keeps_going() -> None:
    """The tracking learner with an obstacle on its reference: a PhasedAvoidingField, the same
    fast path as the batch path, no entry, the phase reaches 1 and every start reaches the goal."""
    from lfd.obstacles import PhasedAvoidingField

    demos = lfd.load_demos("spiral")
    field = lfd.train("tracking", demos, seed=0)
    ob = on_path_obstacle(demos, 0.5, 0.08)
    a = avoid(field, [ob])
    assert isinstance(a, PhasedAvoidingField) and a.kind is field.kind
    starts = demos.x[:, 0]
    t = np.linspace(0.0, 3.0 * float(demos.t[0, -1]), 601)
    x, s = a.rollout_with_phase(starts, t)
    assert float(a.gamma(x).min()) >= 1.0
    assert s[:, -1].min() > 0.99
    assert np.all(np.linalg.norm(x[:, -1] - field.goal, axis=1) < 1e-3 * demos.extent)
    fn = a.phase_point_fn(starts[0])
    v, sdot = fn(starts[0], 0.0)
    v0, sdot0 = field.phase_point_fn(starts[0])(starts[0], 0.0)
    assert sdot == sdot0 and np.all(np.isfinite(v))
    with pytest.raises(ConfigError, match="static obstacles"):
        avoid(field, [Sphere([0.5, 0.5], 0.1, velocity=[0.1, 0.0])])
    with pytest.raises(ConfigError, match="AvoidingField .*does not apply to the tracking learner's field"):
        AvoidingField(field, [ob])
    with pytest.raises(ConfigError, match="a moving goal .*does not apply to the tracking learner's field"):
        shift_goal(field, 1.0, [0.1, 0.0])


#: the Panda sweep's hand margin in the units of its 3-demo spiral (28.2 mm at 0.608 m per unit)
PANDA_HAND_UNITS = 0.0282 / 0.608


@pytest.mark.parametrize("scene", [12, 34])
def test_tracking_phase_keeps_its_pace_while_the_tool_detours(scene: int) -> None:
    """Eq. (T4b): two Panda-sweep scenes (obstacles on the path, grown by the hand's size) in
    which the phase of Eq. (T4) alone was still below 0.4 when the run ended, 1.5 s after the demos'
    duration T. Blended toward the clock in the band, the phase is in its last 1 % (``PHASE_END``,
    where it stops) by T + 1.25 s and the tool ends within 1e-3 of the extent of the goal by
    T + 1.5 s; no step enters an obstacle."""
    import dataclasses

    from lfd.learners.tracking import PHASE_END
    from lfd.obstacles import random_scene

    demos = lfd.spiral(n_demos=3, radius=0.13)
    field = lfd.train("tracking", demos, seed=0)
    m = PANDA_HAND_UNITS
    scene_obs = [dataclasses.replace(o, margin=o.margin + m) for o in random_scene(demos, scene, extra_margin=m)]
    a = avoid(field, scene_obs)
    T = float(demos.t[0, -1] - demos.t[0, 0])
    t = np.linspace(0.0, T + 1.5, int(200 * (T + 1.5)) + 1)
    x, s = a.rollout_with_phase(demos.x[0, 0], t)
    assert float(a.gamma(x).min()) >= 1.0
    assert float(np.interp(T + 1.25, t, s)) >= 1.0 - PHASE_END and s[-1] > 1.0 - 1e-4
    assert float(np.linalg.norm(x[-1] - a.run_goal(demos.x[0, 0]))) < 1e-3 * demos.extent
    assert float(np.linalg.norm(x[-1] - field.goal)) < 1e-3 * demos.extent
    compiled, closure = a.point_band(), a.point_band(compiled=False)      # omega of Eq. (O2), both paths
    w = np.array([compiled(p) for p in x[::20]])
    np.testing.assert_allclose(w, [closure(p) for p in x[::20]], atol=1e-12)
    assert w.max() > 0.5 and w.min() == 0.0                              # the tool went round an obstacle


def test_tracking_phase_keeps_the_demos_pace_in_mid_band() -> None:
    """Eq. (T4b) with the detour weight: GShape with a sphere on its path grown by a Panda hand's
    size (``demo_arm.py --demos lasa:GShape --obstacle sphere:-20,5,3``; reports/obstacles_arm.md).
    The tool goes round in mid-band (1 < Gamma < 1.5), where omega of Eq. (O2) is about 1/2, so
    weighting by omega would slow the phase there. With the detour weight every demo start's phase
    ends by T + 0.5 s and its tool is within 1 mm (LASA units) of the goal by then; no step enters
    the obstacle. The compiled detour weight equals the Python one and is 1 across the band."""
    from lfd.obstacles.avoidance import CONVERGENCE_BAND, DETOUR_HOLD

    demos = lfd.load_demos("lasa:GShape")
    field = lfd.train("tracking", demos, seed=0)
    a = avoid(field, parse_obstacle("sphere:-20,5,3;margin=10.04", 2))
    T = float(field.duration)
    t = np.linspace(0.0, T + 0.5, int(100 * (T + 0.5)) + 1)
    x, s = a.rollout_with_phase(demos.x[:, 0], t)
    assert float(a.gamma(x.reshape(-1, 2)).min()) >= 1.0
    assert float(a.gamma(x.reshape(-1, 2)).min()) < 1.0 + CONVERGENCE_BAND   # the detours are in the band
    assert float(s[:, -1].min()) > 1.0 - 1e-3
    assert float(np.linalg.norm(x[:, -1] - demos.goal, axis=1).max()) < 1.0
    compiled, closure = a.point_band(hold=DETOUR_HOLD), a.point_band(compiled=False, hold=DETOUR_HOLD)
    pts = x[:, ::25].reshape(-1, 2)
    w = np.array([compiled(p) for p in pts])
    np.testing.assert_allclose(w, [closure(p) for p in pts], atol=1e-12)
    band = a.gamma(pts) <= 1.0 + CONVERGENCE_BAND
    assert band.any() and np.all(w[band] == 1.0) and w.min() == 0.0


def test_phased_field_steers_toward_its_runs_end() -> None:
    """Demos that end apart are learned relative to their own ends, so every run of the tracking
    field ends at the goal it is given (here one moved off the mean end, ``toward``): Eqs. (O2)-(O3)
    take r(1 | x0) as the goal of that run, so with an obstacle beside that end the run still stops
    there; a goal inside an obstacle is refused."""
    base = lfd.spiral(n_demos=3, radius=0.13)
    u = np.clip((base.t - base.t[:, :1]) / (base.t[:, -1:] - base.t[:, :1]), 0.0, 1.0)[..., None]
    ends = np.array([[0.01, 0.0], [0.0, 0.0], [-0.01, 0.0]])    # within the demos' end tolerance
    demos = lfd.DemoSet(t=base.t, x=base.x + u ** 3 * ends[:, None, :], name="spread-ends")
    trained = lfd.train("tracking", demos, seed=0)
    x0 = demos.x[0, 0]
    assert float(np.linalg.norm(trained.reference(np.array([1.0]), x0)[0] - trained.goal)) < 1e-9
    off = np.array([0.006, 0.002])
    field = trained.toward(trained.goal + off)
    end = field.reference(np.array([1.0]), x0)[0]
    np.testing.assert_allclose(end, trained.goal + off, atol=1e-9)
    side = np.array([-off[1], off[0]]) / np.linalg.norm(off)
    ob = Sphere(end + 0.014 * side, 0.01)                      # Gamma(end) = 1.4: omega > 0 there
    a = avoid(field, [ob])
    np.testing.assert_allclose(a.run_goal(x0), end, atol=1e-12)
    fn = a.phase_point_fn(x0)
    v, sdot = fn(end, 1.0)
    assert sdot == 0.0 and float(np.linalg.norm(v)) < 1e-9
    T = float(demos.t[0, -1] - demos.t[0, 0])
    t = np.linspace(0.0, T + 1.5, int(200 * (T + 1.5)) + 1)
    x, s = a.rollout_with_phase(x0, t)
    assert float(a.gamma(x).min()) >= 1.0 and s[-1] > 1.0 - 1e-4
    assert float(np.linalg.norm(x[-1] - end)) < 1e-3 * demos.extent
    with pytest.raises(ConfigError, match="goal"):
        r = 0.4 * float(np.linalg.norm(off))                   # the mean goal outside, the run's end inside
        avoid(field, [Sphere(end + 0.5 * r * side, r)]).phase_point_fn(x0)


@pytest.mark.parametrize("name", ["spiral", "spiral3d", "lasa:Sshape"])
def test_random_scenes_are_seeded_and_keep_goal_and_starts_clear(name: str) -> None:
    from lfd.obstacles import random_scene
    from lfd.obstacles.groups import group

    demos = lfd.load_demos(name)
    for seed in range(12):
        scene = random_scene(demos, seed)
        again = random_scene(demos, seed)
        assert [o.describe() for o in scene] == [o.describe() for o in again]
        assert 1 <= len(scene) <= 3 and all(o.dim == demos.dim for o in scene)
        for u in group(scene):
            assert float(u.geometry(demos.goal[None], 0.0)[0][0]) >= 1.01
            assert float(u.geometry(demos.x[:, 0], 0.0)[0].min()) >= 1.05
        sizes = [o.size - o.margin for o in scene]
        assert max(sizes) <= 0.1 * np.sqrt(demos.dim) * 1.4 * demos.extent
    grown = random_scene(demos, 0, extra_margin=0.05 * demos.extent)
    assert all(float(o.gamma(demos.goal)) >= 1.0 for o in grown)
    with pytest.raises(ConfigError, match="1 to 16"):
        random_scene(demos, 0, count=0)
