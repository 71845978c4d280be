"""``lfd bench robottasks``: the pose suite's protocol, the Cartesian DMP baseline, the command.

One ``--quick`` run of both splits (tracking and the DMP, one task, 1 perturbed start per demo, 2
workers) is shared by the module; a second run checks that it resumes. (The contraction learner's and
the NODE's rollouts go through the same ``lfd.bench.fields`` code and ``POSES`` states as the tracking
field's; they are left out to keep the module fast on a 2-core machine.)
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bench_runs import bench_run
from scipy.spatial.distance import cdist

from lfd.bench import robottasks as rt
from lfd.bench.dmp import fit_cartesian_dmp, make_cartesian_config, mean_pose_demo
from lfd.bench.runner import run_cells
from lfd.demos import ROBOTTASKS, robottasks
from lfd.errors import ConfigError, DemoError
from lfd.metrics import dtw, dtw_path
from lfd.pose import PoseChart, geodesic_angle, quaternion_matrices

pytestmark = pytest.mark.usefixtures("one_thread")

TASK = "scoop"
LEARNERS = ("tracking", "dmp")
CELLS = [f"{learner}__{TASK}__seed0" for learner in LEARNERS]
SUITE = rt.RobotTasksSuite(rt.RobotTasksProtocol())
# a held-out reproduction's last pose from the end of the demo it was run toward (mm, degrees; just
# above what tracking and the DMP reach on scoop at --quick)
HELD_OUT_END_MM, HELD_OUT_END_DEG = 2.0, 1.0
# The Cartesian DMP against the mean demo it was fitted to, from the mean demo's start (just above
# what it scores on scoop with the library's int_dt)
DMP_MEAN_MAX_MM, DMP_MEAN_RMS_MM, DMP_MEAN_MAX_DEG = 6.0, 2.5, 0.5


# ---------------------------------------------------------------- protocol pieces

def test_perturbed_starts_are_5_cm_and_30_degrees_from_their_demo_start() -> None:
    demos = robottasks(TASK)
    assert demos.q is not None and demos.goal_q is not None
    protocol = rt.RobotTasksProtocol()
    st = rt.perturbed_starts(demos, TASK, protocol)
    assert st.x.shape == (72, 3) and st.q.shape == (72, 4) and list(st.demo) == [i for i in range(9) for _ in range(8)]
    x0, q0 = demos.x[st.demo, 0], demos.q[st.demo, 0]
    np.testing.assert_allclose(np.linalg.norm(st.x - x0, axis=1), 0.05, rtol=1e-12)
    turn = np.degrees(geodesic_angle(quaternion_matrices(st.q), quaternion_matrices(q0)))
    np.testing.assert_allclose(turn, 30.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(st.q, axis=1), 1.0, atol=1e-12)
    assert (np.einsum("ij,ij->i", st.q, q0) > 0).all()                  # signed like the demo start
    directions = (st.x - x0) / 0.05
    assert np.linalg.svd(directions, compute_uv=False)[-1] > 1.0          # spread over all of R^3
    # the chart point of a start is that pose: its rotation is R' to round-off
    chart = PoseChart.at(demos.goal_q)
    z = chart.to_chart(st.x, st.q)
    back = np.degrees(geodesic_angle(chart.rotations(z), quaternion_matrices(st.q)))
    assert back.max() < 1e-6 and np.allclose(z[:, :3], st.x)
    again = rt.perturbed_starts(demos, TASK, protocol)
    assert np.array_equal(again.x, st.x) and np.array_equal(again.q, st.q)
    other = rt.perturbed_starts(robottasks("pouring"), "pouring", protocol)
    assert not np.allclose(other.x - robottasks("pouring").x[other.demo, 0], st.x - x0)


def test_dtw_path_is_the_alignment_of_lfd_metrics_dtw() -> None:
    rng = np.random.default_rng(3)
    for n, m in ((1, 1), (1, 7), (40, 55), (73, 31)):
        a, b = np.cumsum(rng.normal(size=(n, 3)), axis=0), np.cumsum(rng.normal(size=(m, 3)), axis=0)
        path = dtw_path(a, b)
        assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (n - 1, m - 1)
        steps = np.diff(path, axis=0)
        assert ((steps >= 0) & (steps <= 1)).all() and (steps.sum(axis=1) >= 1).all()
        cost = cdist(a, b)[path[:, 0], path[:, 1]].sum()
        assert cost == pytest.approx(dtw(a, b), rel=1e-12)


def test_protocol_and_option_errors_are_config_errors() -> None:
    assert SUITE.resolve_units("all") == list(ROBOTTASKS) and len(ROBOTTASKS) == 9
    assert SUITE.resolve_units("all", quick=True) == list(rt.QUICK_UNITS)
    assert SUITE.resolve_units("scoop,pouring,scoop") == ["scoop", "pouring"]
    with pytest.raises(ConfigError, match="nosuch"):
        SUITE.resolve_units("scoop,nosuch")
    with pytest.raises(ConfigError, match="perturbed_starts"):
        rt.RobotTasksProtocol(perturbed_starts=-1)
    with pytest.raises(ConfigError, match="perturb_angle_deg"):
        rt.RobotTasksProtocol(perturb_angle_deg=180.0)
    with pytest.raises(ConfigError, match="int_dt"):
        make_cartesian_config(int_dt=0)
    with pytest.raises(ConfigError, match="unknown option"):
        make_cartesian_config(weights=5)
    a = SUITE.cell("dmp", TASK, 0, None, {})
    b = rt.RobotTasksSuite(rt.RobotTasksProtocol(perturbed_starts=2)).cell("dmp", TASK, 0, None, {})
    assert a.hash != b.hash and a.stem == b.stem == f"dmp__{TASK}__seed0"


def test_cartesian_dmp_reproduces_the_mean_demo() -> None:
    demos = robottasks(TASK)
    assert demos.goal_q is not None
    model = fit_cartesian_dmp(demos)
    mean_x, mean_q = mean_pose_demo(demos)
    assert np.allclose(np.linalg.norm(mean_q, axis=1), 1.0)
    assert (np.einsum("ij,ij->i", mean_q[1:], mean_q[:-1]) > 0).all()      # sign-continuous
    y, yd = model.reproduce(np.concatenate([mean_x, mean_q], axis=1)[None], demos.t[:1])
    assert y.shape == (1, 1000, 7) and yd.shape == (1, 1000, 6)
    x, q = y[..., :3], y[..., 3:]
    err_mm = 1000 * np.linalg.norm(x[0] - mean_x, axis=1)
    err_deg = np.degrees(geodesic_angle(quaternion_matrices(q[0]), quaternion_matrices(mean_q)))
    assert err_mm.max() < DMP_MEAN_MAX_MM and np.sqrt(np.mean(err_mm ** 2)) < DMP_MEAN_RMS_MM
    assert err_deg.max() < DMP_MEAN_MAX_DEG
    # the other sign of the start quaternion is the same orientation: the same rollout (its first 2 s)
    y2, _ = model.run(np.concatenate([mean_x[0], -mean_q[0]]), model.duration, model.duration / 999, 120)
    x2, q2 = y2[:, :3], y2[:, 3:]
    assert np.allclose(x2, x[0, :120]) and np.degrees(geodesic_angle(quaternion_matrices(q2),
                                                                     quaternion_matrices(q[0, :120]))).max() < 1e-6
    # from a perturbed start it reaches the goal pose and stays there (coarse int_dt: fast)
    model.dmp.int_dt = 1 / 60
    st = rt.perturbed_starts(demos, TASK, rt.RobotTasksProtocol(perturbed_starts=1))
    t = np.linspace(0.0, 3 * model.duration, 300)
    yr = model.rollouts(np.concatenate([st.x[:1], st.q[:1]], axis=1), t)
    xr, qr = yr[..., :3], yr[..., 3:]
    late = t > 2 * model.duration
    assert 1000 * np.linalg.norm(xr[:, late] - demos.goal, axis=-1).max() < 1.0
    assert np.degrees(geodesic_angle(quaternion_matrices(qr[:, late]),
                                     quaternion_matrices(demos.goal_q))).max() < 1.0
    # toward another end pose (the held-out split): the goal moves, given with either quaternion sign
    end = np.concatenate([demos.x[3, -1] + [0.02, 0.0, -0.01], -demos.q[3, -1]])
    moved = model.toward(end)
    assert np.allclose(moved.goal[:3], end[:3]) and abs(moved.goal[3:] @ demos.q[3, -1]) == pytest.approx(1.0)
    assert moved.goal[3:] @ model.goal[3:] > 0                                       # signed like the goal it had
    assert np.array_equal(model.goal[:3], demos.goal)                                  # the model is unchanged
    ym = moved.rollouts(np.concatenate([st.x[:1], st.q[:1]], axis=1), t)
    assert 1000 * np.linalg.norm(ym[:, late, :3] - end[:3], axis=-1).max() < 1.0
    assert rt.angles_deg(ym[:, late, 3:], demos.q[3, -1]).max() < 1.0


def test_a_task_a_learner_refuses_is_reported_not_cached(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: Any) -> Any:
        raise DemoError("robottasks:scoop: demos do not end near a common goal")

    monkeypatch.setattr(rt.RobotTasksSuite, "evaluate", refuse)
    cell = SUITE.cell("dmp", TASK, 0, None, {})
    result = run_cells([cell], tmp_path / "cache", workers=1, progress=False)
    assert result.records == [] and result.computed == [cell.stem]
    assert result.failed == [{"cell": cell.stem, "reason": "robottasks:scoop: demos do not end near a common goal",
                              "attempts": 1, "refused": True}]
    assert list((tmp_path / "cache").iterdir()) == []


# ---------------------------------------------------------------- the command

QUICK_ARGV = ["bench", "robottasks", "--learner", ",".join(LEARNERS), "--quick", "--tasks", TASK,
              "--perturbed-starts", "1", "--workers", "2"]


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return bench_run(tmp_path_factory.mktemp("robottasks"), QUICK_ARGV, "rt.md")


def test_results_json_has_every_cell_with_numbers_in_range(quick: dict[str, Any]) -> None:
    r = quick["json"]
    assert {"protocol", "protocol_hash", "learners", "tasks", "seeds", "quick", "summary", "run", "results"} <= set(r)
    assert r["tasks"] == [TASK] and r["quick"] is True and r["protocol"]["perturbed_starts"] == 1
    assert r["protocol"] == rt.RobotTasksProtocol(perturbed_starts=1).to_dict()
    inside = [c for c in r["results"] if c["split"] == "in-sample"]
    assert sorted(f"{c['learner']}__{c['task']}__seed{c['seed']}" for c in inside) == sorted(CELLS)
    assert r["run"]["computed"] == 2 + 2 * 9 and r["run"]["cached"] == 0 and r["run"]["failed"] == []
    cells = {c["learner"]: c for c in inside}
    for learner, c in cells.items():
        assert set(c["metrics"]) == set(rt.METRICS) and all(len(v) == 9 for v in c["per_demo"].values())
        assert all(isinstance(v, float) and v >= 0 for v in c["metrics"].values()), learner
        conv = c["convergence"]
        assert conv["n_starts"] == 9 and conv["radius_mm"] == 1.0 and conv["radius_deg"] == 1.0
        assert conv["horizon_s"] == pytest.approx(3 * 999 / 60)
        assert c["train_time_s"] > 0 and c["step_time_us"] > 0 and c["pose_step_time_us"] > 0
        assert conv["rate"] == 1.0, (learner, conv)       # a tracking field and a DMP reach the goal pose
        m = c["metrics"]                                  # the demos' shape and the goal pose
        assert m["dtw_mm"] < 6000 and m["dtw_angle_deg"] < 6.0, (learner, m)
        assert m["final_mm"] < 2.0 and m["final_deg"] < 1.0, (learner, m)
    assert cells["tracking"]["integrators"] == {"reproduce": "rk4 on (x, s), step 0.0167 s",
                                                "rollouts": "rk4 on (x, s), step 0.0666 s"}
    assert cells["dmp"]["config"]["int_dt"] == pytest.approx(1 / 60)   # the quick option
    s = r["summary"]
    assert set(s) == set(LEARNERS) and s["dmp"]["in-sample"]["units"] == 1 and s["dmp"]["in-sample"]["converged"] == 1.0


def test_held_out_runs_a_field_per_demo_toward_that_demos_own_end(quick: dict[str, Any]) -> None:
    """9 cells per learner, cell i trained on the other 8 demos and run from demo i's start toward its
    own end pose, which it reaches. The demos end at one position but at orientations degrees apart:
    where demo i's end lies away from the training demos' goal orientation, the run ends at demo i's."""
    demos = robottasks(TASK)
    assert demos.q is not None
    for learner in LEARNERS:
        apart = 0
        held = sorted((c for c in quick["json"]["results"] if c["learner"] == learner and c["split"] == "held-out"),
                      key=lambda c: c["fold"])
        assert [c["fold"] for c in held] == list(range(9))
        for c in held:
            i = c["fold"]
            assert c["scored_demos"] == [i] and c["train_demos"] == [k for k in range(9) if k != i]
            assert set(c["metrics"]) == set(rt.METRICS) and all(len(v) == 1 for v in c["per_demo"].values())
            m = c["metrics"]
            assert m["final_mm"] < HELD_OUT_END_MM and m["final_deg"] < HELD_OUT_END_DEG, (learner, i, m)
            y = np.load(quick["dir"] / ".cache" / "r" / f"{c['learner']}__{TASK}__seed0__out{i}.npz")["reproduction"]
            assert y.shape == (1, demos.n_samples, 7)
            np.testing.assert_allclose(y[0, 0, :3], demos.x[i, 0], atol=1e-9)            # from its own start
            assert rt.angles_deg(y[0, -1, 3:], demos.q[i, -1]) == pytest.approx(m["final_deg"], rel=1e-9, abs=1e-9)
            train_goal_q = demos.subset(c["train_demos"]).goal_q
            gap = rt.angles_deg(demos.q[i, -1], train_goal_q)           # demo i's end from the training goal
            if gap > 2 * HELD_OUT_END_DEG:
                apart += 1
                assert rt.angles_deg(y[0, -1, 3:], train_goal_q) > gap - HELD_OUT_END_DEG, (learner, i)
        assert apart >= 5
        s = quick["json"]["summary"][learner]
        mean = float(np.mean([h["metrics"]["dtw_mm"] for h in held]))
        assert s["held-out"]["metrics"]["dtw_mm"]["mean"] == pytest.approx(mean, rel=1e-12)
        assert s["held-out / in-sample"]["dtw_mm"]["ratio"] == pytest.approx(
            mean / s["in-sample"]["metrics"]["dtw_mm"]["mean"], rel=1e-12)


def test_report_has_tables_and_figures(quick: dict[str, Any]) -> None:
    md, d = quick["md"], quick["dir"]
    assert md.startswith("# RoboTasks9 benchmark")
    summary = md.split("## Summary")[1].split("## ")[0]
    for learner in LEARNERS:
        assert re.search(rf"^\| {learner} \| 1 \|", summary, re.M)
        section = md.split(f"## Per task: {learner}")[1].split("## ")[0]
        inside, held = section.split(f"Held-out demos, {learner}:")
        for table in (inside, held):
            rows = [line for line in table.splitlines() if line.startswith("| ")][1:]
            assert [row.split("|")[1].strip() for row in rows] == [TASK, "**Mean**", "**Median**"]
    assert "## Reading" in md and "100.0% of the perturbed starts" in md
    split = md.split("## In-sample and held-out")[1].split("## ")[0]
    assert "| learner | tasks | DTW (sum, mm) in-sample | held-out | ratio | angle along DTW (°) in-sample |" in split
    assert all(re.search(rf"^\| {learner} \| 1 \| ", split, re.M) for learner in LEARNERS)
    for kind in ("paths", "angle"):
        assert f"(figures/rt_{TASK}_{kind}.png)" in md
        fig = d / "figures" / f"rt_{TASK}_{kind}.png"
        assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and fig.stat().st_size > 20_000


def test_second_run_resumes_from_the_cache(quick: dict[str, Any], capsys: pytest.CaptureFixture[str]) -> None:
    d = quick["dir"]
    capsys.readouterr()
    r = bench_run(d, QUICK_ARGV, "rt.md")["json"]
    assert "0 cell(s) computed, 20 from" in capsys.readouterr().out
    assert r["run"]["computed"] == 0 and r["run"]["cached"] == 20
    before = {(c["learner"], c["fold"]): c["metrics"] for c in quick["json"]["results"]}
    assert {(c["learner"], c["fold"]): c["metrics"] for c in r["results"]} == before
