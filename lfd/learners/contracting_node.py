"""Contracting NODE: a neural ODE that contracts by construction, trained through its ODE solver.

The paper's two methods in one field: the contraction learner's bounded flow phi (``lfd.learners.flows``,
Eqs. (F1)-(F4)) of a *nonlinear* latent field contracting in the identity metric (normalised units),

    Eq. (N1): dy/dt = h(y) = A (y - y*) - W' D (tanh(W y + c) - tanh(W y* + c)),   y* = phi(0),
              A = -lambda I + S - P (Eq. (C2)),  D = diag(softplus(delta)) >= 0,
    Eq. (N2): f(x) = J_phi(x)^-1 h(phi(x)),

so sym(J_h) <= -lambda I at every y, and the contraction learner's theorem holds with A replaced by h:
Eq. (C1) in M = J_phi' J_phi on all of R^d, the paper's Eq. (18) with sqrt(b/a) <= sqrt(KAPPA), Eq. (C6)
with Lip(h) <= |A| + |W' D W|. Poses: the chart's R^6 (Eq. (P1)); a run-time goal translates the field.

Trained as the NODE is (``lfd.learners.node``): multiple shooting (the paper's Eqs. (4), (13)) with a
segment curriculum, stratified batches and Adam, each segment integrated by RK4 (Eqs. (3), (5)) of Eq. (N1)
in the latent space, where the flow of Eq. (N2) is y = phi(x) exactly, plus each demo's whole rollout
against its path (Eq. (N5)). The speed along a trajectory can grow at most sqrt(b/a)-fold, so demos
starting from rest are first re-timed to a never-rising speed (Eq. (N4)); the rate defaults to half the
fastest the re-timed demos allow. Theorem, proof, costs: docs/equations.md, "The contracting NODE".

References
----------
Lohmiller, W., Slotine, J.-J. E. (1998). On contraction analysis for non-linear systems. Automatica 34(6).
Jaffe, S. et al. (2024). Learning neural contracting dynamics: extended linearization and global
guarantees. NeurIPS. arXiv:2402.08090
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

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.learners.base import Learner
from lfd.learners.contraction import (
    DEFAULT_MAX_CONDITION,
    ContractionField,
    ContractionLearner,
    ContractionModule,
    RateFeasibilityWarning,
    feasible_rate,
)
from lfd.learners.node import shoot_segments, uniform_grid
from lfd.learners.optim import Adam
from lfd.threads import torch_threads
from lfd.validate import check_bools, check_ints, check_numbers

POSTFIX_EVERY = 25
# rate None (the default): RATE_FRACTION of the largest rate the re-timed demos' timing allows within the
# condition bound (``feasible_rate``), clipped to RATE_RANGE: a faster rate recovers sooner from a push
# and fits the demos less closely (reports/contracting_node.md)
RATE_FRACTION = 0.5
RATE_RANGE = (0.05, 5.0)   # 1/s


@dataclass
class ContractingNodeConfig:
    """Options of the contracting NODE.

    rate : lambda of Eq. (N1), 1/s, > 0 (the guaranteed contraction rate); None: chosen from the demos
           (RATE_FRACTION of their feasible rate, clipped to RATE_RANGE) and written here by ``fit``
    max_condition : KAPPA > 1, the bound on b/a of the metric (inf: none)
    layers, hidden, window, length_scale : the flow phi (``lfd.learners.flows``), normalised units
    damping : learn the extra damping P of A (else sym(A) = -lambda I)
    units : H, the ridge units of Eq. (N1) (0: the linear latent field of the contraction learner)
    lr, lr_final : Adam's learning rate, cosine-annealed over ``iterations``
    seg, seg_start, curriculum, batch, samples : multiple shooting as the NODE's (``lfd.learners.node``)
    monotone_speed : re-time the demos first, Eq. (N4)
    path_weight, path_points, path_samples : w_p of Eq. (N5) (0: shooting alone), the points per demo
    of its path and the RK4 steps of the whole rollout compared with them
    """

    rate: float | None = None
    max_condition: float = DEFAULT_MAX_CONDITION
    layers: int = 4
    hidden: int = 32
    window: float = 1.5
    length_scale: float = 0.5
    damping: bool = True
    units: int = 32
    lr: float = 1e-2
    lr_final: float = 1e-4
    iterations: int = 400
    seg: int = 15
    seg_start: int = 4
    curriculum: float = 0.5
    batch: int = 48
    samples: int = 100
    monotone_speed: bool = True
    path_weight: float = 1.0
    path_points: int = 25
    path_samples: int = 40

    def __post_init__(self) -> None:
        if self.rate is not None:
            check_numbers(self, ("rate",), "a positive number below 1e6 (or null: from the demos)",
                          lambda v: 0 < v <= 1e6, to_float=True)
        check_numbers(self, ("window", "length_scale"), "a positive number below 1e6",
                      lambda v: 0 < v <= 1e6, to_float=True)
        check_numbers(self, ("lr", "lr_final"), "a positive number at most 1", lambda v: 0 < v <= 1, to_float=True)
        check_numbers(self, ("max_condition",), "a number > 1 (or inf)", lambda v: v > 1, to_float=True,
                      allow_inf=True)
        check_numbers(self, ("path_weight",), "a non-negative number below 1e6", lambda v: 0 <= v <= 1e6,
                      to_float=True)
        check_numbers(self, ("curriculum",), "a number in [0, 1]", lambda v: 0.0 <= v <= 1.0, to_float=True)
        check_ints(self, (("layers", 1, 64), ("hidden", 1, 4096), ("units", 0, 4096), ("iterations", 0, 10**6),
                          ("seg", 2, 10**4), ("seg_start", 2, 10**4), ("batch", 0, 10**6), ("samples", 0, 10**5),
                          ("path_points", 2, 10**4), ("path_samples", 2, 10**4)))
        check_bools(self, ("damping", "monotone_speed"))
        if self.lr_final > self.lr:
            raise ValueError(f"lr_final ({self.lr_final}) must not exceed lr ({self.lr})")
        if self.seg_start > self.seg:
            raise ValueError(f"seg_start ({self.seg_start}) must not exceed seg ({self.seg})")
        if 0 < self.samples < self.seg:
            raise ValueError(f"samples ({self.samples}) must be at least seg ({self.seg})")


class ContractingNodeModule(ContractionModule):
    """f_n of Eq. (N2) on normalised coordinates: x_n, shape (B, d) -> dx_n/dt, shape (B, d).

    The contraction learner's module (phi, A) with the ridge term of Eq. (N1): W (H, d), c (H,) and
    delta (H,), D = softplus(delta). A fresh module has phi = identity and a small ridge term.
    """

    def __init__(self, dim: int, config: ContractingNodeConfig) -> None:
        super().__init__(dim, config)  # type: ignore[arg-type]  # the same option names (duck-typed)
        units = config.units
        self.ridge_w = nn.Parameter(torch.randn(units, dim) / config.length_scale)
        self.ridge_c = nn.Parameter(4.0 * torch.rand(units) - 2.0)
        self.ridge_delta = nn.Parameter(torch.full((units,), -3.0))

    def ridge_gain(self) -> torch.Tensor:
        """D's diagonal, softplus(delta) >= 0, shape (H,)."""
        return nn.functional.softplus(self.ridge_delta)

    def latent_velocity(self, y: torch.Tensor, y_star: torch.Tensor) -> torch.Tensor:
        """h(y) of Eq. (N1), shape (B, d), at y, shape (B, d), with y* = phi(0), shape (1, d)."""
        return self.latent_function(y_star)(y)

    def latent_function(self, y_star: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        """y (B, d) -> h(y) (B, d) of Eq. (N1), with A, D and tanh(W y* + c) formed once (for a solver's
        many evaluations in one training step)."""
        a_t = self.latent_matrix().T
        w, c, g = self.ridge_w, self.ridge_c, self.ridge_gain()
        t_star = torch.tanh(y_star @ w.T + c)                                 # (1, H)

        def h(y: torch.Tensor) -> torch.Tensor:
            return (y - y_star) @ a_t - (g * (torch.tanh(y @ w.T + c) - t_star)) @ w

        return h

    def latent_lipschitz(self) -> torch.Tensor:
        """Lip(h) <= |A|_2 + |W' D W|_2 (tanh' <= 1), a scalar tensor."""
        w = self.ridge_w
        ridge = torch.linalg.matrix_norm(w.T @ (self.ridge_gain()[:, None] * w), ord=2) if len(w) else 0.0
        return torch.linalg.matrix_norm(self.latent_matrix(), ord=2) + ridge

    def trajectory(self, x0: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Not in closed form for Eq. (N1): integrate the field instead (``VelocityField.rollout``)."""
        raise NotImplementedError("the contracting NODE's flow has no closed form; use rollout")


def rk4_latent(h: Callable[[torch.Tensor], torch.Tensor], y0: torch.Tensor, step: torch.Tensor,
               samples: int) -> torch.Tensor:
    """Classical RK4 on dy/dt = h(y): y at the ``samples`` times j step_b, shape (samples, B, d).

    y0 : (B, d) starts; step : (B, 1) each row's time step (the paper's Eq. (3), one step per sample).
    """
    ys = [y0]
    y, half, sixth = y0, step / 2, step / 6
    for _ in range(samples - 1):
        k1 = h(y)
        k2 = h(y + half * k1)
        k3 = h(y + half * k2)
        k4 = h(y + step * k3)
        y = y + sixth * (k1 + 2 * k2 + 2 * k3 + k4)
        ys.append(y)
    return torch.stack(ys)


def monotone_speed_retime(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Eq. (N4): new sample times for one demo, shape (T,), keeping its path x, shape (T, d).

    Each step k keeps its length and moves at v'_k = max_{j >= k} v_j (v_j the demo's speed on step j),
    the largest speed still to come: the speed never rises, the deceleration is the demo's own. Steps
    with nothing moving after them (a demo resting at its end) keep their time.
    """
    dt = np.diff(t)
    ds = np.linalg.norm(np.diff(x, axis=0), axis=1)
    v = np.where(dt > 0, ds / np.where(dt > 0, dt, 1.0), 0.0)
    v_new = np.maximum.accumulate(v[::-1])[::-1]
    dt_new = np.where(v_new > 0, ds / np.where(v_new > 0, v_new, 1.0), dt)
    return t[0] + np.concatenate([[0.0], np.cumsum(dt_new)])


def retimed(demos: DemoSet) -> DemoSet:
    """``demos`` with each demo re-timed by Eq. (N4) and resampled to its own sample count on its
    new, shorter time (linear interpolation)."""
    ts, xs = [], []
    for t, x in zip(demos.t, demos.x):
        tn = monotone_speed_retime(t, x)
        grid = np.linspace(tn[0], tn[-1], len(t))
        xs.append(np.stack([np.interp(grid, tn, x[:, j]) for j in range(x.shape[1])], axis=1))
        ts.append(grid)
    return DemoSet(np.stack(ts), np.stack(xs), name=demos.name, end_tolerance=demos.end_tolerance)


class ContractingNodeField(ContractionField):
    """The contracting NODE's field: contracting by construction (Eqs. (N1)-(N2), (C1)), with the
    contraction learner's metric, rate and analytic bounds; its flow is integrated, not in closed form."""

    module: ContractingNodeModule

    def closed_form_rollout(self, x0: np.ndarray, t: np.ndarray) -> None:  # type: ignore[override]  # none here
        """None: Eq. (N1) has no closed-form flow (rollouts integrate, ``rollout``)."""
        return None

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """x (d,) -> f(x) (d,) in user units, Eq. (N2) in one compiled call (``lfd.learners.flow_kernel``),
        compiled or loaded now, not in the first control step."""
        from lfd.learners.flow_kernel import contraction_point_fn

        m = self.module
        with torch.no_grad():
            ridge = (m.ridge_w.numpy().copy(), m.ridge_c.numpy().copy(), m.ridge_gain().numpy().copy())
        return contraction_point_fn(m.flow.numpy_params(), self.latent_matrix, self.norm.goal,
                                    float(self.norm.scale), ridge=ridge)


class ContractingNodeLearner(Learner, name="contracting_node", config=ContractingNodeConfig,
                             field=ContractingNodeField):
    """A NODE contracting by construction: a bounded flow of a contracting latent field, Eqs. (N1)-(N2)."""

    @classmethod
    def parameter_count(cls, dim: int, config: ContractingNodeConfig) -> int:
        """The contraction learner's flow and A (``ContractionLearner.parameter_count``: the same option
        names) plus the ridge term's H (d + 2)."""
        return ContractionLearner.parameter_count(dim, config) + config.units * (dim + 2)  # type: ignore[arg-type]

    @classmethod
    def build(cls, dim: int, config: ContractingNodeConfig) -> ContractingNodeModule:
        """A fresh float64 module; trains in float64."""
        return ContractingNodeModule(dim, config).double()

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: ContractingNodeConfig,
            progress: bool) -> dict[str, Any]:
        """Multiple shooting of Eq. (N1) on the normalised (and, with ``monotone_speed``, re-timed)
        demos; one thread; Ctrl-C keeps the best module so far.

        Returns ``loss`` (per iteration), ``best_loss``, ``best_iter``, ``seg``, ``iterations``,
        ``interrupted``, ``stopped_nonfinite`` and ``feasible_rate`` (of the demos it trained on;
        warns with ``RateFeasibilityWarning`` when ``rate`` is above it).
        """
        assert isinstance(module, ContractingNodeModule)
        if config.monotone_speed:
            demos = retimed(demos)
        x, h = uniform_grid(demos, config.samples)
        if config.seg > x.shape[1]:
            raise ConfigError(f"contracting_node: seg ({config.seg}) exceeds the {x.shape[1]} samples per demo")
        lam_max = feasible_rate(x - x[:, -1:], np.stack([np.arange(x.shape[1]) * hn for hn in h]),
                                config.max_condition)
        if config.rate is None:
            config.rate = float(np.clip(RATE_FRACTION * lam_max, *RATE_RANGE))
            module.rate = config.rate
        if config.rate > lam_max:
            warnings.warn(f"rate {config.rate:g}/s is above the largest feasible for these demos within "
                          f"max_condition {config.max_condition:g} ({lam_max:.3g}/s): rollouts arrive before "
                          "the demos do", RateFeasibilityWarning, stacklevel=3)
        with torch_threads(1):
            history = _shoot(module, torch.tensor(x), torch.tensor(h), config, progress)
        history["feasible_rate"] = lam_max if math.isfinite(lam_max) else None
        return history


def _shooting_loss(module: ContractingNodeModule, w: torch.Tensor, hb: torch.Tensor, paths: torch.Tensor,
                   path_step: torch.Tensor, path_samples: int, path_weight: float) -> torch.Tensor:
    """Eq. (N5), a scalar: the multiple-shooting error of windows w, shape (S, B, d), with steps hb,
    shape (B, 1), plus ``path_weight`` times the Chamfer distance between each demo's whole rollout
    (``path_samples`` RK4 steps of path_step, shape (N, 1), from its start) and its points paths,
    shape (N, K, d). Every latent error e at a demo point x is mapped back to x to first order,
    J_phi(x)^-1 e (a latent error alone could be scaled away by phi)."""
    s_len, b, d = w.shape
    n, k = paths.shape[:2]
    zero = w.new_zeros(1, d)
    y, jac = module.flow.forward_with_jacobian(torch.cat([w.reshape(-1, d), paths.reshape(-1, d), zero]))
    assert jac is not None
    y_star, nw = y[-1:], s_len * b
    h = module.latent_function(y_star)
    yw = y[:nw].reshape(w.shape)
    pred = rk4_latent(h, yw[0], hb, s_len)
    err = torch.linalg.solve(jac[:nw].reshape(s_len, b, d, d)[1:], (pred[1:] - yw[1:]).unsqueeze(-1))
    loss = (err ** 2).sum((-1, -2)).mean()
    if path_weight > 0:
        yp, jinv = y[nw:nw + n * k].reshape(n, k, d), torch.linalg.inv(jac[nw:nw + n * k]).reshape(n, k, d, d)
        roll = rk4_latent(h, yp[:, 0], path_step, path_samples).transpose(0, 1)            # (N, P, d)
        e = torch.einsum("nkij,npkj->npki", jinv, roll[:, :, None] - yp[:, None])          # (N, P, K, d)
        dist = (e * e).sum(-1)
        loss = loss + path_weight * (dist.min(2).values.mean() + dist.min(1).values.mean()
                                     + dist[:, -1, -1].mean())
    return loss


class _LatentShooter:
    """Eq. (N5) on segments and whole demos, and Adam with its cosine schedule (``shoot_segments``).

    x : (N, T, d) normalised demos on uniform grids; h : (N,) their sample steps, s.
    """

    def __init__(self, module: ContractingNodeModule, x: torch.Tensor, h: torch.Tensor,
                 config: ContractingNodeConfig) -> None:
        self.module, self.config = module, config
        self.opt = Adam(module.parameters(), lr=config.lr, lr_final=config.lr_final, t_max=config.iterations)
        k_idx = np.unique(np.linspace(0, x.shape[1] - 1, config.path_points).round().astype(int))
        self.paths = x[:, k_idx]                                                     # (N, K, d)
        self.path_step = (h * (x.shape[1] - 1) / (config.path_samples - 1))[:, None]   # (N, 1)

    def loss(self, w: torch.Tensor, hb: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """Eq. (N5) for windows w (S, B, d) with steps hb (B, 1); tau is not needed (one RK4 step a sample)."""
        c = self.config
        return _shooting_loss(self.module, w, hb, self.paths, self.path_step, c.path_samples, c.path_weight)

    def step(self, loss: torch.Tensor) -> None:
        """One Adam step on ``loss``, then one step of the schedule."""
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()


def _shoot(module: ContractingNodeModule, x: torch.Tensor, h: torch.Tensor, config: ContractingNodeConfig,
           progress: bool) -> dict[str, Any]:
    """Adam on Eq. (N5) in float64, by ``lfd.learners.node.shoot_segments`` after starting A at the
    least-squares contracting fit (``init_latent_from_data``).

    x : (N, T, d) normalised demos on uniform grids; h : (N,) their sample steps, s.
    """
    x, h = x.double(), h.double()
    module.train()
    with torch.no_grad():
        v_all = ((x[:, 1:] - x[:, :-1]) / h[:, None, None]).reshape(-1, x.shape[-1])
        module.init_latent_from_data(x[:, :-1].reshape(-1, x.shape[-1]), v_all)
    return shoot_segments(module, x, h, config, _LatentShooter(module, x, h, config), progress, "contracting_node",
                          "contracting_node")
