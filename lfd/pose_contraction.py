"""The contraction of a pose field, checked on pairs of poses by their geodesic distance.

A pose field is a field on the chart z = (p, l r), r = log(R_g^T R) (``lfd.pose``, Eq. (P1)). Its
learner's guarantee holds in the chart: for the goal-contraction learner, with metric bounds a, b and
rate lambda,

    |z_1(t) - z_2(t)| <= sqrt(b/a) exp(-lambda t) |z_1(0) - z_2(0)|                 (Eq. (18)),

and for the tracking learner the error to the reference decays like exp(-K t) (Eq. (T5)). By
Eq. (P4) the geodesic angle between the two orientations is at most the chart distance of their
rotation parts over l, so the same bound holds for the pose distance

    D(P_1, P_2) = sqrt(|p_1 - p_2|^2 + l^2 angle(R_1, R_2)^2) <= |z_1 - z_2|,

in particular for the angle to the goal orientation. ``check_pose_contraction`` samples what the
statement covers and where it is most likely to fail: pairs near each other and far apart, starts up
to a hair below a half turn from the goal, positions in the demos' box grown by half its size, and
follows them (the exact flow of Eq. (C4) for the goal-contraction learner, else RK4). It also
reports the pairs that straddle the cut locus (orientations a half
turn from the goal, close to each other but on opposite sides): there the chart distance is large
while the geodesic one is small, so the bound, stated in the chart distance, says nothing about the
geodesic one; such pairs separate before they converge (the obstruction of ``lfd.pose``).
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import pinocchio as pin

from lfd.field import StateSpace, VelocityField
from lfd.pose import PoseChart, geodesic_angle

PAIRS = 256                 # pairs of each kind (near, far)
HORIZON_RATES = 5.0         # follow pairs for 5 / rate seconds ...
MAX_HORIZON_S = 30.0        # ... at most
STEPS = 600                 # RK4 steps over the horizon
ANTIPODE_MARGIN = 1e-2      # rad: starts reach to pi minus this from the goal orientation
REL_TOLERANCE = 1e-6        # the bound is checked as measured <= bound (1 + tol) + floor
ABS_FLOOR = 1e-9            # chart units: the integrator's floor


def _random_rotations(rng: np.random.Generator, goal: np.ndarray, n: int, max_angle: float) -> np.ndarray:
    """n rotations R_g exp(theta u), theta uniform in [0, max_angle], u uniform on the sphere; (n, 3, 3)."""
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    theta = rng.uniform(0.0, max_angle, n)
    return np.stack([goal @ pin.exp3(a * v) for a, v in zip(theta, u)])


def check_pose_contraction(field: VelocityField, n_pairs: int = PAIRS, seed: int = 0) -> dict[str, Any]:
    """Sample the stated contraction of a pose field (module docstring) on pairs of poses.

    Parameters
    ----------
    field : VelocityField
        A pose field (``StateSpace.POSE``): one built with a metric (``contraction_metric``, the
        goal-contraction learner's) is checked against its ``rate`` and overshoot sqrt(b/a) of its
        ``metric_bounds``; any other is followed and reported, not checked.
    n_pairs : int
        Pairs of each kind: near (the second pose 1 cm and 0.05 rad from the first) and far
        (independent).
    seed : int
        Seeds the poses.

    Returns
    -------
    dict
        ``checked`` (bool: a stated bound exists), ``holds`` (bool), ``rate`` (1/s), ``overshoot``,
        ``worst_ratio`` (max over pairs and times of D(t) / (overshoot exp(-rate t) |z_1(0) - z_2(0)|)),
        ``worst_chart_ratio`` (the same with |z_1(t) - z_2(t)| for D(t)),
        ``geodesic_decay_rate`` (the smallest sampled -log(angle(T) / angle(0)) / T over pairs, 1/s),
        ``goal_worst_ratio`` (the same bound on the pose distance to the goal), ``cut_locus_growth``
        (the largest growth of the geodesic angle between pairs straddling the cut locus), ``n_pairs``,
        ``horizon_s``, ``max_start_angle_deg``, ``rotation_length_m_per_rad`` (l).
    """
    if field.space is not StateSpace.POSE or field.demo_box is None:
        raise ValueError("check_pose_contraction needs a pose field that stores its demo box")
    chart = cast(PoseChart, field.chart)
    rng = np.random.default_rng(seed)
    lo, hi = field.demo_box
    pad = (hi[:3] - lo[:3]) * 0.25
    plo, phi = lo[:3] - pad, hi[:3] + pad
    rate = 0.0 if field.rate is None else float(field.rate)
    bounds = field.metric_bounds
    overshoot = 1.0 if bounds is None else float(bounds[1] / bounds[0]) ** 0.5
    # the pair bound is that of a field built with a metric (the goal-contraction learner's); the
    # tracking learner's (Eq. (T5)) is to its reference, checked by
    # ``lfd.learners.tracking.check_tracking_contraction`` in the chart
    checked = rate > 0 and field.contraction_metric() is not None
    horizon = min(HORIZON_RATES / rate, MAX_HORIZON_S) if rate > 0 else MAX_HORIZON_S
    t = np.linspace(0.0, horizon, STEPS + 1)
    max_angle = math.pi - ANTIPODE_MARGIN
    l = chart.length
    # far pairs: independent poses; near pairs: a small displacement and turn of the first
    p1 = rng.uniform(plo, phi, size=(2 * n_pairs, 3))
    r1 = _random_rotations(rng, chart.goal_rotation, 2 * n_pairs, max_angle)
    p2 = np.concatenate([rng.uniform(plo, phi, size=(n_pairs, 3)),
                         p1[n_pairs:] + 0.01 * _unit(rng, n_pairs)])
    r2 = np.concatenate([_random_rotations(rng, chart.goal_rotation, n_pairs, max_angle),
                         np.stack([r @ pin.exp3(0.05 * u) for r, u in zip(r1[n_pairs:], _unit(rng, n_pairs))])])
    z1 = np.concatenate([p1, chart.rotation_coordinates(r1)], axis=1)
    z2 = np.concatenate([p2, chart.rotation_coordinates(r2)], axis=1)
    za, zb = _rollout(field, z1, t), _rollout(field, z2, t)                      # (B, T, 6)
    # the pose distance D(t) against the chart bound
    ang = geodesic_angle(chart.rotations(za), chart.rotations(zb))             # (B, T)
    dist = np.sqrt(np.sum((za[..., :3] - zb[..., :3]) ** 2, -1) + (l * ang) ** 2)
    d0 = np.linalg.norm(z1 - z2, axis=1)
    bound = overshoot * np.exp(-rate * t)[None, :] * d0[:, None]
    ratio = float(np.max(dist / np.maximum(bound * (1 + REL_TOLERANCE) + ABS_FLOOR, 1e-300)))
    chart_ratio = float(np.max(np.linalg.norm(za - zb, axis=-1) / (bound * (1 + REL_TOLERANCE) + ABS_FLOOR)))
    with np.errstate(divide="ignore", invalid="ignore"):
        decay = -np.log(ang[:, -1] / ang[:, 0]) / horizon
    decay = decay[np.isfinite(decay)]
    # the pose distance to the goal (p_g, R_g), whose chart point is (p_g, 0)
    goal_z = np.asarray(field.goal, dtype=np.float64)
    to_goal = np.sqrt(np.sum((za[..., :3] - goal_z[:3]) ** 2, -1) + (l * chart.angle_to_goal(za)) ** 2)
    g0 = np.linalg.norm(z1 - goal_z, axis=1)
    goal_ratio = float(np.max(to_goal / (overshoot * np.exp(-rate * t)[None, :] * g0[:, None]
                                         * (1 + REL_TOLERANCE) + ABS_FLOOR)))
    # pairs straddling the cut locus: a half turn from the goal about u and about -u, a hair apart
    u = _unit(rng, 32)
    a = math.pi - 0.02
    c1 = np.stack([chart.goal_rotation @ pin.exp3(a * v) for v in u])
    c2 = np.stack([chart.goal_rotation @ pin.exp3(-a * v) for v in u])
    base = np.full((32, 3), 0.5) * (plo + phi)
    ca = _rollout(field, np.concatenate([base, chart.rotation_coordinates(c1)], axis=1), t)
    cb = _rollout(field, np.concatenate([base, chart.rotation_coordinates(c2)], axis=1), t)
    cut = geodesic_angle(chart.rotations(ca), chart.rotations(cb))
    finite = bool(np.isfinite(za).all() and np.isfinite(zb).all())
    holds = finite and (not checked or (ratio <= 1.0 and chart_ratio <= 1.0 and goal_ratio <= 1.0))
    return {"checked": bool(checked), "holds": bool(holds), "rate": rate, "overshoot": overshoot,
            "worst_ratio": ratio, "worst_chart_ratio": chart_ratio, "goal_worst_ratio": goal_ratio,
            "geodesic_decay_rate": float(decay.min()) if decay.size else math.nan,
            "cut_locus_growth": float(np.max(cut / cut[:, :1])), "n_pairs": 2 * n_pairs, "horizon_s": horizon,
            "max_start_angle_deg": math.degrees(max_angle), "rotation_length_m_per_rad": l}


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _rollout(field: VelocityField, z0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Chart trajectories, shape (B, T, 6), from z0 (B, 6) over t (T,): the field's exact flow where it
    has one (the contraction field's Eq. (C4), ``closed_form_rollout``), else its RK4 ``rollout``
    (with the phase for tracking)."""
    with np.errstate(all="ignore"):
        exact = field.closed_form_rollout(z0, t)
        return field.rollout(z0, t, method="rk4") if exact is None else np.asarray(exact)
