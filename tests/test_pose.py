"""Poses: the log chart at the goal (lfd.pose), pose demo sets, and the learners on R^3 x SO(3)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

import lfd
from lfd.demos import ROBOTTASKS, DemoSet, load_file, robottasks, save_file
from lfd.errors import DemoError
from lfd.field import StateSpace
from lfd.pose import PoseChart, chart_demos, continuous, geodesic_angle, mean_quaternion, quaternion_matrices

pytestmark = pytest.mark.usefixtures("one_thread")   # torch rollouts: one thread (conftest.py)


def _random_rotations(rng: np.random.Generator, n: int, max_angle: float = np.pi) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return np.stack([pin.exp3(a * v) for a, v in zip(rng.uniform(0, max_angle, n), u)])


@pytest.fixture(scope="module")
def small_pouring() -> DemoSet:
    d = robottasks("pouring")
    return DemoSet(d.t[:3, ::4], d.x[:3, ::4], name="pouring-small", q=d.q[:3, ::4])


def test_robottasks_data_is_shipped_in_metres_and_radians() -> None:
    for task in ROBOTTASKS:
        d = robottasks(task)
        assert d.x.shape == (9, 1000, 3) and d.q.shape == (9, 1000, 4)
        assert 0.0 < float(d.x[..., 0].min()) and float(np.abs(d.x).max()) < 1.0       # metres, not cm
        assert np.allclose(np.linalg.norm(d.q, axis=-1), 1.0, atol=1e-12)
        assert np.all(np.sum(d.q[:, 1:] * d.q[:, :-1], axis=-1) >= 0)                 # continuous
        assert abs(float(d.t[0, 1] - d.t[0, 0]) - 1 / 60) < 1e-12
    with pytest.raises(DemoError, match=r"robottasks:nope: unknown task; known: bottle2shelf"):
        robottasks("nope")
    with pytest.raises(DemoError, match=r"robottasks:all: the nine tasks are nine demo sets"):
        lfd.load_demos("robottasks:all")


def test_chart_round_trip_and_the_geodesic_bound_far_from_the_goal() -> None:
    rng = np.random.default_rng(0)
    goal = _random_rotations(rng, 1)[0]
    chart = PoseChart(goal)
    rots = _random_rotations(rng, 400, np.pi - 1e-3)          # up to a hair below the antipode
    r = chart.rotation_coordinates(rots)
    assert np.allclose(chart.angle_to_goal(np.concatenate([np.zeros((400, 3)), r], 1)),
                       geodesic_angle(goal[None], rots), atol=1e-9)
    back = chart.rotations(np.concatenate([np.zeros((400, 3)), r], 1))
    assert float(np.max(geodesic_angle(back, rots))) < 1e-9
    # Eq. (P4): the geodesic angle never exceeds the chart distance / l, even for far pairs
    i, j = rng.integers(0, 400, (2, 2000))
    ang = geodesic_angle(rots[i], rots[j])
    assert np.all(ang <= np.linalg.norm(r[i] - r[j], axis=1) / chart.length + 1e-9)
    assert float(np.max(ang)) > 2.5                                                     # far pairs were drawn


def test_twist_is_the_derivative_of_the_chart_map() -> None:
    rng = np.random.default_rng(1)
    chart = PoseChart(_random_rotations(rng, 1)[0])
    for _ in range(20):
        z = np.concatenate([rng.normal(size=3), chart.length * rng.normal(size=3)])
        zd = rng.normal(size=6)
        h = 1e-7
        r1, r2 = chart.rotations(z), chart.rotations(z + h * zd)
        omega_fd = r1 @ pin.log3(r1.T @ r2) / h                                           # world axes
        tw = chart.twist(z, zd)
        assert np.allclose(tw[3:], omega_fd, atol=1e-5 * max(1.0, float(np.linalg.norm(omega_fd))))
        assert np.array_equal(tw[:3], zd[:3])


def test_karcher_mean_centres_the_chart() -> None:
    rng = np.random.default_rng(2)
    rots = np.stack([_random_rotations(rng, 1, 0.6)[0] for _ in range(9)])
    q = np.stack([pin.Quaternion(r).coeffs()[[3, 0, 1, 2]] for r in rots])
    q[::2] *= -1                                                                        # signs do not matter
    m = mean_quaternion(q)
    chart = PoseChart.at(m)
    assert float(np.linalg.norm(chart.rotation_coordinates(quaternion_matrices(q)).mean(0))) < 1e-12


def test_pose_demo_validation_messages() -> None:
    d = robottasks("scoop")
    t, x, q = d.t[:2, ::10], d.x[:2, ::10], d.q[:2, ::10].copy()
    bad = q.copy()
    bad[1, 5] *= 1.2
    with pytest.raises(DemoError, match=r"quaternion of demo 1 at sample 5 has norm 1\.2, not a rotation"):
        DemoSet(t, x, q=bad)
    near = q.copy()
    near[0, 3] *= 1.004
    assert np.allclose(np.linalg.norm(DemoSet(t, x, q=near).q, axis=-1), 1.0, atol=1e-15)   # renormalised
    nan = q.copy()
    nan[1, 2, 0] = np.nan
    with pytest.raises(DemoError, match=r"NaN or inf in the quaternions of demo 1"):
        DemoSet(t, x, q=nan)
    with pytest.raises(DemoError, match=r"quaternions have shape \(2, 100, 3\), expected \(2, 100, 4\)"):
        DemoSet(t, x, q=q[..., :3])
    flipped = q.copy()
    flipped[0, 40:] *= -1                                                                # the same orientations
    got = DemoSet(t, x, q=flipped)
    assert np.array_equal(got.q, DemoSet(t, x, q=q).q)
    assert np.array_equal(continuous(flipped[0]), q[0])
    turned = q.copy()                                     # demo 1 ends turned far from demo 0: accepted
    turned[1, -1] = [0.0, 1.0, 0.0, 0.0] if abs(q[1, -1, 1]) < 0.7 else [1.0, 0.0, 0.0, 0.0]
    apart = DemoSet(t, x, q=turned)
    assert apart.end_q is not None and np.array_equal(apart.end_q, apart.q[:, -1])
    assert float(np.degrees(geodesic_angle(*quaternion_matrices(apart.end_q)))) > 90.0
    assert np.allclose(apart.goal_q, mean_quaternion(apart.end_q), atol=1e-15)


def test_pose_files_round_trip_bit_for_bit(tmp_path) -> None:
    """Pouring demos 0, 1 and 3 (which the clean-up of a recording leaves as they are) read back bit for bit."""
    d = robottasks("pouring")
    clean = DemoSet(d.t[[0, 1, 3], ::4], d.x[[0, 1, 3], ::4], name="pouring-clean", q=d.q[[0, 1, 3], ::4])
    for name in ("d.csv", "d.npz"):
        save_file(clean, tmp_path / name)
        back = load_file(tmp_path / name)
        assert back.has_orientation and back.notes == ()
        assert np.array_equal(back.t, clean.t) and np.array_equal(back.x, clean.x)
        assert np.array_equal(back.q, clean.q)
    assert (tmp_path / "d.csv").read_text().splitlines()[0] == "demo,t,x,y,z,qw,qx,qy,qz"
    # demos of different lengths: positions linearly, orientations by slerp, on the longest length
    rows = (tmp_path / "d.csv").read_text().splitlines()
    two = [r for r in rows[1:] if r.startswith("2,")]
    keep = set(two[::2] + two[-1:])                                                     # every other sample, both ends
    short = [r for r in rows[1:] if not r.startswith("2,") or r in keep]
    (tmp_path / "u.csv").write_text("\n".join([rows[0], *short]) + "\n")
    u = load_file(tmp_path / "u.csv")
    assert u.notes == (f"{tmp_path / 'u.csv'}: demos resampled to 250 samples each, evenly in time (they had "
                       "126 to 250, at 7.5 to 15 Hz)",)
    assert u.n_samples == clean.n_samples and np.allclose(u.t[2], clean.t[2], atol=1e-12)
    ang = geodesic_angle(quaternion_matrices(u.q[2]), quaternion_matrices(clean.q[2]))
    assert float(np.max(ang[0::2])) < 1e-7                                              # at the kept samples
    rot = quaternion_matrices(u.q[2])
    prev, mid, nxt = rot[0:-3:2], rot[1:-2:2], rot[2:-1:2]          # between kept samples: on their geodesic arc
    assert np.allclose(geodesic_angle(prev, mid) + geodesic_angle(mid, nxt), geodesic_angle(prev, nxt), atol=1e-9)


def test_a_recorded_pour_read_from_a_file_loses_nothing(tmp_path, small_pouring) -> None:
    """Pouring demo 2 creeps for its last 2.6 s, below 2% of its peak speed but well outside the
    recording's noise: it is slow motion, not standing still, so read back from a file every sample
    stays, bit for bit, and nothing is noted."""
    save_file(small_pouring, tmp_path / "d.npz")
    back = load_file(tmp_path / "d.npz")
    assert back.notes == ()
    assert np.array_equal(back.t, small_pouring.t) and np.array_equal(back.x, small_pouring.x)
    assert np.array_equal(back.q, small_pouring.q)
    tail = small_pouring.t[2] >= small_pouring.t[2, -1] - 2.6
    moved = float(np.linalg.norm(small_pouring.x[2, tail][-1] - small_pouring.x[2, tail][0]))
    assert moved > 1e-4                                        # it does move at the end: > 0.1 mm


def test_bad_pose_file_is_one_line_exit_2(tmp_path, small_pouring) -> None:
    save_file(small_pouring, tmp_path / "d.csv")
    lines = (tmp_path / "d.csv").read_text().splitlines()
    parts = lines[7].split(",")
    parts[5] = repr(float(parts[5]) * 3)                                                # qw far from unit
    lines[7] = ",".join(parts)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    r = subprocess.run([sys.executable, "-m", "lfd.cli", "train", "--learner", "tracking", "--demos",
                        str(tmp_path / "bad.csv"), "--out", str(tmp_path / "m.pt")], capture_output=True, text=True)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "not a rotation" in r.stderr
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize("learner", ["tracking", "contraction"])
def test_pose_fields_converge_and_save(tmp_path, small_pouring, learner: str) -> None:
    options = {"iterations": 40} if learner == "contraction" else {}
    f = lfd.train(learner, small_pouring, seed=0, **options)
    assert f.space is StateSpace.POSE and f.dim == 6 and f.chart is not None
    zd = chart_demos(small_pouring, f.chart)
    t = np.linspace(0, 3 * float(small_pouring.t[0, -1]), 400)
    z = f.rollout_with_phase(zd.x[:, 0], t)[0] if learner == "tracking" else f.rollout(zd.x[:, 0], t)
    assert float(np.max(np.linalg.norm(z[:, -1, :3] - small_pouring.goal, axis=1))) < 1e-3
    assert float(np.max(np.degrees(f.chart.angle_to_goal(z[:, -1])))) < 1.0
    # the twist at a pose: the chart field's linear part and Eq. (P3)'s angular part
    tw = f.pose_velocity(small_pouring.x[0, 10], small_pouring.q[0, 10])
    assert tw.shape == (6,) and np.isfinite(tw).all()
    f.save(tmp_path / "m.pt")
    g = lfd.load(str(tmp_path / "m.pt"))
    assert g.chart is not None and np.array_equal(g.chart.goal_rotation, f.chart.goal_rotation)
    assert np.array_equal(g.pose_velocity(small_pouring.x[0, 10], small_pouring.q[0, 10]), tw)


def test_contraction_pose_certificate_holds_far_away(small_pouring) -> None:
    from lfd.certify import certify

    f = lfd.train("contraction", small_pouring, seed=0, iterations=30)
    cert = certify(f, samples=1000, pose_pairs=48)
    assert cert.pose is not None and cert.pose["checked"] and cert.pose["holds"]
    assert cert.pose["max_start_angle_deg"] > 179.0
    assert cert.pose["worst_ratio"] <= 1.0 and cert.pose["goal_worst_ratio"] <= 1.0
    assert cert.pose["geodesic_decay_rate"] > 0.0
    assert cert.certified, cert.proof


def test_eval_takes_pose_demos_as_chart_points(tmp_path, small_pouring) -> None:
    save_file(small_pouring, tmp_path / "d.npz")
    lfd.train("tracking", small_pouring).save(tmp_path / "m.pt")
    ok = subprocess.run([sys.executable, "-m", "lfd.cli", "eval", str(tmp_path / "m.pt"), "--demos",
                         str(tmp_path / "d.npz"), "--json", str(tmp_path / "e.json")], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / "e.json").exists()
    bad = subprocess.run([sys.executable, "-m", "lfd.cli", "eval", str(tmp_path / "m.pt"), "--demos", "spiral3d"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "trained on poses, the demos are positions" in bad.stderr


def test_contraction_trains_on_demos_in_a_subspace() -> None:
    # a 3-D path in a plane, and poses that turn about one fixed axis: X'X of Eq. (C2)'s fit is singular
    flat = lfd.spiral3d(n_demos=3, n_samples=120, height=0.0, noise=0.0)
    lfd.train("contraction", flat, seed=0, iterations=3)
    d = robottasks("scoop")
    t, x = d.t[:3, ::10], d.x[:3, ::10]
    u = np.linspace(1.0, 0.0, t.shape[1])
    axis = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    q = np.stack([np.stack([pin.Quaternion(pin.exp3(1.2 * s * axis)).coeffs()[[3, 0, 1, 2]] for s in u])] * 3)
    f = lfd.train("contraction", DemoSet(t, x, q=q), seed=0, iterations=3)
    assert all(bool(np.isfinite(p.detach().numpy()).all()) for p in f.module.parameters())
