"""Whole-arm clearance: the collision dampers (sim.scene.collision), the IK QP (robots.ik.constrained),
the hand margin, ``blocked``, and the user's case of a small sphere on the path of the Panda."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

import lfd
import sim
from lfd.obstacles import Sphere, avoid
from robots import load_robot
from robots.errors import RobotError
from robots.ik.constrained import ConstrainedIK, QpGains
from robots.kinematics import Kinematics
from sim.errors import SimError
from sim.scene.collision import ArmClearance, Clearance, hand_margin_m
from sim.scene.obstacles import obstacle_contacts

ROOT = Path(__file__).resolve().parents[1]


def users_spiral() -> lfd.DemoSet:
    return lfd.spiral(n_demos=3, radius=0.13)


def users_sphere(demos: lfd.DemoSet) -> Sphere:
    """6 % of the extent, on demo 0 at 40 % of its arc length (the case of the issue)."""
    x = demos.x[0]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    return Sphere(x[np.searchsorted(s, 0.4 * s[-1])], 0.06 * demos.extent)


@pytest.fixture(scope="module")
def scene():
    """The Panda with the user's sphere and a table, at a posture with the fingers 1-3 cm from the sphere."""
    demos = users_spiral()
    ob = users_sphere(demos)
    exp = sim.Experiment(load_robot("panda", table=True), demos, obstacles=[ob])
    robot = exp.robot
    model = exp.physics.model.ptr
    data = mujoco.MjData(model)
    tool = exp.placement.to_world(ob.center) + np.array([0.0, 0.0, 0.0])
    side = exp.placement.to_world(ob.center + np.array([0.0, ob.radius])) - exp.placement.to_world(ob.center)
    target = tool + side / np.linalg.norm(side) * (exp.placement.scale * ob.radius + 0.035)
    from robots import solve_pose_ik

    q, err, _ = solve_pose_ik(robot, target, exp.setup.rotation_ref, q0=robot.q_home)
    assert err < 1e-4
    data.qpos[robot.mj_qpos_adr] = q
    mujoco.mj_forward(model, data)
    return exp, model, data, q


def test_damper_rows_are_mujocos_distances_and_jacobians(scene) -> None:
    """Each row is n^T J(p1) at MuJoCo's nearest points (checked against mj_geomDistance and mj_jac
    called here), its bound k (d - d_s); only pairs within d_i."""
    exp, model, data, _ = scene
    guard = ArmClearance(model, exp.robot, Clearance())
    A, b = guard.rows(data)
    assert len(b) >= 1 and guard.min_distance < 0.04 and "obstacle_0" in guard.closest
    spec, ft, jac = guard.spec, np.zeros(6), np.zeros((3, model.nv))
    want = []
    for g1, g2, mutual in guard.pairs:
        d = mujoco.mj_geomDistance(model, data, g1, g2, spec.influence_m, ft)
        if d >= spec.influence_m:
            continue
        n = (ft[3:] - ft[:3]) / np.linalg.norm(ft[3:] - ft[:3]) * np.sign(d)
        mujoco.mj_jac(model, data, jac, None, ft[:3].copy(), int(model.geom_bodyid[g1]))
        row = n @ jac[:, exp.robot.mj_dof_adr]
        if mutual:
            mujoco.mj_jac(model, data, jac, None, ft[3:].copy(), int(model.geom_bodyid[g2]))
            row = row - n @ jac[:, exp.robot.mj_dof_adr]
        want.append((row, spec.rate * (d - spec.safety_m)))
    assert len(want) == len(b)
    order = np.lexsort(np.round(A, 9).T)
    worder = np.lexsort(np.round(np.array([w[0] for w in want]), 9).T)
    np.testing.assert_allclose(A[order], np.array([w[0] for w in want])[worder], atol=1e-12)
    np.testing.assert_allclose(b[order], np.array([w[1] for w in want])[worder], atol=1e-12)


def test_check_decides_as_the_rows_and_gives_their_minimum_on_a_path_into_the_sphere(scene) -> None:
    """``ArmClearance.check`` (lower bounds from the broad phase and from cached distances, exact
    distances only where a row could bind) decides, for random qdot, exactly as the rows of
    ``rows`` whether a damper binds (any A qdot > b), and otherwise gives their smallest distance
    and its pair, on a joint path that takes the fingers from beyond d_i into the sphere (states a
    few mm from it and touching included), walked forward, back and with jumps."""
    exp, model, _, _ = scene
    robot = exp.robot
    from robots import solve_pose_ik

    ob = exp.obstacles[0]
    centre = exp.placement.to_world(ob.center)
    side = exp.placement.to_world(ob.center + np.array([0.0, ob.radius])) - centre
    side /= np.linalg.norm(side)
    ends = []
    for gap in (0.06, -0.03):    # the tool point this far beyond the fingers' reach (hand margin) from the surface
        target = centre + side * (exp.placement.scale * ob.radius + hand_margin_m(robot) + gap)
        q, err, _ = solve_pose_ik(robot, target, exp.setup.rotation_ref, q0=robot.q_home)
        assert err < 1e-4
        ends.append(q)
    path = np.linspace(ends[0], ends[1], 240)
    rng = np.random.default_rng(3)
    order = np.concatenate([np.arange(240), np.arange(239, -1, -3), rng.integers(0, 240, 60)])
    data = mujoco.MjData(model)
    guard, exact = ArmClearance(model, robot), ArmClearance(model, robot)
    binds, smallest = 0, np.inf
    for k in order:
        data.qpos[robot.mj_qpos_adr] = path[k] + rng.normal(0.0, 2e-4, robot.n)
        mujoco.mj_forward(model, data)
        A, b = exact.rows(data)
        for scale in (0.02, 0.3, 2.0):    # rad/s
            qdot = rng.normal(0.0, scale, robot.n)
            want = bool(np.any(A @ qdot > b))
            assert guard.check(data, qdot) == want
            binds += want
            if not want:
                assert guard.min_distance == exact.min_distance and guard.closest == exact.closest
        smallest = min(smallest, exact.min_distance)
    assert smallest < 0.0 and 50 < binds < 3 * len(order) - 50   # touching states; both decisions met


def test_table_and_self_pairs_are_checked_but_not_the_base_on_its_table(scene) -> None:
    exp, model, data, _ = scene
    guard = ArmClearance(model, exp.robot)
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table_top")
    table_pairs = [p for p in guard.pairs if p[1] == table]
    bodies = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[p[0]])) for p in table_pairs}
    assert "panda_hand" in bodies and "panda_link0" not in bodies and "panda_link1" not in bodies
    assert any(p[2] for p in guard.pairs)                                       # arm against arm
    home = mujoco.MjData(model)
    home.qpos[exp.robot.mj_qpos_adr] = exp.robot.q_home
    mujoco.mj_forward(model, home)
    assert all(mujoco.mj_geomDistance(model, home, g1, g2, 0.04, np.zeros(6)) >= 0.04
               for g1, g2, m in guard.pairs if m)


def test_the_hand_margin_is_the_fingers_reach_around_the_tool_point() -> None:
    panda = hand_margin_m(load_robot("panda"))
    assert 0.02 < panda < 0.04          # the fingers, not the 20 cm hand above them
    assert hand_margin_m(load_robot("planar")) == 0.0


def test_clearance_options_are_checked() -> None:
    with pytest.raises(SimError, match="influence_m"):
        Clearance(safety_m=0.05, influence_m=0.04)
    with pytest.raises(SimError, match="rate"):
        Clearance(rate=0.0)
    with pytest.raises(SimError, match="safety_m"):
        Clearance(safety_m=float("nan"))
    with pytest.raises(RobotError, match="limit_gain"):
        QpGains(limit_gain=0.0)


def test_the_qp_is_the_dls_without_rows_and_keeps_every_row(scene) -> None:
    exp, _, data, q = scene
    robot = exp.robot
    kin = Kinematics(robot)
    kin.update(q)
    cik = ConstrainedIK(robot, (0, 1, 2, 3, 4, 5), kin)
    twist = np.array([0.1, -0.05, 0.02, 0.0, 0.0, 0.0])
    free, relaxed = cik.solve(q, twist, 0.002, np.zeros((0, robot.n)), np.zeros(0), kin=kin)
    assert not relaxed
    np.testing.assert_allclose(kin.ee_jacobian() @ free, twist, atol=1e-5)   # mu = 1e-6 pulls toward the posture
    guard = ArmClearance(exp.physics.model.ptr, robot)
    A, b = guard.rows(data)
    centre = exp.placement.to_world(exp.obstacles[0].center)
    toward = centre - kin.ee_position()
    tw = np.concatenate([0.5 * toward / np.linalg.norm(toward), np.zeros(3)])  # 0.5 m/s straight at it
    x, relaxed = cik.solve(q, tw, 0.002, A, b, kin=kin)
    assert not relaxed and np.all(A @ x <= b + 1e-7) and cik.active.any()
    x, relaxed = cik.solve(q, tw, 0.002, A, b - 1e3, kin=kin)                 # asks for a retreat it cannot make
    assert relaxed and np.all(A @ x <= np.maximum(b - 1e3, 0.0) + 1e-7)


def beside_the_goal(demos: lfd.DemoSet, gap_m: float = 0.015) -> Sphere:
    """A sphere of 6 % of the extent whose surface is ``gap_m`` from the goal, along the fingers'
    opening (the tool's y axis): the tool point fits there, the fingers (28 mm from it) do not."""
    exp = sim.Experiment(load_robot("panda"), demos, clearance=None)
    fingers = exp.placement.axes.T @ exp.setup.rotation_ref[:, 1]               # task axes
    r = 0.06 * demos.extent
    return Sphere(demos.goal + fingers / np.linalg.norm(fingers) * (r + gap_m / exp.placement.scale), r)


def test_a_goal_the_hand_cannot_reach_is_reported_blocked_and_nothing_touches() -> None:
    """The tool point's goal lies 15 mm from a sphere: without the dampers the fingers run into it;
    with them the arm stops 10 mm clear, short of its goal, and the run says ``blocked``."""
    from known_fields import sink_field

    demos = users_spiral()
    bare = sink_field(demos)
    ob = beside_the_goal(demos)
    results = {}
    for clearance in (None, "auto"):
        exp = sim.Experiment(load_robot("panda"), demos, obstacles=[ob], clearance=clearance)
        r = exp.run(avoid(bare, [ob]), "none")                 # the tool point avoids it
        results[clearance] = (r, obstacle_contacts(exp.robot, r.trace.q, r.trace.t))
    r, c = results[None]
    assert c.steps_in_contact > 100 and "blocked" not in r.metrics
    r, c = results["auto"]
    assert c.steps_in_contact == 0 and c.min_clearance_m > 0.008
    assert r.metrics["blocked"] is True and r.metrics["final_goal_error_m"] > 0.005
    assert 0.008 < r.metrics["arm_min_clearance_m"] < 0.012 and r.metrics["guard_active_s"] > 0.5


def test_the_users_case_with_default_options_touches_nothing_and_reaches_the_goal(tmp_path) -> None:
    """scripts/demo_arm.py with the user's sphere and no margin: 0 contacts and the goal within
    5 mm, with and without a push; ``--no-arm-clearance`` (the tool point only) hits it."""
    demos = users_spiral()
    from lfd.demos import save_file

    save_file(demos, tmp_path / "spiral3.npz")
    ob = users_sphere(demos)
    text = f"sphere:{float(ob.center[0])!r},{float(ob.center[1])!r},{ob.radius!r}"
    base = [sys.executable, str(ROOT / "scripts" / "demo_arm.py"), "--robot", "panda", "--demos",
            str(tmp_path / "spiral3.npz"), "--obstacle", text, "--learner", "contraction", "--no-video", "--no-plots",
            "--iters", "300", "--quiet"]   # the second run takes the model the first trained (the model cache)
    for extra, out in ((["--perturb", "none,push"], "safe"), (["--perturb", "none", "--no-arm-clearance"], "tool")):
        p = subprocess.run(base + extra + ["--out", str(tmp_path / out)], capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-2000:]
    safe = json.loads((tmp_path / "safe" / "metrics.json").read_text())
    tool = json.loads((tmp_path / "tool" / "metrics.json").read_text())
    for run in safe["runs"]:
        m = run["metrics"]
        assert m["obstacle_steps_in_contact"] == 0 and m["final_goal_error_m"] < 0.005, m
        assert m["blocked"] is False and m["arm_min_clearance_m"] > 0.009
    assert safe["settings"]["clearance"]["safety_m"] == 0.01
    demo_s = float(demos.t[0, -1] - demos.t[0, 0])                    # obstacle runs get 3x the demo's time
    assert abs(safe["settings"]["duration_s"] - (3.0 * demo_s + 1.5)) < 1e-9
    assert sum(run["metrics"]["obstacle_steps_in_contact"] for run in tool["runs"]) > 0
    assert tool["settings"]["clearance"] is None


def test_blocked_runs_are_said_on_stderr(tmp_path, monkeypatch, capsys) -> None:
    """Without the hand margin (patched to 0) the job takes the tool point to a goal the fingers
    cannot reach: one ``blocked:`` line on stderr, ``blocked`` in the run's metrics, no contact. With
    the margin the same obstacle is refused before any work."""
    import sim.run.obstacle_runs as obstacle_runs
    from lfd.demos import save_file
    from lfd.errors import ConfigError

    demos = users_spiral()
    save_file(demos, tmp_path / "spiral3.npz")
    ob = beside_the_goal(demos)
    job = sim.ArmJob(robot="panda", learners=("contraction",), demos=str(tmp_path / "spiral3.npz"),
                     scenarios=("none",), videos=False, plots=False, out=str(tmp_path / "out"), iters=300,
                     obstacles=(f"sphere:{float(ob.center[0])!r},{float(ob.center[1])!r},{ob.radius!r}",), quiet=True)
    with pytest.raises(ConfigError, match="within the hand's size"):
        sim.run_job(job)
    monkeypatch.setattr(obstacle_runs, "hand_margin_m", lambda robot: 0.0)
    report = sim.run_job(job)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.startswith("blocked:")]
    assert len(lines) == 1 and "contraction / none" in lines[0] and "mm from its goal" in lines[0], err
    assert report.results[0].metrics["blocked"] is True and report.results[0].metrics["stopped_short"] is False
    assert report.results[0].metrics["obstacle_steps_in_contact"] == 0
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert saved["runs"][0]["metrics"]["blocked"] is True


def test_runs_that_end_short_with_nothing_in_the_way_say_so(tmp_path, monkeypatch, capsys) -> None:
    """A field too slow to arrive (a linear sink at 0.01/s) with a sphere off its path: the run ends
    more than 20 mm from its goal and no damper holds it back: ``stopped_short`` (not ``blocked``) in the
    metrics, one ``short:`` line on stderr. The blocked run of the test above is not short."""
    from known_fields import sink_field

    import sim.run.plan as plan
    from lfd.demos import save_file

    demos = users_spiral()
    save_file(demos, tmp_path / "spiral3.npz")
    ob = Sphere(demos.goal + 0.8 * demos.extent, 0.03 * demos.extent)
    slow = sink_field(demos, "contraction", a=0.01)
    monkeypatch.setattr(plan, "cached_field", lambda name, *a, **k: (slow, tmp_path / "slow.pt", False))
    job = sim.ArmJob(robot="panda", learners=("contraction",), demos=str(tmp_path / "spiral3.npz"),
                     scenarios=("none",), videos=False, plots=False, out=str(tmp_path / "out"),
                     obstacles=(f"sphere:{float(ob.center[0])!r},{float(ob.center[1])!r},{ob.radius!r}",), quiet=True)
    report = sim.run_job(job)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.startswith("short:")]
    assert len(lines) == 1 and "contraction / none ended" in lines[0] and "nothing holding it back" in lines[0], err
    m = report.results[0].metrics
    assert m["stopped_short"] is True and m["blocked"] is False and m["final_goal_error_m"] > 0.02
    assert m["obstacle_steps_in_contact"] == 0
    assert not any(x.startswith("blocked:") for x in err.splitlines())


def test_avoid_is_refused_above_three_dimensions() -> None:
    from known_fields import linear_field

    from lfd.errors import ConfigError

    f = linear_field(-np.eye(6), np.zeros(6))
    with pytest.raises(ConfigError, match="2-D or 3-D"):
        avoid(f, [])
