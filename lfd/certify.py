"""A numerical contraction certificate: check Eq. (C1) of ``lfd.learners.contraction`` on a dense grid.

For a field dx/dt = f(x) and a metric M(x), the contraction condition with rate lambda is

    Eq. (C1): Q(x) = J_f' M + M J_f + dM/dt <= -2 lambda M,   dM/dt = sum_k (dM/dx_k) f_k,

that is, the largest generalised eigenvalue of (Q, M),

    Eq. (K1): g(x) = max eig( L^-1 Q L^-T ),   M = L L' (Cholesky),

is at most -2 lambda. At every grid point J_f and dM/dt come from forward-mode autodiff of the
field's torch module in float64 (``torch.func.jvp`` on the whole batch, one pass per column of
J_f: the module must act on each row on its own, as every learner's does); nothing is
finite-differenced. (``vmap(jacfwd(.))`` is avoided: in torch 2.13 it gets ``linalg.solve``
wrong.) A field with a metric (``metric_normalized_torch``, e.g. the contraction learner's
J_phi' J_phi) is checked in it with its own rate; any other field (the NODE) in the identity
metric M = I, where g(x) = max eig(J_f + J_f'), with the requested rate or ``IDENTITY_RATE``.

Units: g is invariant to the isotropic normalisation x_n = (x - goal) / s (J_f is unchanged and M
scales by 1/s^2 on both sides), so the check runs on normalised coordinates; the reported point
is in user units and the metric bounds a, b are those of M in user units.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np
import torch
from torch.func import jvp

from lfd.errors import ConfigError
from lfd.field import VelocityField

DEFAULT_SAMPLES = 20_000
DEFAULT_TOLERANCE = 1e-6   # relative: float64 round-off in g grows with cond(M); measured 4e-8 |bound| at cond 1e6
IDENTITY_RATE = 0.05       # 1/s: the rate checked for a field without a metric unless one is asked for
BOX_GROWTH = 0.5           # the default box is the demos' bounding box grown by 50%
CHUNK = 8192               # points per vectorised evaluation


@dataclass(frozen=True)
class Certificate:
    """The outcome of ``certify``.

    worst : max over the grid of g(x), Eq. (K1), 1/s; bound : -2 rate
    certified : worst <= bound + slack, slack = tolerance max(1, |bound|) (round-off allowance, 1/s)
    argmax : the grid point of ``worst`` (user units); metric_min_eig, metric_max_eig : observed a and b of M
    box : [lo, hi] (user units); n_points : grid size; metric : "learned" or "identity"
    n_invalid : points where M or Q was not finite or M not numerically positive definite (g = inf)
    """

    learner: str
    metric: str
    rate: float
    bound: float
    tolerance: float
    slack: float
    worst: float
    margin: float
    argmax: list[float]
    metric_min_eig: float
    metric_max_eig: float
    n_points: int
    n_invalid: int
    box: list[list[float]]
    certified: bool
    elapsed_s: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        """Human-readable lines for the command line."""
        verdict = "CERTIFIED" if self.certified else "NOT CERTIFIED"
        pt = ", ".join(f"{v:.4g}" for v in self.argmax)
        return (f"{verdict}: contraction rate {self.rate:g}/s in the {self.metric} metric "
                f"({self.learner} model)\n"
                f"  worst generalised eigenvalue {self.worst:.6g} vs bound -2*rate = {self.bound:.6g} "
                f"(slack {self.slack:.3g}), at ({pt})\n"
                f"  metric bounds a = {self.metric_min_eig:.4g}, b = {self.metric_max_eig:.4g} "
                f"(b/a = {self.metric_max_eig / self.metric_min_eig:.4g}); "
                f"{self.n_points} points in box {_fmt_box(self.box)}; {self.elapsed_s:.2f} s"
                + (f"\n  {self.n_invalid} points where the metric is not numerically positive definite"
                   if self.n_invalid else ""))


def _fmt_box(box: list[list[float]]) -> str:
    return " x ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(*box))


def grid(lo: np.ndarray, hi: np.ndarray, samples: int) -> np.ndarray:
    """A regular grid with m = ceil(samples^(1/d)) points per axis, corners included.

    lo, hi : arrays, shape (d,); returns shape (m^d, d).
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    m = max(2, math.ceil(samples ** (1.0 / lo.shape[0]) - 1e-9))
    axes = [np.linspace(a, b, m) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, lo.shape[0])


def default_box(field: VelocityField, grow: float = BOX_GROWTH) -> tuple[np.ndarray, np.ndarray] | None:
    """The training demos' box from the model's history, grown by ``grow`` times its size, or None.

    Reads ``history["demo_box"]`` (user units), which ``lfd.train`` stores for every learner.
    """
    h = field.history
    if "demo_box" in h:
        lo, hi = (np.asarray(v, dtype=np.float64) for v in h["demo_box"])
    else:
        return None
    pad = (hi - lo) * grow / 2
    return lo - pad, hi + pad


def generalized_eigenvalues(field: VelocityField, xn: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """g(x) of Eq. (K1) and the eigenvalues of M_n at normalised points xn, shape (B, d).

    Returns g, shape (B,), and eig(M_n), shape (B, d) (identity metric: all ones). Where M_n or
    Q is not finite, or M_n is not numerically positive definite, g = +inf (not certified).
    """
    module = field.module
    d = xn.shape[1]
    eye = torch.eye(d, dtype=xn.dtype)
    f = module(xn)
    jf = torch.stack([jvp(module, (xn,), (eye[k].expand_as(xn),))[1] for k in range(d)], dim=-1)  # (B, d, d)
    metric_fn: Callable[[torch.Tensor], torch.Tensor] | None = getattr(field, "metric_normalized_torch", None)
    if metric_fn is None:
        q = jf + jf.transpose(1, 2)
        return torch.linalg.eigvalsh(q)[:, -1], torch.ones(xn.shape[0], d, dtype=xn.dtype)
    m, m_dot = jvp(metric_fn, (xn,), (f,))                               # M, dM/dt = (dM/dx) f
    q = jf.transpose(1, 2) @ m + m @ jf + m_dot
    bad = ~torch.isfinite(m).flatten(1).all(1) | ~torch.isfinite(q).flatten(1).all(1)
    eye_b = eye.expand_as(m)
    m_ok = torch.where(bad[:, None, None], eye_b, m)
    eig_m = torch.where(bad[:, None], math.nan, torch.linalg.eigvalsh(m_ok))
    low, info = torch.linalg.cholesky_ex(m_ok)
    bad |= info != 0                                                     # M not numerically positive definite
    low = torch.where(bad[:, None, None], eye_b, low)
    y = torch.linalg.solve_triangular(low, torch.where(bad[:, None, None], eye_b, q), upper=False)  # L^-1 Q
    g = torch.linalg.solve_triangular(low, y.transpose(1, 2), upper=False)  # L^-1 Q' L^-T
    g = torch.linalg.eigvalsh(0.5 * (g + g.transpose(1, 2)))[:, -1]
    return torch.where(bad, torch.full_like(g, math.inf), g), eig_m


def certify(field: VelocityField, lo: np.ndarray | None = None, hi: np.ndarray | None = None,
            samples: int = DEFAULT_SAMPLES, rate: float | None = None,
            tolerance: float = DEFAULT_TOLERANCE) -> Certificate:
    """Check Eq. (C1) on a grid of at least ``samples`` points in the box [lo, hi] (user units).

    Without a box, the training demos' box grown by 50% (``default_box``). ``rate`` defaults to
    the field's own (``field.rate``) or, for a field without a metric, ``IDENTITY_RATE``.
    Raises ConfigError for a missing or empty box, a bad rate, sample count or tolerance.
    """
    if lo is None or hi is None:
        box = default_box(field)
        if box is None:
            raise ConfigError("no box to certify in: the model's history has no demo box; give --box or --demos")
        lo, hi = box
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1), np.asarray(hi, dtype=np.float64).reshape(-1)
    if lo.shape != (field.dim,) or hi.shape != (field.dim,):
        raise ConfigError(f"the box must have {field.dim} lower and {field.dim} upper bounds for this "
                          f"{field.dim}-D model, got {lo.size} and {hi.size}")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()):
        raise ConfigError(f"the box must be finite with max > min on every axis, got {lo.tolist()} .. {hi.tolist()}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ConfigError(f"samples must be an integer >= 2, got {samples!r}")
    if rate is None:
        rate = float(getattr(field, "rate", IDENTITY_RATE))
    if not (math.isfinite(rate) and rate > 0):
        raise ConfigError(f"rate must be a positive number (1/s), got {rate!r}")
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise ConfigError(f"tolerance must be a non-negative number, got {tolerance!r}")

    t0 = time.perf_counter()
    pts = grid(lo, hi, samples)
    xn_all = torch.from_numpy(field.norm.to_norm(pts))
    worst, where, invalid = -math.inf, 0, 0
    a, b = math.inf, -math.inf
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small per-point matrices: one thread is as fast and immune to oversubscription
    try:
        for start in range(0, len(pts), CHUNK):
            g, eig_m = generalized_eigenvalues(field, xn_all[start:start + CHUNK])
            invalid += int((~torch.isfinite(g)).sum())
            i = int(torch.argmax(torch.nan_to_num(g, nan=math.inf)))
            if float(g[i]) > worst:
                worst, where = float(g[i]), start + i
            ok = torch.isfinite(eig_m).all(1)
            if ok.any():
                a, b = min(a, float(eig_m[ok, 0].min())), max(b, float(eig_m[ok, -1].max()))
    finally:
        torch.set_num_threads(threads)
    has_metric = hasattr(field, "metric_normalized_torch")
    s2 = field.norm.scale ** 2 if has_metric else 1.0
    bound = -2.0 * rate
    slack = tolerance * max(1.0, abs(bound))
    return Certificate(
        learner=field.learner, metric="learned" if has_metric else "identity", rate=float(rate),
        bound=bound, tolerance=float(tolerance), slack=slack, worst=worst, margin=bound - worst,
        argmax=[float(v) for v in pts[where]], metric_min_eig=a / s2, metric_max_eig=b / s2,
        n_points=int(len(pts)), n_invalid=invalid, box=[lo.tolist(), hi.tolist()], certified=bool(worst <= bound + slack),
        elapsed_s=time.perf_counter() - t0)
