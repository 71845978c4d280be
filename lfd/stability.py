"""The check of a stated Lyapunov function (the stable NODE's, Eqs. (L1)-(L3) of docs/equations.md):
its analytic conditions from the weights, then the decrease dV/dt <= -alpha(V) V sampled on the
box and far out, in every direction, where a construction is most likely to fail.

The far points lie on ``FAR_DIRECTIONS`` seeded unit directions at normalised radii log-spaced from
``NEAR_RADIUS`` (at the goal, where round-off meets the correction's division by |grad V|^2) to
``FAR_RADIUS`` (a million demo sizes away). A point breaks the decrease where dV/dt > -alpha(V) V
(1 - ``ROUND_OFF``), and V's bounds where V leaves [s_lo^2 |x_n|^2, s_hi^2 |x_n|^2] by more than the
same relative slack.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lfd.field import VelocityField

__all__ = ["check_lyapunov", "far_points"]

FAR_DIRECTIONS = 2048
NEAR_RADIUS = 1e-6
FAR_RADIUS = 1e6
RADII = 37             # three per decade
ROUND_OFF = 1e-8       # relative slack of the sampled checks (float64 sums of a few dozen terms)
SEED = 0


def far_points(field: VelocityField, directions: int = FAR_DIRECTIONS) -> np.ndarray:
    """Points at normalised radii NEAR_RADIUS .. FAR_RADIUS on ``directions`` seeded unit directions,
    in user units, shape (directions * RADII, d)."""
    u = np.random.default_rng(SEED).normal(size=(directions, field.dim))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = np.geomspace(NEAR_RADIUS, FAR_RADIUS, RADII)
    return field.norm.from_norm((r[:, None, None] * u[None]).reshape(-1, field.dim))


def check_lyapunov(field: VelocityField, box_points: np.ndarray) -> dict[str, Any] | None:
    """The stated Lyapunov function of ``field`` checked, or None where it states none.

    box_points : array, shape (P, d), user units: points of the box to check besides ``far_points``.
    Returns the field's ``stability_constants`` with:

    - ``analytic_holds``: its analytic conditions hold (``holds`` of the constants);
    - ``worst_ratio``: max over the points of dV/dt / (alpha(V) V) (at most -1 by Eq. (L2)), and
      ``argmax`` its point (user units); ``n_decrease_fails``: points with a ratio above -1 + ROUND_OFF;
    - ``n_bound_fails``: points where V leaves s_lo^2 |x_n|^2 .. s_hi^2 |x_n|^2;
    - ``n_invalid``: points where V, dV/dt or alpha(V) is not finite;
    - ``n_points``, ``far_radius`` (user units) and ``holds``: every check passed.
    """
    constants = field.stability_constants()
    if constants is None:
        return None
    pts = np.concatenate([np.asarray(box_points, dtype=np.float64).reshape(-1, field.dim), far_points(field)])
    values = field.lyapunov(pts)
    assert values is not None, "a field that states Lyapunov constants states its V"
    v, dv, alpha = values
    finite = np.isfinite(v) & np.isfinite(dv) & np.isfinite(alpha)
    xn = field.norm.to_norm(pts)
    r2 = np.sum(xn * xn, axis=1)
    moving = finite & (v > 0)
    with np.errstate(all="ignore"):
        ratio = np.where(moving, dv / (alpha * v), -math.inf)
    decrease_fails = int(np.sum(ratio > -1.0 + ROUND_OFF))
    s_lo, s_hi = float(constants["s_lo"]), float(constants["s_hi"])
    outside = (v < s_lo ** 2 * r2 * (1 - ROUND_OFF)) | (v > s_hi ** 2 * r2 * (1 + ROUND_OFF))
    bound_fails = int(np.sum(finite & outside))
    worst = int(np.argmax(ratio))
    invalid = int(np.sum(~finite))
    holds = bool(constants["holds"]) and decrease_fails == 0 and bound_fails == 0 and invalid == 0
    return {**constants, "analytic_holds": bool(constants["holds"]), "worst_ratio": float(ratio[worst]),
            "argmax": [float(c) for c in pts[worst]], "n_decrease_fails": decrease_fails,
            "n_bound_fails": bound_fails, "n_invalid": invalid, "n_points": int(len(pts)),
            "far_radius": FAR_RADIUS * float(field.norm.scale), "holds": holds}
