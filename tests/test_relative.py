"""Each demo learned relative to its own end (Eqs. (R1)-(R2)), the path-matched reference (Eq. (T1c)),
demos that end apart, and the guarantees for goals far from the demos' mean end."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import lfd
from lfd.certify import certify
from lfd.cli import main
from lfd.demos import DemoSet, lasa, save_file
from lfd.demos.relative import end_spread, relative_to_ends
from lfd.learners import LEARNERS, get_learner
from lfd.learners.tracking import check_tracking_contraction
from lfd.learners.tracking_reference import learn_reference
from lfd.pose import PoseChart
from lfd.rotations import geodesic_angle, quaternion_matrices

pytestmark = pytest.mark.usefixtures("one_thread")

SPREAD = 0.3          # ends spread up to this fraction of the extent
FAST = {"iterations": 20}   # a learner with iterations trains briefly: its guarantees do not depend on it


def spread_lasa(seed: int = 0) -> DemoSet:
    """LASA Angle with each demo translated by a seeded offset of up to ``SPREAD`` of the extent (mm)."""
    d = lasa("Angle")
    rng = np.random.default_rng(seed)
    ang, rad = rng.uniform(0, 2 * np.pi, d.n_demos), SPREAD * d.extent * np.sqrt(rng.uniform(0, 1, d.n_demos))
    off = rad[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    return DemoSet(d.t, d.x + off[:, None, :], name="lasa:Angle spread")


def spread_poses(seed: int = 0) -> DemoSet:
    """Five pose demos (metres, 4 s): a conical spiral turning 60 degrees about a tilted axis onto its
    final orientation; each demo translated by up to ``SPREAD`` of the extent and ending at an
    orientation turned by up to 25 degrees from the others'."""
    rng = np.random.default_rng(seed)
    base = lfd.spiral3d(n_demos=5, n_samples=150, radius=0.2, height=0.2, duration=4.0, noise=0.0, seed=seed)
    s = np.linspace(1.0, 0.0, base.n_samples)
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    x, q = [], []
    for xi in base.x:
        end = Rotation.from_rotvec(np.radians(25.0) * rng.uniform(-1, 1, 3) / np.sqrt(3))
        rot = end * Rotation.from_rotvec(np.radians(60.0) * s[:, None] * axis)
        x.append(xi + SPREAD * base.extent * rng.uniform(-1, 1, 3) / np.sqrt(3))
        q.append(rot.as_quat(scalar_first=True))
    return DemoSet(base.t, np.stack(x), q=np.stack(q), name="spread poses")


# ---------------------------------------------------------------- Eqs. (R1)-(R2)

def test_relative_demos_end_at_the_goal_and_keep_their_motion_seen_from_their_end() -> None:
    """(R1): every demo ends at the mean end, x_i - x_i(T) kept; (R2): every demo ends at the mean final
    orientation, R_i(T)^T R_i(t) kept (left multiplication), so the chart at the goal (Eq. (P1)) holds
    the chart points of each demo's own end's chart."""
    d = spread_poses()
    assert end_spread(d)[0] > 0.1 and end_spread(d)[1] > 5.0
    r = relative_to_ends(d)
    assert end_spread(r)[0] < 1e-12 and end_spread(r)[1] < 1e-6
    assert np.allclose(r.goal, d.goal, atol=1e-12)
    assert np.degrees(geodesic_angle(quaternion_matrices(r.goal_q), quaternion_matrices(d.goal_q))) < 1e-6
    assert np.allclose(r.x - r.ends[:, None], d.x - d.ends[:, None], atol=1e-12)
    for i in range(d.n_demos):
        own = PoseChart.at(d.q[i, -1]).to_chart(d.x[i], d.q[i])
        learned = PoseChart.of(r).to_chart(r.x[i], r.q[i])
        assert np.allclose(own[:, 3:], learned[:, 3:], atol=1e-9)
    q = relative_to_ends(lasa("Angle"), goal=np.array([10.0, -5.0]))
    assert np.allclose(q.ends, [10.0, -5.0], atol=1e-12)


# ---------------------------------------------------------------- Eq. (T1c)

def test_path_matching_averages_time_warped_copies_of_one_path_onto_that_path() -> None:
    """Demos tracing one path at different paces: the path-matched reference (Eq. (T1c)) lies on the
    path and is timed by the mean pace; the time-matched mean (Eq. (T1)) cuts the corners."""
    t = np.linspace(0.0, 2.0, 400)
    theta = np.linspace(0.0, 1.0, 2001)
    path = np.stack([np.cos(3 * np.pi * theta), np.sin(3 * np.pi * theta)], 1) * (1 - theta)[:, None]
    xs = []
    for p in (0.6, 1.0, 1.7):
        u = (t / t[-1]) ** p
        xs.append(np.stack([np.interp(u, theta, path[:, j]) for j in range(2)], 1))
    demos = DemoSet(t, np.stack(xs))
    dist = {}
    for align in ("time", "path"):
        tab = learn_reference(demos, 40, 512, False, 0.02, False, align)
        dist[align] = float(np.max(np.min(np.linalg.norm(tab.ref[:, None] - path[None], axis=-1), axis=1)))
        assert np.allclose(tab.ref[[0, -1]], [path[0], path[-1]], atol=1e-3)
    assert dist["path"] < 0.01 < 0.1 < dist["time"]


# ---------------------------------------------------------------- demos that end apart

def fast_options(learner: str) -> dict[str, int]:
    return dict(FAST) if "iterations" in get_learner(learner).Config.__dataclass_fields__ else {}


@pytest.mark.parametrize("learner", LEARNERS)
@pytest.mark.parametrize("poses", [False, True], ids=["positions", "poses"])
def test_every_learner_trains_on_demos_that_end_apart(learner: str, poses: bool) -> None:
    demos = spread_poses() if poses else spread_lasa()
    field = lfd.train(learner, demos, **fast_options(learner))
    assert np.isfinite(field(np.zeros(field.dim))).all()
    assert np.allclose(field.goal[:demos.dim], demos.goal)


@pytest.mark.parametrize("learner", ["tracking", "contraction"])
def test_held_out_runs_end_at_their_own_goal_within_1_mm(learner: str) -> None:
    """Leave one demo out of the spread LASA set (mm): the field run toward that demo's own end from its
    start ends within 1 mm of it."""
    d = spread_lasa()
    for i in (0, 3):
        field = lfd.train(learner, d.subset([j for j in range(d.n_demos) if j != i]), **fast_options(learner))
        moved = field.toward(d.ends[i])
        x, _ = moved.trajectory(d.x[i, 0], np.linspace(0.0, 12.0, 1201))
        assert np.linalg.norm(x[-1] - d.ends[i]) <= 1.0


@pytest.mark.parametrize("learner", ["tracking", "contraction"])
def test_held_out_pose_runs_end_at_their_own_pose_within_1_mm_and_1_degree(learner: str) -> None:
    d = spread_poses()
    i = 2
    field = lfd.train(learner, d.subset([j for j in range(d.n_demos) if j != i]), **fast_options(learner))
    moved = field.toward(np.concatenate([d.ends[i], d.end_q[i]]))
    start = moved.chart.point_of(d.x[i, 0], d.q[i, 0])
    z, _ = moved.trajectory(start, np.linspace(0.0, 16.0, 1601))
    assert np.linalg.norm(z[-1, :3] - d.ends[i]) <= 1e-3
    assert np.degrees(moved.chart.angle_to_goal(z[-1])) <= 1.0


# ---------------------------------------------------------------- guarantees for any goal

FAR = np.array([400.0, -250.0])   # mm: eight extents from the demos' mean end


@pytest.fixture(scope="module")
def angle_fields() -> dict[str, lfd.VelocityField]:
    d = lasa("Angle")
    return {"contraction": lfd.train("contraction", d, iterations=20), "tracking": lfd.train("tracking", d)}


def test_the_contraction_certificate_holds_for_a_far_goal(angle_fields: dict[str, lfd.VelocityField]) -> None:
    """Eq. (K1) on the box moved with the goal (``toward`` moves the demo box), at the field's own rate."""
    cert = certify(angle_fields["contraction"].toward(FAR), samples=400, equilibria=False)
    assert cert.certified and cert.worst <= cert.bound + cert.slack
    assert np.all(np.asarray(cert.box[0]) > FAR - 200.0) and np.all(np.asarray(cert.box[1]) < FAR + 200.0)


def test_tracking_convergence_holds_for_a_far_goal(angle_fields: dict[str, lfd.VelocityField]) -> None:
    r = check_tracking_contraction(angle_fields["tracking"].toward(FAR), n_points=2000, n_starts=8, steps=300)
    assert r["certified"] and r["worst_error_excess"] <= 1e-5
    assert abs(r["worst_eig"] + angle_fields["tracking"].rate) <= 1e-6


def test_pose_contraction_holds_for_a_turned_goal() -> None:
    field = lfd.train("contraction", spread_poses(), iterations=20)
    goal = np.concatenate([[0.5, -0.3, 0.2], Rotation.from_rotvec([0.0, 1.5, 0.5]).as_quat(scalar_first=True)])
    cert = certify(field.toward(goal), samples=1000, equilibria=False, pose_pairs=8)
    assert cert.certified


# ---------------------------------------------------------------- the commands take a goal

@pytest.fixture(scope="module")
def angle_files(tmp_path_factory: pytest.TempPathFactory, angle_fields: dict[str, lfd.VelocityField]
                ) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("relative")
    angle_fields["tracking"].save(root / "t.pt")
    d = lasa("Angle").subset([0, 4])
    d = DemoSet(d.t[:, ::10], d.x[:, ::10])                   # 100 samples: quick rollouts
    save_file(d, root / "here.npz")
    save_file(DemoSet(d.t, d.x + FAR), root / "far.npz")     # the same demos, moved to end at the far goal
    return {"model": root / "t.pt", "here": root / "here.npz", "far": root / "far.npz", "root": root}


def test_certify_eval_and_plot_take_a_goal(angle_files: dict[str, Path]) -> None:
    """The model run toward a far goal: certified (exit 0), and it scores the demos moved there as it
    scores them at home."""
    model, here, far, root = (str(angle_files[k]) for k in ("model", "here", "far", "root"))
    goal = f"--goal={FAR[0]:g},{FAR[1]:g}"
    assert main(["certify", model, goal, "--samples", "400", "--no-equilibria"]) == 0
    scores = {}
    for name, demos, extra in (("here", here, []), ("far", far, [goal])):
        out = Path(root) / f"{name}.json"
        assert main(["eval", model, "--demos", demos, *extra, "--json", str(out)]) == 0
        scores[name] = json.loads(out.read_text())
    assert scores["far"]["goal"] == list(FAR) and scores["here"]["goal"] is None
    for metric in ("rmse", "dtw", "frechet"):
        assert scores["far"]["mean"][metric] == pytest.approx(scores["here"]["mean"][metric], rel=1e-5)
    assert main(["plot", model, "--demos", far, goal, "--perturbed", "0", "--no-equilibria",
                 "--out", str(Path(root) / "far.png")]) == 0
    assert (Path(root) / "far.png").stat().st_size > 0


@pytest.mark.parametrize("goal", ["1,2,3", "nan,1", "a,b"])
def test_a_bad_goal_is_one_line_and_exit_2(angle_files: dict[str, Path], goal: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(angle_files["model"]), "--demos", "lasa:Angle", f"--goal={goal}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "goal" in err[0]
