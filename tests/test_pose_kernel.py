"""The compiled pose chart (lfd.pose_kernel) against Pinocchio: SO(3)'s log near 0, anywhere and
near a half turn, its right Jacobian at every scale, the chart point and twist of one pose
(Eqs. (P1), (P3)) and a quaternion's matrix; and a pose field's twist (``pose_velocity``) against
the same maps done by Pinocchio, for every learner."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import lfd
from lfd import pose_kernel
from lfd.pose import PoseChart

TOL = 1e-12


def _axes(rng: np.random.Generator, n: int) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _angles(rng: np.random.Generator, n: int) -> np.ndarray:
    """Angles anywhere in [0, pi], near 0 (down to 1e-17 and 0) and near pi (down to pi itself)."""
    return np.concatenate([rng.uniform(0.0, np.pi, n), 10.0 ** rng.uniform(-17, -1, n), [0.0, 1e-300],
                           np.pi - 10.0 ** rng.uniform(-16, -1, n), [np.pi, np.nextafter(np.pi, 0.0)]])


def _log3(rot: np.ndarray) -> np.ndarray:
    out = np.empty(3)
    pose_kernel.log3(rot, 1.0, out, 0)
    return out


def test_log3_agrees_with_pinocchio_near_zero_anywhere_and_near_a_half_turn() -> None:
    """To 1e-12 against Pinocchio wherever Pinocchio is exact, and against the rotation vector the
    matrix was made from everywhere (within a few degrees of a half turn Pinocchio's acos loses
    digits, about eps / sin(theta)^2: there the test holds it to that, and the kernel to 1e-12)."""
    rng = np.random.default_rng(0)
    theta = _angles(rng, 400)
    u = _axes(rng, len(theta))
    for th, ax in zip(theta, u):
        rot = pin.exp3(th * ax)
        got, ref = _log3(rot), pin.log3(rot)
        true = th * ax
        if th > np.pi - 1e-6:   # a half turn: r and -r are one rotation
            true = true if np.dot(true, got) >= 0 else -true
            ref = ref if np.dot(ref, got) >= 0 else -ref
        # Pinocchio's acos branch near a half turn (its own half-turn branch starts at eps^(1/3))
        acos_band = np.pi - 0.1 < th and np.cos(th) >= -1.0 + 6.1e-6
        pin_err = 4.0 * np.finfo(float).eps / np.sin(th) ** 2 if acos_band else 0.0
        assert np.abs(got - true).max() <= TOL, (th, got, true)
        assert np.abs(got - ref).max() <= max(TOL, pin_err), (th, got, ref)
    # a rotation that is orthonormal only to round-off is renormalised first, as Pinocchio does
    rot = pin.exp3(np.array([0.3, -1.1, 0.4])) * (1.0 + 1e-9)
    np.testing.assert_allclose(_log3(rot), pin.log3(rot), rtol=0, atol=TOL)


def test_right_jacobian_agrees_with_pinocchio_at_every_scale() -> None:
    rng = np.random.default_rng(1)
    norms = np.concatenate([[0.0, 1e-300, 1e-20, 1e-9, 1.2e-4, 1.23e-4, 1.3e-4], 10.0 ** rng.uniform(-8, 1, 300),
                            [np.pi, 2 * np.pi, 10.0]])
    for n, ax in zip(norms, _axes(rng, len(norms))):
        r, v = n * ax, rng.normal(size=3)
        got = np.array(pose_kernel.jexp3(r[0], r[1], r[2], v, 0))
        np.testing.assert_allclose(got, pin.Jexp3(r) @ v, rtol=0, atol=TOL)


def test_chart_point_twist_and_quaternion_agree_with_pinocchio() -> None:
    """PoseChart.point / point_of / twist (one compiled call each) against Eqs. (P1) and (P3) done
    with Pinocchio's log3, Jexp3 and Quaternion."""
    rng = np.random.default_rng(2)
    q_goal = rng.normal(size=4)
    chart = PoseChart.at(q_goal / np.linalg.norm(q_goal))
    for _ in range(300):
        x, zdot, q = rng.normal(size=3), rng.normal(size=6), rng.normal(size=4)
        rot = pin.exp3(rng.uniform(0.0, 3.0) * _axes(rng, 1)[0])
        z = chart.point(x, rot)
        np.testing.assert_array_equal(z[:3], x)
        np.testing.assert_allclose(z[3:], chart.length * pin.log3(chart.goal_rotation.T @ rot), rtol=0, atol=TOL)
        tw = chart.twist(z, zdot)
        omega = chart.goal_rotation @ pin.Jexp3(-z[3:] / chart.length) @ zdot[3:] / chart.length
        np.testing.assert_allclose(tw, np.concatenate([zdot[:3], omega]), rtol=0, atol=TOL)
        rq = pin.Quaternion(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix()
        out = np.empty((3, 3))
        pose_kernel.quaternion_rotation(q, out)
        np.testing.assert_allclose(out, rq, rtol=0, atol=4e-15)
        np.testing.assert_allclose(chart.point_of(x, q), chart.point(x, rq), rtol=0, atol=TOL)
        # one rotation (compiled) and a batch of them (Pinocchio) give the same coordinates
        np.testing.assert_allclose(chart.rotation_coordinates(rot), chart.rotation_coordinates(rot[None])[0],
                                   rtol=0, atol=TOL)
    # lists and integers are taken as floats
    np.testing.assert_allclose(chart.point([1, 2, 3], np.eye(3).tolist()),
                               chart.point(np.array([1.0, 2, 3]), np.eye(3)))


def test_a_degenerate_pose_gives_nan_not_an_error() -> None:
    chart = PoseChart.at(np.array([1.0, 0.0, 0.0, 0.0]))
    assert np.isnan(chart.point_of(np.zeros(3), np.zeros(4))[3:]).all()
    assert np.isnan(chart.point(np.zeros(3), np.full((3, 3), np.nan))[3:]).all()


@pytest.mark.parametrize("learner", ["node", "contraction", "tracking"])
def test_pose_velocity_is_the_chart_and_the_field(learner: str) -> None:
    """``pose_velocity`` (Eq. (P1), the field, Eq. (P3)) against the same maps by Pinocchio."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 40)
    axis = np.array([0.0, 0.6, 0.8])
    q = np.stack([pin.Quaternion(pin.exp3(0.8 * (1.0 - s) * axis)).coeffs()[[3, 0, 1, 2]] for s in t])
    x = np.stack([0.3 + 0.1 * np.sin(3 * t), 0.1 * t, 0.4 - 0.05 * t], -1)
    demos = lfd.DemoSet(np.stack([t, t]), np.stack([x, x + 0.01]), q=np.stack([q, q]))
    field = lfd.train(learner, demos, iterations=2) if learner != "tracking" else lfd.train(learner, demos)
    chart = field.chart
    assert chart is not None
    for _ in range(10):
        p, qq = x[20] + 0.01 * rng.normal(size=3), q[20] + 0.05 * rng.normal(size=4)
        rot = pin.Quaternion(qq[0], qq[1], qq[2], qq[3]).normalized().toRotationMatrix()
        z = np.concatenate([p, chart.length * pin.log3(chart.goal_rotation.T @ rot)])
        zdot = field(z)
        omega = chart.goal_rotation @ pin.Jexp3(-z[3:] / chart.length) @ zdot[3:] / chart.length
        np.testing.assert_allclose(field.pose_velocity(p, qq), np.concatenate([zdot[:3], omega]),
                                   rtol=1e-10, atol=1e-12)
