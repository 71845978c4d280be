"""Contraction learner: velocity fields that contract by construction, with analytic bounds on all of R^d.

In normalised coordinates (goal at the origin) the field is a learned diffeomorphism phi
(``lfd.learners.flows``) of a linear contracting system,

    Eq. (C2): dy/dt = A (y - y*),  y* = phi(0),  A = -lambda I + S - P  (S skew, P = L L' PSD),
    Eq. (C3): f(x) = J_phi(x)^-1 A (phi(x) - y*),

so it satisfies the paper's Eq. (17) in the form Eq. (C1), J_f' M + M J_f + dM/dt <= -2 lambda M,
at every x, in the metric M(x) = J_phi(x)' J_phi(x). The flow bounds that metric, a I <= M <= b I
with b/a <= KAPPA (``max_condition``, Eq. (F4)), so any two trajectories obey the paper's Eq. (18)
with the overshoot constant, |dx(t)| <= sqrt(b/a) |dx(0)| e^(-lambda t). Closed-form trajectories:
Eq. (C4); an analytic global Lipschitz bound: Eq. (C6) (``lipschitz_bound``).

Training minimises Eq. (C5) by full-batch L-BFGS: the field's direction and the demos' paths and
arrival, their speed only weakly, because a contracting field's speed along a trajectory can grow at
most sqrt(b/a)-fold and demos that start from rest cannot be followed in time (``feasible_rate``,
``RateFeasibilityWarning``). lambda is in 1/s; derivations of Eqs. (C1)-(C6): docs/equations.md.

References
----------
Lohmiller, W., Slotine, J.-J. E. (1998). On contraction analysis for non-linear systems.
Automatica 34(6), 683-696. doi:10.1016/S0005-1098(98)00019-3
Rana, M. A., Li, A., Fox, D., Boots, B., Ramos, F., Ratliff, N. (2020). Euclideanizing flows:
diffeomorphic reduction for learning stable dynamical systems. L4DC, PMLR 120. arXiv:2005.13143
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm.auto import tqdm

from lfd.demos import DemoSet
from lfd.field import ContractingField
from lfd.learners.base import Learner
from lfd.learners.flows import FACTORED_MIN_DIM, SWIRL_COMPONENTS, BoundedFlow
from lfd.threads import torch_threads
from lfd.validate import check_bools, check_ints, check_numbers

# 1/s. With the path loss of Eq. (C5) the rate matters little for the fit (reports/contraction_tradeoff.md);
# a faster rate makes every rollout arrive sooner, but fewer demos can be followed in time
# (``feasible_rate`` is an upper bound on it).
DEFAULT_RATE = 0.5
GRAM_RCOND = 1e-10   # init_latent_from_data: X'X with a smaller eigenvalue ratio is taken as singular
DEFAULT_MAX_CONDITION = 100.0  # b/a <= 100: the overshoot constant sqrt(b/a) is at most 10
REST_TIMES = (0.1, 0.25, 0.5, 1.0)  # Eq. (C5): at T (1 + r) a demo rests at its goal (the origin)
_F_EPS = 1e-24                      # Eq. (C5): inside |f|, keeps the direction's gradient finite at f = 0


class RateFeasibilityWarning(UserWarning):
    """The demos cannot be followed in time at the requested rate within the condition bound."""


def feasible_rate(x: np.ndarray, t: np.ndarray, max_condition: float) -> float:
    """The largest lambda with |x_n(t)| e^(lambda t) <= sqrt(KAPPA) |x_n(0)| for every demo n.

    x : array, shape (N, T, d), relative to the goal; t : array, shape (N, T).
    Returns inf when every rate is feasible and 0 (or less) when none is.
    """
    if math.isinf(max_condition):
        return math.inf
    r = np.linalg.norm(x, axis=-1)                                     # (N, T)
    dt = t - t[:, :1]
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.log(math.sqrt(max_condition) * r[:, :1] / r) / dt
    cap = np.where((dt > 0) & (r > 0), cap, np.inf)
    return float(cap.min())


@dataclass
class ContractionConfig:
    """Options of the contraction learner.

    rate : lambda of Eqs. (C1)-(C2), 1/s, > 0 (the guaranteed contraction rate)
    max_condition : KAPPA >= 1, the bound on b/a of the metric (inf: per-block budget 0.97)
    layers, hidden, window, length_scale : the flow phi (``lfd.learners.flows``), normalised units
    damping : learn the extra damping P of Eq. (C2) (else P = 0 and sym(A) = -lambda I)
    iterations : loss evaluations of L-BFGS; batch : velocity points (a fixed seeded subsample)
    speed_weight : mu of Eq. (C5), the weak speed match (0 disables)
    traj_weight, traj_points, path_samples : w_x of Eq. (C5) (0 disables the path terms), the
    samples per demo of its path and of the latent rollout compared with it
    """

    rate: float = DEFAULT_RATE
    max_condition: float = DEFAULT_MAX_CONDITION
    layers: int = 4
    hidden: int = 32
    window: float = 1.5
    length_scale: float = 0.5
    damping: bool = True
    # Chosen by mean DTW on LASA shapes: a larger speed_weight pulls the paths away from the demos
    # (Eq. (C5)), traj_weight 3 fits better than 10, and more L-BFGS evaluations gain less than the
    # run-to-run noise.
    iterations: int = 150
    batch: int = 300
    speed_weight: float = 0.02
    traj_weight: float = 3.0
    traj_points: int = 25
    path_samples: int = 50

    def __post_init__(self) -> None:
        check_numbers(self, ("rate", "window", "length_scale"), "a positive number below 1e6",
                      lambda v: 0 < v <= 1e6, to_float=True)
        check_numbers(self, ("speed_weight", "traj_weight"), "a non-negative number below 1e6",
                      lambda v: 0 <= v <= 1e6, to_float=True)
        check_numbers(self, ("max_condition",), "a number > 1 (or inf)", lambda v: v > 1, to_float=True,
                      allow_inf=True)
        check_ints(self, (("layers", 1, 64), ("hidden", 1, 4096), ("iterations", 0, 10**6), ("batch", 1, 10**6),
                          ("traj_points", 2, 10**4), ("path_samples", 2, 10**4)))
        check_bools(self, ("damping",))
        if self.speed_weight == 0 and self.traj_weight == 0:
            raise ValueError("speed_weight and traj_weight cannot both be 0: nothing would set the field's speed")


class ContractionModule(nn.Module):
    """f_n of Eq. (C3) on normalised coordinates: x_n, shape (B, d) -> dx_n/dt, shape (B, d).

    ``factored`` (True from d = ``FACTORED_MIN_DIM`` on) selects how Eq. (C3) and the loss's latent
    rollouts are computed, never what they are: J_phi^-1 applied layer by layer
    (``BoundedFlow.forward_with_inverse_jacobian``) and the rollouts' evenly spaced matrix
    exponentials as powers of one (``latent_path``), instead of the dense J_phi, its solve and one
    matrix exponential per time. Both agree to rounding; smaller d keep the dense path.
    """

    def __init__(self, dim: int, config: ContractionConfig) -> None:
        super().__init__()
        self.dim = dim
        self.factored = dim >= FACTORED_MIN_DIM
        self.rate = config.rate
        self.flow = BoundedFlow(dim, config.layers, config.hidden, config.window, config.max_condition,
                                config.length_scale)
        self.skew = nn.Parameter(torch.zeros(dim, dim))
        self.damping = nn.Parameter(0.3 * torch.eye(dim)) if config.damping else None

    def latent_matrix(self) -> torch.Tensor:
        """A = -lambda I + S - P of Eq. (C2), shape (d, d)."""
        w = self.skew
        a = -self.rate * torch.eye(self.dim, dtype=w.dtype) + (w - w.T)
        if self.damping is not None:
            low = torch.tril(self.damping)
            a = a - low @ low.T
        return a

    @torch.no_grad()
    def init_latent_from_data(self, x: torch.Tensor, v: torch.Tensor) -> None:
        """Start A of Eq. (C2) at the contracting matrix nearest the least-squares fit v ~ A_ls x.

        x, v : tensors, shape (B, d). S = skew(A_ls); P = the PSD part of -(sym(A_ls) + lambda I),
        eigenvalues clipped below at 1e-3. With phi = identity, f(x) = A x then starts as the
        best linear contracting field (up to that projection).
        """
        # normal equations summed by torch, not LAPACK's least squares: MKL's gelsy takes a
        # process-dependent path (last-bit differences on the same data), which L-BFGS amplifies
        # into visibly different trained models
        gram = (x[:, :, None] * x[:, None, :]).sum(0)               # X'X, (d, d)
        cross = (x[:, :, None] * v[:, None, :]).sum(0)              # X'V, (d, d)
        ev = torch.linalg.eigvalsh(gram)
        if not bool(ev[0] > GRAM_RCOND * ev[-1]):
            # demos in a subspace (a planar 3-D path, a pose turning about one axis): X'X is
            # singular, so a small ridge picks the least-squares fit of least norm there
            gram = gram + GRAM_RCOND * float(ev[-1].clamp_min(1e-300)) * torch.eye(self.dim, dtype=x.dtype)
        a_ls = torch.linalg.solve(gram, cross).T                     # v ~ A_ls x
        self.skew.copy_((a_ls - a_ls.T) / 4)           # W = skew(A_ls) / 2, so W - W' = skew(A_ls)
        if self.damping is not None:
            eye = torch.eye(self.dim, dtype=x.dtype)
            evals, evecs = torch.linalg.eigh(-(a_ls + a_ls.T) / 2 - self.rate * eye)
            p = evecs @ torch.diag(evals.clamp_min(1e-3)) @ evecs.T
            self.damping.copy_(torch.linalg.cholesky(p))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Eq. (C3). x : tensor, shape (B, d); returns f(x), shape (B, d)."""
        return self.velocity_and_latent(x)[0]

    def velocity_and_latent(self, x: torch.Tensor
                            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """f(x) of Eq. (C3), shape (B, d), with y = phi(x), shape (B, d), y* = phi(0), shape (1, d),
        and J_phi(x), shape (B, d, d) (None when ``factored``: J_phi^-1 is then applied layer by
        layer, never formed)."""
        x1 = torch.cat([x, x.new_zeros(1, self.dim)])
        if self.factored:
            y, solve = self.flow.forward_with_inverse_jacobian(x1)
            y, y_star = y[:-1], y[-1:]
            v = self.latent_velocity(y, y_star)                # h(phi(x)), Eq. (C2)
            return solve(torch.cat([v, v.new_zeros(1, self.dim)]))[:-1], y, y_star, None
        y, jac = self.flow.forward_with_jacobian(x1)
        assert jac is not None
        y, y_star, jac = y[:-1], y[-1:], jac[:-1]
        v = self.latent_velocity(y, y_star)                    # h(phi(x)), Eq. (C2)
        return torch.linalg.solve(jac, v.unsqueeze(-1)).squeeze(-1), y, y_star, jac

    def latent_velocity(self, y: torch.Tensor, y_star: torch.Tensor) -> torch.Tensor:
        """The latent field h(y) = A (y - y*) of Eq. (C2), shape (B, d), at y, shape (B, d)."""
        return (y - y_star) @ self.latent_matrix().T

    def ridge_gain(self) -> torch.Tensor:
        """The gains D of a nonlinear latent term (``lfd.learners.contracting_node``), shape (H,): none here."""
        return self.skew.new_zeros(0)

    def latent_lipschitz(self) -> torch.Tensor:
        """An upper bound of Lip(h) = sup |J_h| on all of R^d (here |A|_2), a scalar tensor."""
        return torch.linalg.matrix_norm(self.latent_matrix(), ord=2)

    def metric(self, x: torch.Tensor) -> torch.Tensor:
        """M_n(x) = J_phi(x)' J_phi(x), shape (B, d, d), for x : tensor, shape (B, d)."""
        _, jac = self.flow.forward_with_jacobian(x)
        assert jac is not None
        return jac.transpose(-1, -2) @ jac

    def latent_trajectory(self, y0: torch.Tensor, y_star: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """y(t) of Eq. (C2) from latent starts y0, shape (N, d), at times t, shape (N, K): (N, K, d)."""
        at = self.latent_matrix() * t.reshape(-1, 1, 1)                             # (N K, d, d)
        e = torch.linalg.matrix_exp(at).reshape(*t.shape, self.dim, self.dim)      # (N, K, d, d)
        return y_star + (e @ (y0 - y_star)[:, None, :, None]).squeeze(-1)          # (N, K, d)

    def latent_path(self, y0: torch.Tensor, y_star: torch.Tensor, step: torch.Tensor, samples: int) -> torch.Tensor:
        """y(j step_n) of Eq. (C2), j = 0..samples - 1, shape (N, samples, d), from latent starts y0,
        shape (N, d), with time steps step, shape (N,).

        ``latent_trajectory`` at the evenly spaced times j step_n, without a matrix exponential per
        time: exp(A j dt) = exp(A dt)^j, applied by doubling (the samples [m, 2m) are E^m applied to
        the samples [0, m), then E^m is squared): one matrix exponential and about log2(samples)
        d x d products per demo.
        """
        e = torch.linalg.matrix_exp(self.latent_matrix() * step.reshape(-1, 1, 1))    # E = exp(A dt), (N, d, d)
        ys = (y0 - y_star)[:, None, :]                                                 # (N, 1, d)
        while ys.shape[1] < samples:
            ys = torch.cat([ys, ys[:, :samples - ys.shape[1]] @ e.transpose(1, 2)], 1)
            if ys.shape[1] < samples:
                e = e @ e
        return y_star + ys

    @torch.no_grad()
    def trajectory(self, x0: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Eq. (C4): the exact solutions from x0, shape (N, d), at times t, shape (N, K): (N, K, d)."""
        y = self.flow(torch.cat([x0, x0.new_zeros(1, self.dim)]))
        yt = self.latent_trajectory(y[:-1], y[-1:], t)
        return self.flow.inverse(yt.reshape(-1, self.dim)).reshape(yt.shape)


def lipschitz_bound(module: ContractionModule, grid: int = 4000) -> float:
    """An upper bound of Lip(f_n) over all of R^d, Eq. (C6), 1/s.

    With r_k = |x_{k-1} - c_k| the distance of layer k's input from its centre, |D J_phi(x)| <=
    sum_k P_k K_k(r_k) and |x| <= r_k + |c_k| + D_k (D_k = sum_{j<k} drift_j), so

        sup_x |D J_phi(x)| |x| <= sum_k P_k sup_r K_k(r) (r + |c_k| + D_k),

    each a 1-D sup over r >= 0 taken on ``grid`` intervals of [0, 12 w] (w the layer's widest
    Gaussian), each interval bounded from above by ``LayerBound.curvature``; beyond 12 w the Gaussian
    is below e^-72 and the term decays. Returns inf for non-finite parameters.
    """
    if not all(bool(torch.isfinite(p).all()) for p in module.parameters()):
        return math.inf
    layers = module.flow.bounds()
    with torch.no_grad():
        a_norm = float(module.latent_lipschitz()) * (1 + 1e-12)   # Lip(h): |A| for Eq. (C2)
    hi_s = np.array([layer.sigma_hi for layer in layers])
    s_lo = float(np.prod([layer.sigma_lo for layer in layers]))
    s_hi = float(np.prod(hi_s))
    drift = np.cumsum([0.0] + [layer.drift for layer in layers])[:-1]              # D_k
    second = 0.0
    for k, layer in enumerate(layers):
        p_k = np.prod(hi_s[k + 1:]) * np.prod(hi_s[:k]) ** 2                     # |J_after| |J_before|^2
        offset = float(np.linalg.norm(layer.center)) + drift[k]
        width = float(np.max(layer.params["rho"])) if layer.kind == "swirl" else module.flow.window
        edges = np.linspace(0.0, 12.0 * width, grid + 1)
        lo, hi = edges[:-1], edges[1:]
        second += p_k * float((layer.curvature(lo, hi) * (hi + offset)).max())
    return a_norm * s_hi / s_lo + a_norm * s_hi / s_lo ** 2 * second


class ContractionField(ContractingField):
    """A field contracting by construction (Eq. (C1)), with its metric, rate and analytic bounds.

    ``rate`` is lambda in 1/s; ``metric(x)`` is M(x) in user units; ``metric_bounds`` (a, b) bound
    M on all of R^d; ``condition_bound`` = b/a and ``lipschitz_bound`` (1/s) are analytic.
    """

    module: ContractionModule

    @property
    def latent_matrix(self) -> np.ndarray:
        """A of Eq. (C2), shape (d, d); -max eig sym(A) >= rate is the rate actually built in."""
        with torch.no_grad():
            return self.module.latent_matrix().numpy().copy()

    @property
    def metric_bounds(self) -> tuple[float, float]:
        """(a, b) with a I <= M(x) <= b I for every x in R^d, user units (Eq. (F4))."""
        s_lo, s_hi = self.module.flow.singular_value_bounds()
        s2 = self.norm.scale ** 2
        return s_lo ** 2 / s2, s_hi ** 2 / s2

    @property
    def lipschitz_bound(self) -> float:
        """An upper bound of the field's Lipschitz constant on all of R^d, 1/s (Eq. (C6))."""
        return lipschitz_bound(self.module)

    def theorem_conditions(self) -> dict[str, Any]:
        """The theorem's conditions (docs/equations.md, Eqs. (C1)-(C3) and (N1)-(N2)) read from the weights.

        Returns ``holds``, ``sym_a_max`` (the largest eigenvalue of sym(A) + lambda I at the stated rate,
        <= 0 needed), ``ridge_min`` (the smallest ridge gain, >= 0 needed; None without a ridge term),
        ``flow_ratio`` (s_hi / s_lo of the flow) and ``sqrt_kappa`` (the bound it must stay under); for
        non-finite weights ``holds`` is False and the values NaN.
        """
        module = self.module
        if not all(bool(torch.isfinite(p).all()) for p in module.parameters()):
            return {"holds": False, "sym_a_max": math.nan, "ridge_min": None, "flow_ratio": math.nan,
                    "sqrt_kappa": math.nan}
        with torch.no_grad():
            a = module.latent_matrix().double()
            rate = float(self.config["rate"])   # the stated rate, whatever the module was built with
            sym = (a + a.T) / 2 + rate * torch.eye(a.shape[0], dtype=a.dtype)
            sym_max = float(torch.linalg.eigvalsh(sym).max())
            gain = module.ridge_gain()
            ridge_min = float(gain.min()) if gain.numel() else None
        s_lo, s_hi = module.flow.singular_value_bounds()
        kappa = float(self.config.get("max_condition", math.inf))
        sqrt_kappa = math.sqrt(kappa) if math.isfinite(kappa) else math.inf
        tol = 1e-12 * max(1.0, float(torch.linalg.matrix_norm(a, ord=2)))
        holds = (sym_max <= tol and (ridge_min is None or ridge_min >= 0.0)
                 and math.isfinite(s_hi / s_lo) and s_hi / s_lo <= sqrt_kappa * (1 + 1e-9))
        return {"holds": bool(holds), "sym_a_max": sym_max, "ridge_min": ridge_min, "flow_ratio": s_hi / s_lo,
                "sqrt_kappa": sqrt_kappa}

    def metric_normalized_torch(self, xn: torch.Tensor) -> torch.Tensor:
        """M_n(x_n) = J_phi' J_phi, shape (B, d, d); differentiable (used by ``lfd.certify``)."""
        return self.module.metric(xn)

    def contraction_metric(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """``metric_normalized_torch``: the metric Eq. (C1) holds in (``lfd.certify``)."""
        return self.metric_normalized_torch

    def metric(self, x: np.ndarray) -> np.ndarray:
        """M(x) = J_phi(x_n)' J_phi(x_n) / s^2 in user units. x : array, shape (..., d) -> (..., d, d)."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"metric expects points of dimension {self.dim}, got shape {x.shape}")
        xn = torch.tensor(self.norm.to_norm(x.reshape(-1, self.dim)))
        with torch.no_grad():
            m = self.module.metric(xn).numpy()
        return m.reshape(*x.shape, self.dim) / self.norm.scale ** 2

    def closed_form_rollout(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The flow in closed form, Eq. (C4): the one rollout that needs no ODE solver.

        Every other rollout goes through ``lfd.integrate`` (``rollout``, the paper's Eq. (5));
        this one solves Eq. (5) exactly for this field, by the latent linear system.

        Parameters
        ----------
        x0 : array, shape (B, d)
            Starts, user units.
        t : array, shape (T,)
            Times, s; t[0] is the start.

        Returns
        -------
        array, shape (B, T, d)
            x(t), user units.
        """
        x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
        tt = torch.tensor(np.broadcast_to(np.asarray(t, dtype=np.float64) - t[0], (len(x0), len(t))).copy())
        xn = self.module.trajectory(torch.tensor(self.norm.to_norm(x0)), tt).numpy()
        return self.norm.from_norm(xn)

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """x (d,) -> f(x) (d,) in user units: the normalisation, phi, J_phi and the d x d solve of
        Eq. (C3) in one compiled call (``lfd.learners.flow_kernel``; see
        ``VelocityField.single_point_evaluator``), compiled or loaded now, not in the first control step."""
        from lfd.learners.flow_kernel import contraction_point_fn

        return contraction_point_fn(self.module.flow.numpy_params(), self.latent_matrix, self.norm.goal,
                                    float(self.norm.scale))


class _NonFinite(Exception):
    """The loss became NaN or inf: stop and keep the best parameters."""


class ContractionLearner(Learner, name="contraction", config=ContractionConfig, field=ContractionField):
    """Velocity field = diffeomorphism of a linear contracting system, Eqs. (C2)-(C3)."""

    @classmethod
    def parameter_count(cls, dim: int, config: ContractionConfig) -> int:
        """Parameters of ``build``: per flow pair a swirl (centre d, Theta and widths 2 x
        SWIRL_COMPONENTS, axis 3 for d = 3, plane 2 d for d >= 4) and a block (W1, b1, W2: H (2 d + 1)),
        the budget split 2 per pair, then S (d^2) and, with damping, L (d^2)."""
        generator = 3 if dim == 3 else 2 * dim if dim >= 4 else 0
        per_pair = dim + 2 * SWIRL_COMPONENTS + generator + config.hidden * (2 * dim + 1) + 2
        return config.layers * per_pair + dim * dim * (2 if config.damping else 1)

    @classmethod
    def build(cls, dim: int, config: ContractionConfig) -> ContractionModule:
        """A fresh float64 module (phi = identity, A = -lambda I - 0.09 I); trains in float64."""
        return ContractionModule(dim, config).double()

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: ContractionConfig,
            progress: bool) -> dict[str, Any]:
        """Minimise Eq. (C5) by L-BFGS on normalised demos; Ctrl-C keeps the best module so far.

        Runs single-threaded (the tensors are small: one thread is as fast, immune to
        oversubscription and gives the same floats every run). Returns ``loss`` (per evaluation),
        ``best_loss``, ``iterations``, ``interrupted``, ``stopped_nonfinite`` and
        ``feasible_rate`` (warns with ``RateFeasibilityWarning`` when the rate is above it).
        """
        assert isinstance(module, ContractionModule)
        lam_max = feasible_rate(demos.x, demos.t, config.max_condition)
        if config.rate > lam_max:
            warnings.warn(
                f"rate {config.rate:g}/s is not feasible for these demos within max_condition "
                f"{config.max_condition:g} (sqrt = {math.sqrt(config.max_condition):.3g}): "
                "the largest feasible rate is "
                + (f"{lam_max:.3g}/s" if lam_max > 0 else "none (a demo moves away from the goal by more than "
                   "sqrt(max_condition)); raise max_condition")
                + "; rollouts cannot keep the demos' timing", RateFeasibilityWarning, stacklevel=3)
        with torch_threads(1):
            history = cls._fit(module, demos, config, progress)
        history["feasible_rate"] = lam_max if math.isfinite(lam_max) else None
        return history

    @classmethod
    def _fit(cls, module: ContractionModule, demos: DemoSet, config: ContractionConfig,
             progress: bool) -> dict[str, Any]:
        """Full-batch L-BFGS on Eq. (C5); the module ends at its best evaluation."""
        data = _FitData.of(demos, config, next(module.parameters()).dtype)
        module.train()
        module.init_latent_from_data(data.x_all, data.v_all)
        opt = torch.optim.LBFGS(module.parameters(), lr=1.0, max_iter=max(config.iterations, 1),
                                max_eval=config.iterations, history_size=50, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-10, tolerance_change=1e-12)
        losses: list[float] = []
        best: dict[str, Any] = {"loss": math.inf, "state": None}
        bar = tqdm(total=config.iterations, desc=f"contraction (rate {config.rate:g}/s)",
                   disable=not progress, leave=False)

        def closure() -> torch.Tensor:
            opt.zero_grad()
            loss = data.loss(module, config)
            value = float(loss.detach())
            if not math.isfinite(value):
                raise _NonFinite
            losses.append(value)
            if value < best["loss"]:
                best["loss"] = value
                best["state"] = {k: t.detach().clone() for k, t in module.state_dict().items()}
            bar.update(1)
            if len(losses) % 10 == 1:
                bar.set_postfix(loss=f"{value:.4g}")
            loss.backward()
            return loss

        interrupted = nonfinite = False
        try:
            if config.iterations > 0:
                opt.step(closure)
        except KeyboardInterrupt:
            interrupted = True
        except _NonFinite:
            nonfinite = True
        finally:
            bar.close()
        if best["state"] is not None:
            module.load_state_dict(best["state"])
        module.eval()
        return {"loss": losses, "best_loss": best["loss"] if losses else None, "iterations": len(losses),
                "interrupted": interrupted, "stopped_nonfinite": nonfinite}


@dataclass(frozen=True)
class _FitData:
    """The tensors of Eq. (C5), built once per fit (normalised units).

    x_all, v_all : (K, d), every demo point and its velocity (for the initial A);
    x_in : (nv + N + N nk, d), the rows [velocity points | demo starts | demo path samples], so
    one pass of phi and J_phi serves every term; v_dir : (nv, d), the unit directions of the
    velocity points, v_log : (nv,), their log speeds, w : (nv,), their weights |xd| / rms |xd|;
    tk : (N, J + nr), the latent rollout's times (``path_samples`` over [0, T_n], then T_n (1 + r)).
    """

    x_all: torch.Tensor
    v_all: torch.Tensor
    x_in: torch.Tensor
    v_dir: torch.Tensor
    v_log: torch.Tensor
    w: torch.Tensor
    tk: torch.Tensor
    nv: int
    n0: int
    nk: int
    n_path: int

    @classmethod
    def of(cls, demos: DemoSet, config: ContractionConfig, dtype: torch.dtype) -> _FitData:
        """Velocity points: a fixed, seeded subsample of ``batch`` demo points (draws from torch's
        global generator); path samples: ``traj_points`` per demo, evenly in time."""

        def tensor(a: np.ndarray) -> torch.Tensor:
            # a copy: torch-aligned memory, so LAPACK takes one path in every process
            return torch.tensor(a, dtype=dtype)

        d, n0 = demos.dim, demos.n_demos
        x_all, v_all = tensor(demos.x.reshape(-1, d)), tensor(demos.xd.reshape(-1, d))
        pick = torch.randperm(len(x_all))[:config.batch] if len(x_all) > config.batch else slice(None)
        x, v = x_all[pick], v_all[pick]
        speed = torch.sqrt((v * v).sum(1))
        rms = float(torch.sqrt((v_all * v_all).sum(1).mean()))
        tiny = 1e-9 * max(rms, 1e-300)
        moving = speed > tiny                   # a point at rest has no direction: weight 0
        w = torch.where(moving, speed / max(rms, 1e-300), torch.zeros_like(speed))
        v_dir = torch.where(moving[:, None], v / speed.clamp_min(tiny)[:, None], torch.zeros_like(v))
        v_log = torch.log(speed.clamp_min(tiny))
        k_idx = np.unique(np.linspace(0, demos.n_samples - 1, config.traj_points).round().astype(int))
        duration = demos.t[:, -1:] - demos.t[:, :1]                               # (N, 1)
        tau = duration * np.linspace(0.0, 1.0, config.path_samples)[None, :]
        tk = tensor(np.concatenate([tau, duration * (1.0 + np.asarray(REST_TIMES))], axis=1))
        x_in = torch.cat([x, tensor(demos.x[:, 0]), tensor(demos.x[:, k_idx]).reshape(-1, d)])
        return cls(x_all, v_all, x_in, v_dir, v_log, w, tk, len(x), n0, len(k_idx), config.path_samples)

    def loss(self, module: ContractionModule, config: ContractionConfig) -> torch.Tensor:
        """Eq. (C5) (docs/equations.md) in normalised units, a scalar tensor:

            L = mean_i w_i |f_i/|f_i| - xd_i/|xd_i||^2 + mu mean_i w_i (log |f_i| - log |xd_i|)^2
                + w_x (Q + E + R) / mean |phi(x_demo) - y*|^2,

        with w_i = |xd_i| / rms |xd|, mu = ``speed_weight``, w_x = ``traj_weight``; per demo, Q is the
        Chamfer distance between its latent rollout (Eq. (C2)) and its latent points, E the rollout's
        arrival error at T_n and R its distance from y* at T_n (1 + r), r in ``REST_TIMES``.
        """
        nv, n0 = self.nv, self.n0
        f, y, y_star, _ = module.velocity_and_latent(self.x_in)
        f2 = (f[:nv] * f[:nv]).sum(1) + _F_EPS                                 # |f|^2 (> 0)
        f_dir = f[:nv] / torch.sqrt(f2)[:, None]
        loss = (self.w * ((f_dir - self.v_dir) ** 2).sum(1)).mean()
        if config.speed_weight > 0:
            loss = loss + config.speed_weight * (self.w * (0.5 * torch.log(f2) - self.v_log) ** 2).mean()
        if config.traj_weight > 0:
            z = y[nv + n0:].reshape(n0, self.nk, -1)                         # phi(x_demo(t_k)), (N, K, d)
            if module.factored:      # the same rollout: the path's evenly spaced times as powers of one step
                path = module.latent_path(y[nv:nv + n0], y_star, self.tk[:, 1], self.n_path)
                rest = module.latent_trajectory(y[nv:nv + n0], y_star, self.tk[:, self.n_path:])
            else:
                roll = module.latent_trajectory(y[nv:nv + n0], y_star, self.tk)   # (N, J + nr, d)
                path, rest = roll[:, :self.n_path], roll[:, self.n_path:]
            dist = ((path[:, :, None, :] - z[:, None, :, :]) ** 2).sum(-1)   # (N, J, K)
            chamfer = dist.min(2).values.mean() + dist.min(1).values.mean()
            arrive = ((path[:, -1] - z[:, -1]) ** 2).sum(-1).mean()
            settle = ((rest - y_star) ** 2).sum(-1).mean()
            y_scale = ((z - y_star) ** 2).sum(-1).mean()         # scale-free: phi cannot shrink the error away
            loss = loss + config.traj_weight * (chamfer + arrive + settle) / y_scale
        return loss
