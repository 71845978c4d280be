"""Differential IK (dls, pink) and position IK on the built-in arms, by kinematic integration q <- q + qdot dt."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from robots import (
    BUILTIN_ROBOTS,
    IK_BACKENDS,
    DifferentialIK,
    Kinematics,
    RobotError,
    RobotModel,
    load_robot,
)
from robots.ik import solve_position_ik

DT = 0.002
MARGIN = 0.02  # default limit_margin of both backends
SPEED_FRACTION = 0.97  # default speed_fraction of both backends: the IK commands at most 0.97 v_max
CASES = [(robot, backend) for robot in BUILTIN_ROBOTS for backend in IK_BACKENDS]


@pytest.fixture(scope="module")
def robots() -> dict[str, RobotModel]:
    return {name: load_robot(name) for name in BUILTIN_ROBOTS}


@pytest.mark.parametrize(("name", "backend"), CASES)
def test_straight_line_twist_is_tracked_for_one_second(robots: dict[str, RobotModel], name: str,
                                                       backend: str) -> None:
    """Constant twist v = (0.1, -0.05, 0.08) m/s (planar: x, y only), w = 0: the tool stays on the line
    p(t) = p0 + v t within 0.2 mm and keeps its orientation within 1 mrad (6-D task)."""
    robot = robots[name]
    ik, kin = DifferentialIK(robot, backend), Kinematics(robot)
    twist = np.array([0.1, -0.05, 0.0 if robot.planar else 0.08, 0.0, 0.0, 0.0])
    q = robot.q_home.copy()
    kin.update(q)
    p0, r0 = kin.ee_position().copy(), kin.ee_rotation().copy()
    worst_pos = worst_rot = 0.0
    for step in range(1, 501):
        q = q + ik.solve(q, twist, DT) * DT
        kin.update(q)
        worst_pos = max(worst_pos, np.linalg.norm(kin.ee_position() - (p0 + twist[:3] * DT * step)))
        if not robot.planar:
            worst_rot = max(worst_rot, np.linalg.norm(pin.log3(kin.ee_rotation() @ r0.T)))
    assert worst_pos < 2e-4
    assert worst_rot < 1e-3
    assert ik.limit_hits == 0


def _drive(robot: RobotModel, ik: DifferentialIK, q: np.ndarray, twist: np.ndarray, steps: int) -> tuple[float, ...]:
    """Integrate and return (largest step beyond the soft limits, largest |qdot_i| / v_max_i, closest approach
    to a soft limit)."""
    beyond = ratio = 0.0
    closest = np.inf
    lo, hi = robot.q_min + MARGIN, robot.q_max - MARGIN
    for _ in range(steps):
        qdot = ik.solve(q, twist, DT)
        assert np.all(np.isfinite(qdot))
        ratio = max(ratio, float(np.max(np.abs(qdot) / robot.v_max)))   # against the joint's own limit
        q = q + qdot * DT
        beyond = max(beyond, float(np.max(lo - q)), float(np.max(q - hi)))
        closest = min(closest, float(np.min(np.minimum(q - lo, hi - q))))
    return beyond, ratio, closest


@pytest.mark.parametrize("backend", IK_BACKENDS)
def test_joint_position_limits_hold(robots: dict[str, RobotModel], backend: str) -> None:
    """Planar arm with joint 1 near its upper limit, tool pushed for 2 s at 0.3 m/s along the direction that turns
    joint 1 further: q stays inside [q_min + margin, q_max - margin], |qdot| <= v_max, and limit_hits counts it."""
    robot = robots["planar"]
    ik, kin = DifferentialIK(robot, backend), Kinematics(robot)
    q = np.array([2.6, 0.5, 0.5])
    kin.update(q)
    p = kin.ee_position()
    tangent = np.array([-p[1], p[0]]) / np.linalg.norm(p[:2])
    beyond, ratio, closest = _drive(robot, ik, q, np.r_[0.3 * tangent, 0.0, 0.0, 0.0, 0.0], 1000)
    assert beyond <= 1e-9
    assert ratio <= SPEED_FRACTION * (1 + 1e-6)
    assert closest < 1e-6  # the limit was reached
    assert ik.limit_hits > 100


@pytest.mark.parametrize("backend", IK_BACKENDS)
def test_joint_beyond_a_soft_limit_does_not_go_further(robots: dict[str, RobotModel], backend: str) -> None:
    """A measured q 0.015 rad past q_max - margin (servo overshoot) with a twist pushing further out: the solve
    succeeds and that joint does not move further out."""
    robot = robots["planar"]
    ik = DifferentialIK(robot, backend)
    q = np.array([robot.q_max[0] - MARGIN + 0.015, 0.5, 0.5])
    kin = Kinematics(robot)
    kin.update(q)
    p = kin.ee_position()
    qdot = ik.solve(q, np.r_[0.3 * np.array([-p[1], p[0]]) / np.linalg.norm(p[:2]), 0.0, 0.0, 0.0, 0.0], DT)
    assert np.all(np.isfinite(qdot)) and qdot[0] <= 1e-9
    assert ik.limit_hits == 1


@pytest.mark.parametrize("backend", IK_BACKENDS)
def test_speed_fraction_sets_the_commanded_limit_and_is_checked(robots: dict[str, RobotModel], backend: str) -> None:
    """speed_fraction = 1 commands up to v_max itself; a fraction outside (0, 1] is a RobotError."""
    robot = robots["panda"]
    ik = DifferentialIK(robot, backend, speed_fraction=1.0)
    _, ratio, _ = _drive(robot, ik, robot.q_home.copy(), np.array([3.0, -2.0, 1.0, 0, 0, 0]), 5)
    assert 0.999 < ratio <= 1.0 + 1e-6
    for bad in (0.0, -0.5, 1.5, float("nan"), True, "0.9"):
        with pytest.raises(RobotError, match="speed_fraction"):
            DifferentialIK(robot, backend, speed_fraction=bad)


@pytest.mark.parametrize(("name", "backend"), CASES)
def test_velocity_limit_scales_a_too_fast_twist(robots: dict[str, RobotModel], name: str, backend: str) -> None:
    robot = robots[name]
    ik = DifferentialIK(robot, backend)
    beyond, ratio, _ = _drive(robot, ik, robot.q_home.copy(), np.array([3.0, -2.0, 1.0, 0, 0, 0]), 20)
    assert beyond <= 1e-9
    assert 0.999 * SPEED_FRACTION < ratio <= SPEED_FRACTION * (1 + 1e-6)   # scaled to the commanded limit
    assert ik.limit_hits == 20


@pytest.mark.parametrize(("name", "backend"), CASES)
def test_null_space_posture_does_not_disturb_the_task(robots: dict[str, RobotModel], name: str,
                                                      backend: str) -> None:
    """Away from q_home with a zero twist the posture term moves the joints but not the tool (J qdot ~ 0); with a
    twist, J qdot equals it. dls: exactly (projector); pink: up to the posture cost's weight (1e-3)."""
    robot = robots[name]
    ik, kin = DifferentialIK(robot, backend), Kinematics(robot)
    rows = list(ik.rows)
    tol = 1e-12 if backend == "dls" else 1e-4
    q = np.clip(robot.q_home + np.where(np.arange(robot.n) % 2, 0.3, -0.3), robot.q_min + 0.1, robot.q_max - 0.1)
    kin.update(q)
    p0 = kin.ee_position().copy()
    for twist in (np.zeros(6), np.array([0.05, 0.02, 0.03, 0.0, 0.0, 0.1])):
        qdot = ik.solve(q, twist, DT)
        assert np.abs(kin.ee_jacobian()[rows] @ qdot - twist[rows]).max() < tol
    q_start = q.copy()
    for _ in range(500):
        q = q + ik.solve(q, np.zeros(6), DT) * DT
    kin.update(q)
    assert np.linalg.norm(q - q_start) > 0.03                                         # the posture changed,
    assert np.linalg.norm(q - robot.q_home) < np.linalg.norm(q_start - robot.q_home)  # toward q_home,
    assert np.linalg.norm(kin.ee_position() - p0) < 1e-4                              # the tool did not move


@pytest.mark.parametrize("backend", IK_BACKENDS)
def test_singular_configuration_gives_bounded_finite_qdot(robots: dict[str, RobotModel], backend: str) -> None:
    robot = robots["planar"]
    ik = DifferentialIK(robot, backend)
    for q in (np.zeros(3), np.array([0.0, 1e-5, 0.0])):  # arm stretched: no radial (x) velocity possible
        for twist in (np.array([1.0, 0, 0, 0, 0, 0]), np.array([0, 1.0, 0, 0, 0, 0])):
            qdot = ik.solve(q, twist, DT)
            assert np.all(np.isfinite(qdot)) and np.all(np.abs(qdot) <= SPEED_FRACTION * robot.v_max * (1 + 1e-6))


def test_dls_damping_bounds_the_gain_near_a_singularity(robots: dict[str, RobotModel]) -> None:
    """Near the stretched posture (s_min ~ 1e-5) a pseudo-inverse would give |qdot| ~ |v| / s_min; with
    lambda^2 = lambda_max^2 (1 - (s_min/eps)^2) the gain is at most 1 / (2 lambda) = 10 for lambda_max = 0.05."""
    robot = robots["planar"]
    q = np.array([0.0, 1e-5, 0.0])
    kin = Kinematics(robot)
    kin.update(q)
    s_min = np.linalg.svd(kin.ee_jacobian()[:2], compute_uv=False)[-1]
    twist = np.array([1e-3, 0, 0, 0, 0, 0])
    assert 1e-3 / s_min > 10.0  # the undamped solution would be large
    qdot = DifferentialIK(robot, "dls", posture_gain=0.0).solve(q, twist, DT)
    assert np.linalg.norm(qdot) <= 1e-3 / (2 * 0.05) * (1 + 1e-9)


def test_kin_argument_reuses_an_updated_kinematics(robots: dict[str, RobotModel]) -> None:
    """solve(q, ..., kin=K) uses K's Jacobian: with an independent Kinematics updated at q it equals
    the solve that updates its own; with K left at another posture it does not (K was used)."""
    robot = robots["panda"]
    q = robot.q_home + 0.1
    twist = np.array([0.1, 0.0, -0.1, 0.2, 0.0, 0.0])
    reference = DifferentialIK(robot, "dls").solve(q, twist, DT)  # updates its own kinematics at q
    ik = DifferentialIK(robot, "dls")
    ik.kinematics.update(robot.q_home - 0.3)  # its own kinematics elsewhere: must not be used
    kin = Kinematics(robot)
    kin.update(q)
    np.testing.assert_allclose(ik.solve(q, twist, DT, kin=kin), reference, rtol=1e-12, atol=1e-12)
    stale = Kinematics(robot)
    stale.update(robot.q_home - 0.3)
    assert np.linalg.norm(ik.solve(q, twist, DT, kin=stale) - reference) > 1e-3


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_position_ik_reaches_a_reachable_target(robots: dict[str, RobotModel], name: str) -> None:
    robot = robots[name]
    kin = Kinematics(robot)
    rng = np.random.default_rng(3)
    for _ in range(5):
        kin.update(rng.uniform(robot.q_min + 0.2, robot.q_max - 0.2))
        target = kin.ee_position().copy()
        q, err = solve_position_ik(robot, target)
        kin.update(q)
        assert err < 1e-6 and np.linalg.norm(kin.ee_position() - target) < 1e-6
        assert np.all(q >= robot.q_min) and np.all(q <= robot.q_max)


def test_position_ik_with_orientation_on_panda(robots: dict[str, RobotModel]) -> None:
    robot = robots["panda"]
    kin = Kinematics(robot)
    kin.update(robot.q_home + np.array([0.3, 0.2, -0.2, 0.3, 0.2, -0.3, 0.4]))
    position, rotation = kin.ee_position().copy(), kin.ee_rotation().copy()
    q, err = solve_position_ik(robot, position, rotation)
    kin.update(q)
    assert err < 1e-6
    assert np.linalg.norm(pin.log3(kin.ee_rotation() @ rotation.T)) < 1e-6


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_position_ik_reports_an_unreachable_target(robots: dict[str, RobotModel], name: str) -> None:
    robot = robots[name]
    q, err = solve_position_ik(robot, np.array([3.0, 0.0, 0.3]), max_iters=100)
    assert err > 1.5  # 3 m away, reach ~1 m
    assert np.all(q >= robot.q_min) and np.all(q <= robot.q_max)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"backend": "jacobian"}, r"^unknown IK backend 'jacobian'; known: dls, pink$"),
    ({"rows": (0, 7)}, r"^IK rows must be distinct twist rows in 0\.\.5"),
    ({"gain": 2.0}, r"^unknown gain\(s\) gain for IK backend 'dls'; known: posture_gain, limit_margin, "
                    r"speed_fraction, damping, "),
])
def test_ik_option_errors(robots: dict[str, RobotModel], kwargs: dict, message: str) -> None:
    with pytest.raises(RobotError, match=message):
        DifferentialIK(robots["planar"], **kwargs)


def test_pink_rejects_rows_it_cannot_express(robots: dict[str, RobotModel]) -> None:
    with pytest.raises(RobotError, match=r"pink backend cannot select rows \(0, 2\)"):
        DifferentialIK(robots["panda"], "pink", rows=(0, 2))
    assert DifferentialIK(robots["panda"], "pink", rows=(0, 1, 2)).rows == (0, 1, 2)


def _reference_dls(robot: RobotModel, rows: tuple[int, ...], q: np.ndarray, twist: np.ndarray,
                   dt: float) -> tuple[np.ndarray, bool]:
    """The DlsBackend formulas written plainly (default gains): s_min from an SVD, a dense solve, the full limit
    section on every call. Returns (qdot, whether a limit changed qdot)."""
    lam2_max, eps2, k_p = 0.05 ** 2, 0.05 ** 2, 1.0
    kin = Kinematics(robot)
    kin.update(q)
    jac, v = kin.ee_jacobian()[list(rows)], twist[list(rows)]
    z = k_p * (robot.q_home - q)

    def resolve(j: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        s = np.zeros(j.shape[0])
        s[:min(j.shape)] = np.linalg.svd(j, compute_uv=False)
        s2_min = s.min() ** 2
        lam2 = lam2_max * (1.0 - s2_min / eps2) if s2_min < eps2 else 0.0
        return z + j.T @ np.linalg.solve(j @ j.T + lam2 * np.eye(j.shape[0]), v - j @ z)

    qdot = resolve(jac, v, z)
    q_lo, q_hi, v_max = robot.q_min + MARGIN, robot.q_max - MARGIN, robot.v_max * SPEED_FRACTION
    lo_pos, hi_pos = np.minimum(q_lo - q, 0.0) / dt, np.maximum(q_hi - q, 0.0) / dt
    lo, hi = np.maximum(lo_pos, -v_max), np.minimum(hi_pos, v_max)
    if not ((qdot < lo) | (qdot > hi)).any():
        return qdot, False
    over = (qdot < lo_pos) | (qdot > hi_pos)
    fixed = np.zeros(len(q), dtype=bool)
    while over.any():
        fixed |= over
        qdot[fixed] = np.clip(qdot[fixed], lo_pos[fixed], hi_pos[fixed])
        free = ~fixed
        if not free.any():
            break
        qdot[free] = resolve(jac[:, free], v - jac[:, fixed] @ qdot[fixed], z[free])
        over = free & ((qdot < lo_pos) | (qdot > hi_pos))
    qdot /= max(1.0, float(np.max(np.abs(qdot) / v_max)))
    return np.clip(qdot, np.minimum(lo, v_max), np.maximum(hi, -v_max)), True


@pytest.mark.parametrize("name", BUILTIN_ROBOTS)
def test_dls_fast_paths_agree_with_the_plain_formulas(robots: dict[str, RobotModel], name: str) -> None:
    """400 random (q, twist): q over the whole joint range (near, at and past the soft limits), twists from 1 mm/s
    to 3 m/s, some postures near a singularity. The Cholesky and fast-limit-test paths give the reference qdot
    to 1e-12 and the same limit_hits; each path (clean, clamped, damped) occurs."""
    robot = robots[name]
    rows = (0, 1) if robot.planar else (0, 1, 2, 3, 4, 5)
    ik, kin = DifferentialIK(robot, "dls"), Kinematics(robot)
    rng = np.random.default_rng(7)
    worst, hits, damped = 0.0, 0, 0
    for k in range(400):
        q = rng.uniform(robot.q_min - 0.01, robot.q_max + 0.01) if k % 2 else \
            np.clip(robot.q_home + rng.normal(0.0, 0.3, robot.n), robot.q_min, robot.q_max)
        if robot.planar and k % 10 == 0:
            q[1:] = rng.normal(0.0, 0.02, 2)  # near the stretched (singular) posture
        twist = rng.normal(0.0, 1.0, 6) * 10.0 ** rng.uniform(-3.0, 0.5)
        qdot_ref, hit = _reference_dls(robot, rows, q, twist, DT)
        hits_before = ik.limit_hits
        qdot = ik.solve(q, twist, DT)
        assert ik.limit_hits - hits_before == int(hit)
        worst = max(worst, float(np.abs(qdot - qdot_ref).max()))
        hits += hit
        kin.update(q)
        damped += np.linalg.svd(kin.ee_jacobian()[list(rows)], compute_uv=False)[-1] < 0.05
    assert worst < 1e-12
    assert 40 < hits < 360
    assert damped > 5
