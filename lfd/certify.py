"""An honest contraction certificate: analytic bounds where the model has them, a dense check of
Eq. (C1) everywhere, and a verdict that is never stronger than what was shown.

For a field dx/dt = f(x) (the paper's Eq. (15)) and a metric M(x), the contraction condition with
rate lambda (the paper's Eq. (17), Eq. (C1) with dM/dt) is checked on a grid (above 3 dimensions:
the box's corners and seeded uniform samples) as the largest generalised eigenvalue g(x) of
(J_f' M + M J_f + dM/dt, M), Eq. (K1), against -2 lambda up to the round-off slack of Eq. (K2), with
J_f and dM/dt from forward-mode autodiff in float64. A field built with a metric
(``contraction_metric``) is checked in it with its own rate, any other (the NODE) in the identity
metric. ``certified`` is claimed only where it is proven: analytic bounds that make Eq. (C1) hold
on all of R^d, confirmed by the grid; or a bound between the grid points (``jacobian_lipschitz_bound``)
that closes the gaps ("not proven" where it is too loose, "not certified" where a grid point
fails, a trajectory from the box diverges or anything is NaN or inf). A field with a phase is
certified by its own stated property. Whatever the check, a field whose autonomous view has a
spurious attractor, a closed orbit or starts that escape the box (``lfd.equilibria``) is "not
certified". A field with a stated Lyapunov function (the stable NODE) is certified by it instead
(``lfd.stability``: its analytic conditions, the decrease sampled on the box and far out). The
reasoning in full: docs/equations.md, Eqs. (K1)-(K2), (E1)-(E4) and (L1)-(L3).

References
----------
Lohmiller, W., Slotine, J.-J. E. (1998). On contraction analysis for non-linear systems.
Automatica 34(6), 683-696. doi:10.1016/S0005-1098(98)00019-3
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any, cast

import numpy as np
import torch
from torch.func import jvp

from lfd.equilibria import EquilibriumReport, check_box, find_equilibria
from lfd.errors import ConfigError
from lfd.field import FieldKind, StateSpace, VelocityField, by_kind
from lfd.pose_contraction import PAIRS, check_pose_contraction
from lfd.stability import ROUND_OFF, check_lyapunov
from lfd.threads import torch_threads
from lfd.transient import transient_growth

DEFAULT_SAMPLES = 20_000
DEFAULT_TOLERANCE = 0.0    # extra absolute slack (1/s) on top of the round-off slack Eq. (K2)
IDENTITY_RATE = 0.05       # 1/s: the rate checked for a field without a metric unless one is asked for
BOX_GROWTH = 0.5           # the default box is the demos' bounding box grown by 50%
CHUNK = 8192               # points per vectorised evaluation
MIN_PER_AXIS = 10          # the grid has at least this many points per axis
GRID_MAX_DIM = 3           # above this dimension the points are the box's corners and uniform samples
MIN_RANDOM_SAMPLES = 1000  # ... at least this many
MAX_SAMPLES = 10_000_000
SAFETY = 1000.0            # Eq. (K2): multiples of eps of the round-off allowance
RK4_RADIUS = 2.6           # h |mu| <= 2.6 stays in RK4's stability region for every mu with Re mu <= 0
ESCAPE_STARTS = 256        # starts on the box whose trajectories are followed
ESCAPE_STEPS = 400         # RK4 steps over the horizon
ESCAPE_HORIZON_S = 20.0    # at most this long (s); 5 / rate when shorter

VERDICTS = ("certified", "not proven", "not certified")


@dataclass(frozen=True)
class Certificate:
    """The outcome of ``certify``.

    verdict : "certified", "not proven" or "not certified"; certified : verdict == "certified"
    proof : how the verdict was reached (one line)
    worst : max over the grid of g(x), Eq. (K1), 1/s; bound : -2 rate; margin : bound - worst
    slack : the largest round-off slack Eq. (K2) used at a grid point (+ ``tolerance``)
    argmax : the grid point of ``worst`` (user units)
    sampled_metric_min_eig, sampled_metric_max_eig : smallest and largest eigenvalue of M seen on
        the grid (samples, not bounds)
    metric_bound_a, metric_bound_b, condition_bound, overshoot, lipschitz_bound, rk4_max_step :
        the analytic constants (for all x in R^d) where the field has them, else None; overshoot is
        sqrt(b/a), rk4_max_step = RK4_RADIUS / lipschitz_bound (s)
    cell_lipschitz, cell_radius, worst_over_box : the between-samples bound (identity metric)
    box : the requested box; checked_box : the grid's box (it contains the trajectories)
    pose : for a pose field, ``lfd.pose_contraction.check_pose_contraction`` (pairs of poses, their
        geodesic distance); a failed check there makes the verdict "not certified"
    n_starts, n_left_box : starts on the box followed, and how many left it
    n_points, per_axis : grid size; n_invalid : points where M, Q or g was not finite, or M not
        numerically positive definite
    equilibria : ``lfd.equilibria.find_equilibria`` on the box (None when not searched); a spurious
        attractor, a closed orbit or an escaping start there makes the verdict "not certified"
    structural, growth : for a field built as a bounded flow of a contracting latent field, the
        theorem's conditions read from its weights and Eq. (18) with its constant sampled on the box and
        far out (``lfd.transient``); either failing makes the verdict "not certified"
    lyapunov : for a field with a stated Lyapunov function, ``lfd.stability.check_lyapunov``; then
        ``metric`` is "lyapunov", ``rate`` the decay rate of Eq. (L3), ``worst`` the largest sampled
        dV/dt / (alpha(V) V) against ``bound`` -1, ``overshoot`` s_hi / s_lo and the metric
        eigenvalues s_lo^2, s_hi^2 (V's bounds over |x_n|^2)
    """

    learner: str
    metric: str
    rate: float
    bound: float
    verdict: str
    certified: bool
    proof: str
    worst: float
    margin: float
    slack: float
    tolerance: float
    argmax: list[float]
    sampled_metric_min_eig: float
    sampled_metric_max_eig: float
    metric_bound_a: float | None
    metric_bound_b: float | None
    condition_bound: float | None
    overshoot: float | None
    lipschitz_bound: float | None
    rk4_max_step: float | None
    cell_lipschitz: float | None
    cell_radius: float
    worst_over_box: float | None
    n_points: int
    per_axis: int
    n_invalid: int
    n_starts: int
    n_left_box: int
    box: list[list[float]]
    checked_box: list[list[float]]
    elapsed_s: float
    pose: dict[str, Any] | None = None
    equilibria: EquilibriumReport | None = None
    lyapunov: dict[str, Any] | None = None
    structural: dict[str, Any] | None = None
    growth: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["equilibria"] = None if self.equilibria is None else self.equilibria.to_dict()
        return out

    def summary(self) -> str:
        """Human-readable lines for the command line."""
        if self.lyapunov is not None:
            return self._lyapunov_summary()
        pt = ", ".join(f"{v:.4g}" for v in self.argmax)
        lines = [f"{self.verdict.upper()}: contraction rate {self.rate:g}/s in the {self.metric} metric "
                 f"({self.learner} model)",
                 f"  proof: {self.proof}"]
        if self.overshoot is not None:
            lines.append(f"  analytic, for all x: a = {self.metric_bound_a:.4g}, b = {self.metric_bound_b:.4g}, "
                         f"b/a = {self.condition_bound:.4g}, overshoot sqrt(b/a) = {self.overshoot:.4g}: "
                         f"|dx(t)| <= {self.overshoot:.4g} |dx(0)| exp(-{self.rate:g} t)")
            lines.append(f"  analytic Lipschitz bound of f: {self.lipschitz_bound:.4g}/s; RK4 is stable for "
                         f"steps up to {self.rk4_max_step:.4g} s")
        where = f" at ({pt})" if all(math.isfinite(v) for v in self.argmax) else ""
        lines.append(f"  sampled: worst generalised eigenvalue {self.worst:.6g} vs -2*rate = {self.bound:.6g} "
                     f"(round-off slack {self.slack:.3g}){where}; metric eigenvalues seen "
                     f"{self.sampled_metric_min_eig:.4g} .. {self.sampled_metric_max_eig:.4g}")
        if self.cell_lipschitz is not None:
            lines.append(f"  between samples: Lip(J_f) <= {self.cell_lipschitz:.4g}, cell half-diagonal "
                         f"{self.cell_radius:.3g}: g <= {self.worst_over_box:.4g} on the whole box")
        layout = f"{self.per_axis} per axis" if self.per_axis else "random"
        lines.append(f"  {self.n_points} points ({layout}) in {_fmt_box(self.checked_box)}; "
                     f"{self.n_left_box} of {self.n_starts} starts on the box {_fmt_box(self.box)} left it; "
                     f"{self.elapsed_s:.2f} s")
        if self.n_invalid:
            lines.append(f"  {self.n_invalid} points where the field or its metric is not finite or the "
                         f"metric is not positive definite")
        if self.structural is not None:
            c = self.structural
            ridge = "" if c["ridge_min"] is None else f", smallest ridge gain {c['ridge_min']:.3g} (>= 0)"
            lines.append(f"  from the weights: max eig sym(A) + rate I = {c['sym_a_max']:.3g} (<= 0){ridge}, "
                         f"flow s_hi/s_lo = {c['flow_ratio']:.4g} (<= {c['sqrt_kappa']:.4g}): "
                         + ("the theorem's conditions hold" if c["holds"] else "A CONDITION FAILS"))
        if self.growth is not None:
            g = self.growth
            lines.append(f"  Eq. (18) sampled: {g['pairs']} pairs on the box and {g['pairs']} at {g['far']:g} box "
                         f"sizes, split along M's top eigenvector, {g['horizon_s']:.3g} s: worst |dx(t)| e^(rate t) "
                         f"/ |dx(0)| {g['worst_near']:.4g} near, {g['worst_far']:.4g} far, against sqrt(b/a) = "
                         f"{g['overshoot']:.4g}" + ("" if g["holds"] else " (EXCEEDED)"))
        if self.pose is not None:
            p = self.pose
            state = ("holds" if p["holds"] else "FAILS") if p["checked"] else "not stated (reported only)"
            lines.append(f"  poses: {p['n_pairs']} pairs followed {p['horizon_s']:.3g} s, starts up to "
                         f"{p['max_start_angle_deg']:.2f} deg from the goal orientation: the pose-distance bound "
                         f"{state} (worst ratio {p['worst_ratio']:.3g}, to the goal {p['goal_worst_ratio']:.3g}); "
                         f"slowest geodesic decay {p['geodesic_decay_rate']:.3g}/s; pairs across the cut locus "
                         f"separate up to {p['cut_locus_growth']:.3g}x before converging")
        if self.equilibria is not None:
            lines.extend("  " + line for line in self.equilibria.summary().splitlines())
        return "\n".join(lines)


    def _lyapunov_summary(self) -> str:
        c = cast(dict[str, Any], self.lyapunov)
        pt = ", ".join(f"{v:.4g}" for v in self.argmax)
        lines = [f"{self.verdict.upper()}: globally exponentially stable at the goal, rate {self.rate:.4g}/s, "
                 f"Lyapunov function of Eq. (L1) ({self.learner} model)",
                 f"  proof: {self.proof}",
                 f"  analytic, for all x: s_lo = {c['s_lo']:.4g}, s_hi = {c['s_hi']:.4g}, gamma = {c['gain']:.4g}, "
                 f"goal rate {c['goal_rate']:.4g}/s: |x(t) - goal| <= {c['overshoot']:.4g} |x(0) - goal| "
                 f"exp(-{self.rate:.4g} t) (Eq. (L3)); |fhat(goal)| = {c['nominal_at_goal']:.3g}",
                 f"  sampled: worst dV/dt / (alpha(V) V) {self.worst:.6g} vs -1 at ({pt}); "
                 f"{c['n_decrease_fails']} decrease and {c['n_bound_fails']} bound failures in {self.n_points} "
                 f"points (the box and {c['far_radius']:.3g} units out); {self.n_left_box} of {self.n_starts} "
                 f"starts on the box {_fmt_box(self.box)} left it; {self.elapsed_s:.2f} s"]
        if self.n_invalid:
            lines.append(f"  {self.n_invalid} points where V or its decrease is not finite")
        if self.equilibria is not None:
            lines.extend("  " + line for line in self.equilibria.summary().splitlines())
        return "\n".join(lines)


def _fmt_box(box: list[list[float]]) -> str:
    return " x ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(*box))


def min_samples(d: int) -> int:
    """The fewest points ``certify`` checks in d dimensions."""
    return MIN_PER_AXIS ** d if d <= GRID_MAX_DIM else MIN_RANDOM_SAMPLES


def _per_axis(samples: int, d: int) -> int:
    """Grid points per axis of ``grid`` for ``samples`` points in d dimensions (0: random samples)."""
    return max(MIN_PER_AXIS, math.ceil(samples ** (1.0 / d) - 1e-9)) if d <= GRID_MAX_DIM else 0


def grid(lo: np.ndarray, hi: np.ndarray, samples: int) -> np.ndarray:
    """A regular grid with m = max(MIN_PER_AXIS, ceil(samples^(1/d))) points per axis, corners included;
    above ``GRID_MAX_DIM`` dimensions the 2^d corners (when there are no more than ``samples``) and
    ``samples`` uniform points (seed 0).

    lo, hi : arrays, shape (d,); returns shape (m^d, d) (or (2^d + samples, d)).
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    d = lo.shape[0]
    if d > GRID_MAX_DIM:
        uniform = np.random.default_rng(0).uniform(lo, hi, size=(samples, d))
        if 2 ** d > samples:       # too many corners to list: the uniform samples only
            return uniform
        corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), axis=-1).reshape(-1, d)
        return np.concatenate([corners, uniform])
    m = max(MIN_PER_AXIS, math.ceil(samples ** (1.0 / lo.shape[0]) - 1e-9))
    axes = [np.linspace(a, b, m) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, lo.shape[0])


def default_box(field: VelocityField, grow: float = BOX_GROWTH) -> tuple[np.ndarray, np.ndarray] | None:
    """The training demos' box (``field.demo_box``) grown by ``grow`` times its size, or None.

    Returns (lo, hi), arrays of shape (d,), user units; None for a field without a demo box.
    """
    if field.demo_box is None:
        return None
    lo, hi = field.demo_box
    pad = (hi - lo) * grow / 2
    return lo - pad, hi + pad


def generalized_eigenvalues(field: VelocityField, xn: torch.Tensor
                            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """g(x) of Eq. (K1), eig(M_n) and the round-off scale of Eq. (K2) at normalised points xn (B, d).

    Returns g (B,), eig(M_n) (B, d) (identity metric: ones) and scale (B,) = (2 |J_f| |M| + |dM/dt|)
    / lambda_min(M). Where anything is not finite or M_n is not numerically positive definite,
    g = +inf (not certified).
    """
    module = field.module
    d = xn.shape[1]
    eye = torch.eye(d, dtype=xn.dtype)
    f = module(xn)
    jf = torch.stack([jvp(module, (xn,), (eye[k].expand_as(xn),))[1] for k in range(d)], dim=-1)  # (B, d, d)
    jf_norm = torch.linalg.matrix_norm(jf)
    metric_fn: Callable[[torch.Tensor], torch.Tensor] | None = field.contraction_metric()
    if metric_fn is None:
        q = jf + jf.transpose(1, 2)
        bad = ~torch.isfinite(q).flatten(1).all(1) | ~torch.isfinite(f).all(1)
        g = torch.linalg.eigvalsh(torch.where(bad[:, None, None], eye.expand_as(q), q))[:, -1]
        return (torch.where(bad, torch.full_like(g, math.inf), g), torch.ones(xn.shape[0], d, dtype=xn.dtype),
                2 * jf_norm)
    # torch.func.jvp is annotated as maybe returning 3 items (only with has_aux=True)
    m, m_dot = cast(tuple[torch.Tensor, torch.Tensor], jvp(metric_fn, (xn,), (f,)))  # M, dM/dt = (dM/dx) f
    q = jf.transpose(1, 2) @ m + m @ jf + m_dot
    bad = (~torch.isfinite(m).flatten(1).all(1) | ~torch.isfinite(q).flatten(1).all(1)
           | ~torch.isfinite(f).all(1))
    eye_b = eye.expand_as(m)
    m_ok = torch.where(bad[:, None, None], eye_b, m)
    eig_m = torch.linalg.eigvalsh(m_ok)
    low, info = torch.linalg.cholesky_ex(m_ok)
    bad |= (info != 0) | (eig_m[:, 0] <= 0)                               # M not numerically positive definite
    eig_m = torch.where(bad[:, None], math.nan, eig_m)
    low = torch.where(bad[:, None, None], eye_b, low)
    y = torch.linalg.solve_triangular(low, torch.where(bad[:, None, None], eye_b, q), upper=False)  # L^-1 Q
    g = torch.linalg.solve_triangular(low, y.transpose(1, 2), upper=False)  # L^-1 Q' L^-T
    g = torch.linalg.eigvalsh(0.5 * (g + g.transpose(1, 2)))[:, -1]
    scale = (2 * jf_norm * torch.linalg.matrix_norm(m) + torch.linalg.matrix_norm(m_dot)) / eig_m[:, 0]
    return torch.where(bad, torch.full_like(g, math.inf), g), eig_m, scale


def _analytic(field: VelocityField) -> dict[str, float] | None:
    """The structural constants of a field that states them (``metric_bounds``, ``lipschitz_bound``),
    or None (any non-finite value: None)."""
    try:
        bounds, lip_bound = field.metric_bounds, field.lipschitz_bound
        if bounds is None or lip_bound is None:
            return None
        a, b = (float(v) for v in bounds)
        kappa, lip = b / a, float(lip_bound)
    except (ValueError, RuntimeError, FloatingPointError, ZeroDivisionError):
        return None
    vals = (a, b, kappa, lip)
    if not all(math.isfinite(v) for v in vals) or a <= 0 or b < a or lip <= 0:
        return None
    return {"metric_bound_a": a, "metric_bound_b": b, "condition_bound": kappa, "overshoot": math.sqrt(kappa),
            "lipschitz_bound": lip, "rk4_max_step": RK4_RADIUS / lip}


def escaping_starts(field: VelocityField, lo: np.ndarray, hi: np.ndarray, rate: float
                    ) -> tuple[int, int, np.ndarray, np.ndarray, bool]:
    """Follow starts on the box [lo, hi] for min(5 / rate, ESCAPE_HORIZON_S) s with RK4.

    Returns (n_starts, n_left, lo', hi', finite): the bounding box of the box and every trajectory,
    and whether every trajectory stayed finite.
    """
    d = lo.shape[0]
    m = max(2, int(ESCAPE_STARTS ** (1.0 / d) + 1e-9))    # at most ESCAPE_STARTS starts (16 per axis in 2-D, 6 in 3-D)
    axes = [np.linspace(a, b, m) for a, b in zip(lo, hi)]
    starts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    horizon = min(5.0 / rate, ESCAPE_HORIZON_S)
    t = np.linspace(0.0, horizon, ESCAPE_STEPS + 1)
    with np.errstate(all="ignore"):
        xs = field.rollout(starts, t)                                    # (B, T, d)
    finite = bool(np.isfinite(xs).all())
    tol = 1e-9 * (hi - lo)
    left = ((xs < lo - tol) | (xs > hi + tol)).any(axis=(1, 2)) | ~np.isfinite(xs).all(axis=(1, 2))
    if finite:
        lo2, hi2 = np.minimum(lo, xs.min(axis=(0, 1))), np.maximum(hi, xs.max(axis=(0, 1)))
    else:
        lo2, hi2 = lo, hi
    return len(starts), int(left.sum()), lo2, hi2, finite


def certify(field: VelocityField, lo: np.ndarray | None = None, hi: np.ndarray | None = None,
            samples: int = DEFAULT_SAMPLES, rate: float | None = None,
            tolerance: float = DEFAULT_TOLERANCE, pose_pairs: int | None = None, equilibria: bool = True,
            duration: float | None = None) -> Certificate:
    """Certify Eq. (C1) for ``field`` (see the module docstring for what each verdict means).

    lo, hi : arrays, shape (d,), the box in user units (default: the training demos' box grown
    by 50%, ``default_box``); samples : at least this many grid points (and at least
    MIN_PER_AXIS per axis); rate : 1/s (default: the field's own, or ``IDENTITY_RATE``);
    tolerance : extra absolute slack, 1/s, added to the round-off slack of Eq. (K2); pose_pairs : a pose
    field's pairs of each kind for ``lfd.pose_contraction.check_pose_contraction`` (default its ``PAIRS``);
    equilibria : search the box for spurious attractors, closed orbits and escapes (``lfd.equilibria``,
    the field's autonomous view), any of which makes the verdict "not certified"; duration : the demos'
    duration, s, that sets the search's horizon (default ``find_equilibria``'s).
    Raises ConfigError for a missing or empty box, a bad rate, sample count, tolerance or duration.
    """
    if lo is None or hi is None:
        box = default_box(field)
        if box is None:
            raise ConfigError("no box to certify in: the model's history has no demo box; give --box or --demos")
        lo, hi = box
    lo, hi = check_box(field, lo, hi)
    d = field.dim
    if isinstance(samples, bool) or not isinstance(samples, int) or not min_samples(d) <= samples <= MAX_SAMPLES:
        per = f" ({MIN_PER_AXIS} per axis)" if d <= GRID_MAX_DIM else ""
        raise ConfigError(f"samples must be an integer from {min_samples(d)}{per} "
                          f"to {MAX_SAMPLES}, got {samples!r}")
    if rate is None:
        rate = IDENTITY_RATE if field.rate is None else float(field.rate)     # a stated Lyapunov function: its own
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and 0 < rate <= 1e6):
        raise ConfigError(f"rate must be a positive number up to 1e6 (1/s), got {rate!r}")
    if not (math.isfinite(tolerance) and tolerance >= 0):
        raise ConfigError(f"tolerance must be a non-negative number, got {tolerance!r}")

    if duration is not None and not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")

    with warnings.catch_warnings():     # torch.func's first use warns that torch.jit.script is deprecated
        warnings.simplefilter("ignore", DeprecationWarning)
        if field.stability_constants() is not None:
            cert = _certify_lyapunov(field, lo, hi, samples)
        else:
            cert = by_kind(field, _CERTIFIERS)(field, lo, hi, samples, float(rate), tolerance)
    cert = _check_theorem(field, cert, lo, hi)
    if field.space is StateSpace.POSE:
        pose = check_pose_contraction(field, PAIRS if pose_pairs is None else int(pose_pairs))
        cert = replace(cert, pose=pose)
        if pose["checked"] and not pose["holds"] and cert.certified:
            cert = replace(cert, verdict="not certified", certified=False,
                           proof="a sampled pair of poses breaks the pose-distance bound (a counterexample)")
    if not equilibria:
        return cert
    with torch_threads(1):
        found = find_equilibria(field, lo, hi, duration)
    if found.clean or cert.verdict == "not certified":
        return replace(cert, equilibria=found)
    return replace(cert, equilibria=found, verdict="not certified", certified=False,
                   proof=f"{', '.join(found.failures())} besides the goal: the goal does not attract every start "
                         f"(a counterexample)")


def _check_theorem(field: VelocityField, cert: Certificate, lo: np.ndarray, hi: np.ndarray) -> Certificate:
    """``cert`` with the theorem's conditions of a field that states them (``theorem_conditions``) and, where
    they hold, Eq. (18) sampled (``lfd.transient``); unchanged for any other field."""
    structural = field.theorem_conditions()
    if structural is None:
        return cert
    if not structural["holds"]:     # the bound is not stated by weights that break the theorem: not sampled
        cert = replace(cert, structural=structural)
        return cert if not cert.certified else replace(
            cert, verdict="not certified", certified=False,
            proof="a condition of the theorem fails in the weights (docs/equations.md, Eq. (N1))")
    with torch_threads(1):
        growth = transient_growth(field, lo, hi)
    cert = replace(cert, structural=structural, growth=growth)
    if cert.certified and not growth["holds"]:
        return replace(cert, verdict="not certified", certified=False,
                       proof="a sampled pair of trajectories grows apart by more than sqrt(b/a) (a counterexample)")
    return cert


def _certify(field: VelocityField, lo: np.ndarray, hi: np.ndarray, samples: int, rate: float,
             tolerance: float) -> Certificate:
    """``certify`` of an autonomous field after its arguments were checked."""
    d = field.dim
    t0 = time.perf_counter()
    with torch_threads(1):  # small per-point matrices: one thread is as fast and immune to oversubscription
        n_starts, n_left, clo, chi, traj_finite = escaping_starts(field, lo, hi, rate)
        pts = grid(clo, chi, samples)
        per_axis = _per_axis(samples, d)
        with np.errstate(all="ignore"):
            xn_all = torch.tensor(field.norm.to_norm(pts))
        bound = -2.0 * rate
        worst, where, invalid, slack_max, excess, a, b = _scan(field, xn_all, bound, tolerance)
    has_metric = field.contraction_metric() is not None
    s2 = field.norm.scale ** 2 if has_metric else 1.0
    analytic = _analytic(field) if has_metric else None
    cell_radius = float(0.5 * np.linalg.norm((chi - clo) / (per_axis - 1))) if per_axis else math.inf
    cell_lip: float | None = None
    worst_box: float | None = None
    sampled_ok = invalid == 0 and traj_finite and math.isfinite(worst) and excess <= 0
    if not traj_finite:
        verdict, proof = "not certified", "a trajectory from the box diverged (not finite)"
    elif invalid:
        verdict, proof = "not certified", f"{invalid} grid points are not finite or the metric is not positive definite"
    elif not sampled_ok:
        verdict, proof = "not certified", "a grid point violates Eq. (C1) (a counterexample)"
    elif analytic is not None:
        verdict, proof = "certified", ("structural: Eq. (C1) holds identically on all of R^d with the analytic "
                                       "metric bounds below; the grid confirms the implementation")
    else:
        jl = field.jacobian_lipschitz_bound()
        cell_lip = None if jl is None else float(jl)
        if cell_lip is not None and math.isfinite(cell_lip) and not has_metric and per_axis:
            worst_box = worst + 2.0 * cell_lip * cell_radius
            if worst_box <= bound + tolerance:
                verdict, proof = "certified", "on the checked box: max over the grid + 2 Lip(J_f) h <= -2 rate"
            else:
                verdict, proof = "not proven", ("every grid point passes, but the bound between grid points "
                                                f"(+{2.0 * cell_lip * cell_radius:.3g}) is too loose; use more samples")
        else:
            verdict, proof = "not proven", "every grid point passes, but nothing bounds the field between them"
    analytic = analytic or {}
    return Certificate(
        learner=field.learner, metric="learned" if has_metric else "identity", rate=float(rate), bound=bound,
        verdict=verdict, certified=verdict == "certified", proof=proof, worst=worst, margin=bound - worst,
        slack=slack_max, tolerance=float(tolerance), argmax=[float(v) for v in pts[where]],
        sampled_metric_min_eig=a / s2, sampled_metric_max_eig=b / s2,
        metric_bound_a=analytic.get("metric_bound_a"), metric_bound_b=analytic.get("metric_bound_b"),
        condition_bound=analytic.get("condition_bound"), overshoot=analytic.get("overshoot"),
        lipschitz_bound=analytic.get("lipschitz_bound"), rk4_max_step=analytic.get("rk4_max_step"),
        cell_lipschitz=cell_lip, cell_radius=cell_radius, worst_over_box=worst_box,
        n_points=int(len(pts)), per_axis=per_axis, n_invalid=invalid, n_starts=n_starts, n_left_box=n_left,
        box=[lo.tolist(), hi.tolist()], checked_box=[clo.tolist(), chi.tolist()],
        elapsed_s=time.perf_counter() - t0)


def _certify_lyapunov(field: VelocityField, lo: np.ndarray, hi: np.ndarray, samples: int) -> Certificate:
    """``certify`` of a field with a stated Lyapunov function (``lfd.stability``): certified when its
    analytic conditions hold and the sampled decrease confirms them on the box and far out."""
    t0 = time.perf_counter()
    with torch_threads(1):
        pts = grid(lo, hi, samples)
        check = check_lyapunov(field, pts)
    assert check is not None
    rate = float(check["rate"])
    n_starts, n_left, clo, chi, _ = escaping_starts(field, lo, hi, rate)
    if not check["analytic_holds"]:
        verdict, proof = "not certified", "an analytic condition of Eqs. (L1)-(L2) fails (see the constants)"
    elif not check["holds"]:
        verdict, proof = "not certified", ("a sampled point breaks dV/dt <= -alpha(V) V or V's bounds, or is not "
                                           "finite (a counterexample)")
    else:
        verdict, proof = "certified", ("structural (Eqs. (L1)-(L3)): V positive definite and radially unbounded, "
                                       "dV/dt <= -alpha V on all of R^d; the samples confirm the implementation")
    return Certificate(
        learner=field.learner, metric="lyapunov", rate=rate, bound=-1.0, verdict=verdict,
        certified=verdict == "certified", proof=proof, worst=check["worst_ratio"],
        margin=-1.0 - check["worst_ratio"], slack=ROUND_OFF, tolerance=0.0, argmax=check["argmax"],
        sampled_metric_min_eig=check["s_lo"] ** 2, sampled_metric_max_eig=check["s_hi"] ** 2,
        metric_bound_a=None, metric_bound_b=None, condition_bound=None, overshoot=check["overshoot"],
        lipschitz_bound=None, rk4_max_step=None, cell_lipschitz=None, cell_radius=math.inf, worst_over_box=None,
        n_points=check["n_points"], per_axis=_per_axis(samples, field.dim), n_invalid=check["n_invalid"],
        n_starts=n_starts, n_left_box=n_left,
        box=[lo.tolist(), hi.tolist()], checked_box=[clo.tolist(), chi.tolist()],
        elapsed_s=time.perf_counter() - t0, lyapunov=check)


def _scan(field: VelocityField, xn_all: torch.Tensor, bound: float,
          tolerance: float) -> tuple[float, int, int, float, float, float, float]:
    """Eq. (K1) at every grid point, in chunks of ``CHUNK``; xn_all : tensor, shape (P, d), normalised.

    Returns (worst g, its index, the number of non-finite g, the largest finite slack of Eq. (K2),
    max(g - bound - slack), and the smallest and largest eigenvalue of M_n over the valid points).
    """
    worst, where, invalid, slack_max, excess = -math.inf, 0, 0, 0.0, -math.inf
    a, b = math.inf, -math.inf
    eps = float(np.finfo(np.float64).eps)
    for start in range(0, len(xn_all), CHUNK):
        with torch.no_grad():
            g, eig_m, scale = generalized_eigenvalues(field, xn_all[start:start + CHUNK])
        slack = SAFETY * eps * torch.nan_to_num(scale, nan=math.inf, posinf=math.inf) + tolerance
        invalid += int((~torch.isfinite(g)).sum())
        gi = torch.nan_to_num(g, nan=math.inf, posinf=math.inf)
        i = int(torch.argmax(gi))
        if float(gi[i]) > worst:
            worst, where = float(gi[i]), start + i
        finite_slack = slack[torch.isfinite(slack)]
        if len(finite_slack):
            slack_max = max(slack_max, float(finite_slack.max()))
        excess = max(excess, float((gi - bound - slack).max()))
        ok = torch.isfinite(eig_m).all(1)
        if ok.any():
            a, b = min(a, float(eig_m[ok, 0].min())), max(b, float(eig_m[ok, -1].max()))
    return worst, where, invalid, slack_max, excess, a, b


def _phase_certificate(field: VelocityField, lo: np.ndarray, hi: np.ndarray, samples: int, rate: float,
                       tolerance: float) -> Certificate:
    """The tracking learner's stated property (``lfd.learners.tracking.check_tracking_contraction``):
    for any phase signal the x-subsystem contracts at rate K in the Euclidean metric (a = b = 1), and
    the tracking error decays like e^(-K t) from starts in the box (at the field's own rate K: the
    ``rate`` asked for is not used)."""
    from lfd.learners.tracking import check_tracking_contraction

    t0 = time.perf_counter()
    r = check_tracking_contraction(field, lo, hi, n_points=samples)  # type: ignore[arg-type]
    rate = float(r["rate"])
    worst = 2.0 * float(r["worst_eig"])                 # g = max eig(J + J') in M = I
    values = (worst, float(r["worst_error_excess"]), float(r["lipschitz_bound"]))
    finite = all(math.isfinite(v) for v in values)
    verdict = "certified" if finite and r["certified"] else "not certified"
    a, b = (float(v) for v in r["metric_bounds"])
    lip = float(r["lipschitz_bound"])
    return Certificate(
        learner=field.learner, metric="identity (x-subsystem)", rate=rate, bound=-2.0 * rate, verdict=verdict,
        certified=verdict == "certified",
        proof=f"{r['property']}; checked at {r['n_points']} random (x, s, ds/dt) and from {r['n_starts']} starts",
        worst=worst, margin=-2.0 * rate - worst, slack=float(tolerance), tolerance=float(tolerance),
        argmax=[math.nan] * field.dim, sampled_metric_min_eig=1.0, sampled_metric_max_eig=1.0,
        metric_bound_a=a, metric_bound_b=b, condition_bound=b / a, overshoot=math.sqrt(b / a),
        lipschitz_bound=lip if finite else None, rk4_max_step=RK4_RADIUS / lip if finite and lip > 0 else None,
        cell_lipschitz=None, cell_radius=0.0, worst_over_box=None, n_points=int(r["n_points"]),
        per_axis=0, n_invalid=0 if finite else 1, n_starts=int(r["n_starts"]), n_left_box=0,
        box=[lo.tolist(), hi.tolist()], checked_box=[list(v) for v in r["box"]],
        elapsed_s=time.perf_counter() - t0)


#: how ``certify`` checks a field of each kind: Eq. (C1) on a grid, or the phase-carrying field's
#: property (a time-varying field states nothing to certify)
_CERTIFIERS: dict[FieldKind, Callable[..., Certificate]] = {FieldKind.AUTONOMOUS: _certify,
                                                            FieldKind.PHASED: _phase_certificate}
