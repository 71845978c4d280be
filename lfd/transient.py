"""The contraction learners' guarantee checked as stated: the structural conditions read from the
weights, and Eq. (18) with its constant sampled far beyond the demos.

For a field built as a bounded flow phi of a latent field h (``lfd.learners.contraction``, Eqs. (C2)-(C3),
and ``lfd.learners.contracting_node``, Eqs. (N1)-(N2)) the theorem of docs/equations.md needs three
conditions, each read here from the trained weights (``structural_conditions``): sym(A) <= -lambda I
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
import torch

from lfd.field import VelocityField

FAR = 1000.0         # box sizes: the far starts lie this far from the box's centre
PAIRS = 32           # pairs on the box, and as many far out
PAIR_STEP = 1e-6     # |dx(0)| as a fraction of the box's diagonal
STEPS = 1000         # RK4 steps over the horizon
HORIZON_RATES = 6.0  # the horizon is this many 1/rate (the bound then has decayed by e^6)
SLACK = 1e-6         # relative allowance for the finite-difference pair and the solver's error


def structural_conditions(field: VelocityField) -> dict[str, Any] | None:
    """The theorem's conditions read from ``field``'s weights, or None for a field not built this way.

    Returns ``holds``, ``sym_a_max`` (the largest eigenvalue of sym(A) + lambda I, <= 0 needed),
    ``ridge_min`` (the smallest ridge gain, >= 0 needed; None without a ridge term), ``flow_ratio``
    (s_hi / s_lo of the flow) and ``sqrt_kappa`` (the bound it must stay under); for non-finite
    weights ``holds`` is False and the values NaN.
    """
    module = getattr(field, "module", None)
    if module is None or not hasattr(module, "latent_matrix") or not hasattr(module, "flow"):
        return None
    if not all(bool(torch.isfinite(p).all()) for p in module.parameters()):
        return {"holds": False, "sym_a_max": math.nan, "ridge_min": None, "flow_ratio": math.nan,
                "sqrt_kappa": math.nan}
    with torch.no_grad():
        a = module.latent_matrix().double()
        rate = float(field.config["rate"])   # the stated rate, whatever the module was built with
        sym = (a + a.T) / 2 + rate * torch.eye(a.shape[0], dtype=a.dtype)
        sym_max = float(torch.linalg.eigvalsh(sym).max())
        gain = module.ridge_gain() if hasattr(module, "ridge_gain") else None
        ridge_min = None if gain is None or gain.numel() == 0 else float(gain.min())
    s_lo, s_hi = module.flow.singular_value_bounds()
    kappa = float(field.config.get("max_condition", math.inf))
    sqrt_kappa = math.sqrt(kappa) if math.isfinite(kappa) else math.inf
    tol = 1e-12 * max(1.0, float(torch.linalg.matrix_norm(a, ord=2)))
    holds = (sym_max <= tol and (ridge_min is None or ridge_min >= 0.0)
             and math.isfinite(s_hi / s_lo) and s_hi / s_lo <= sqrt_kappa * (1 + 1e-9))
    return {"holds": bool(holds), "sym_a_max": sym_max, "ridge_min": ridge_min, "flow_ratio": s_hi / s_lo,
            "sqrt_kappa": sqrt_kappa}


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
