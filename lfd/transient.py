"""The contraction learners' guarantee checked as stated: Eq. (18) with its constant, sampled far beyond
the demos.

For a field built as a bounded flow phi of a latent field h (``lfd.learners.contraction``, Eqs. (C2)-(C3),
and ``lfd.learners.contracting_node``, Eqs. (N1)-(N2)) the theorem of docs/equations.md needs three
conditions, which the field reads from its trained weights (``theorem_conditions``): sym(A) <= -lambda I
(the largest eigenvalue of sym(A) + lambda I at most round-off), the ridge gains D >= 0, and the flow's
singular-value bounds with s_hi / s_lo <= sqrt(KAPPA). Under them every pair of trajectories obeys

    Eq. (18) with its constant: |x1(t) - x2(t)| <= sqrt(b/a) e^(-lambda t) |x1(0) - x2(0)|,

which ``transient_growth`` samples: pairs of nearby starts on the checked box and 10^3 box sizes away,
each pair split along the direction where the bound is tightest (the top eigenvector of M(x0): the
displacement that is longest in the metric for its length), followed by RK4 in float64, and the worst
ratio |dx(t)| e^(lambda t) / |dx(0)| compared with sqrt(b/a).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lfd.field import VelocityField

FAR = 1000.0         # box sizes: the far starts lie this far from the box's centre
PAIRS = 32           # pairs on the box, and as many far out
PAIR_STEP = 1e-6     # |dx(0)| as a fraction of the box's diagonal
STEPS = 1000         # RK4 steps over the horizon
HORIZON_RATES = 6.0  # the horizon is this many 1/rate (the bound then has decayed by e^6)
SLACK = 1e-6         # relative allowance for the finite-difference pair and the solver's error


def transient_growth(field: VelocityField, lo: np.ndarray, hi: np.ndarray, pairs: int = PAIRS,
                     seed: int = 0) -> dict[str, Any]:
    """Eq. (18) with its constant, sampled (module docstring) for a field that states ``metric_bounds``.

    lo, hi : arrays, shape (d,), the box, user units. Returns ``holds`` (every ratio within sqrt(b/a)),
    ``worst_near`` and ``worst_far`` (the largest |dx(t)| e^(rate t) / |dx(0)| on the box and far out),
    ``overshoot`` sqrt(b/a), ``far`` (box sizes), ``pairs`` (per group) and ``horizon_s``.
    """
    bounds = field.metric_bounds
    if bounds is None:
        raise ValueError(f"{field.learner}: the field states no metric bounds")
    a, b = bounds
    overshoot = math.sqrt(b / a)
    rate = float(field.config["rate"])
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    d, size = lo.shape[0], float(np.linalg.norm(hi - lo))
    rng = np.random.default_rng(seed)
    near = lo + rng.random((pairs, d)) * (hi - lo)
    u = rng.normal(size=(pairs, d))
    far = (lo + hi) / 2 + FAR * size * u / np.linalg.norm(u, axis=1, keepdims=True)
    starts = np.vstack([near, far])
    step = PAIR_STEP * size
    metric = field.metric(starts)  # type: ignore[attr-defined]  # M(x0), (2 P, d, d): a metric field
    direction = np.linalg.eigh(metric)[1][:, :, -1]                      # M's top eigenvector at each start
    horizon = HORIZON_RATES / rate
    t = np.linspace(0.0, horizon, STEPS + 1)
    both = field.rollout(np.vstack([starts, starts + step * direction]), t, method="rk4")   # one batch
    x1, x2 = both[:len(starts)], both[len(starts):]
    gap = np.linalg.norm(x2 - x1, axis=-1) * np.exp(rate * t)[None, :] / step   # (2 P, T)
    worst = gap.max(axis=1)
    worst_near, worst_far = float(worst[:pairs].max()), float(worst[pairs:].max())
    finite = bool(np.isfinite(worst).all())
    return {"holds": finite and max(worst_near, worst_far) <= overshoot * (1 + SLACK) + SLACK,
            "worst_near": worst_near, "worst_far": worst_far, "overshoot": overshoot, "far": FAR,
            "pairs": pairs, "horizon_s": horizon}
