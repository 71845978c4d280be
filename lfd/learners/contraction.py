"""Contracting velocity fields by construction: a learned diffeomorphism of a linear contracting system.

A field dx/dt = f(x) contracts with rate lambda > 0 in a metric M(x), a I <= M(x) <= b I, when

    Eq. (C1): J_f' M + M J_f + dM/dt <= -2 lambda M   for all x,   dM/dt = sum_k (dM/dx_k) f_k,

and then |dx(t)| <= sqrt(b / a) |dx(0)| exp(-lambda t) for any two neighbouring trajectories.

This learner never has to check Eq. (C1): it holds for every x by construction. With a learned
diffeomorphism phi (``lfd.learners.flows``, affine coupling layers) and a latent linear system

    Eq. (C2): dy/dt = A (y - y*),  y* = phi(0),  A = -lambda I + S - P,
              S = W - W' (skew-symmetric), P = L L' (PSD, learned extra damping),

the field in normalised coordinates (goal at the origin) is

    Eq. (C3): f(x) = J_phi(x)^-1 A (phi(x) - y*),

so y = phi(x) obeys Eq. (C2) exactly and a displacement dx maps to dy = J_phi dx with
d/dt dy = A dy. In the metric M(x) = J_phi(x)' J_phi(x),

    J_f' M + M J_f + dM/dt = J_phi' (A + A') J_phi <= -2 lambda J_phi' J_phi = -2 lambda M,

because sym(A) = -lambda I - P <= -lambda I. The trajectory from x0 has the closed form

    Eq. (C4): x(t) = phi^-1(y* + exp(A t) (phi(x0) - y*)),

which training uses for trajectory matching. The loss, in normalised units, is

    Eq. (C5): L = mean |f(x_i) - xd_i|^2 / mean |xd|^2 + w mean |x(t_k) - x_demo(t_k)|^2 / mean |x_demo|^2.

Units: x_n = (x - goal) / s is an isotropic scaling and time is not rescaled, so lambda is the
same in user time (1/s), and the metric in user units is M(x) = M_n(x_n) / s^2 (``metric``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar

import numpy as np
import torch
from torch import nn
from tqdm.auto import tqdm

from lfd.demos import DemoSet
from lfd.field import VelocityField
from lfd.learners.base import Learner
from lfd.learners.flows import CouplingFlow, coupling_flow_numpy

GRAD_CLIP = 10.0  # max gradient norm per Adam step
DEFAULT_RATE = 0.5  # 1/s: demos of 4-5 s decay by ~e^-2.5, so 0.5 leaves room to fit them


@dataclass
class ContractionConfig:
    """Options of the contraction learner.

    rate : lambda of Eq. (C1)-(C2), 1/s, > 0 (guaranteed contraction rate)
    layers, features, length_scale, log_scale_bound : the coupling flow phi (``lfd.learners.flows``)
    damping : learn the extra damping P of Eq. (C2) (else P = 0 and sym(A) = -lambda I)
    iterations, lr, batch : Adam steps, learning rate (cosine-decayed), velocity points per step
    traj_weight, traj_points : w of Eq. (C5) and the samples per demo it compares (0 disables)
    """

    rate: float = DEFAULT_RATE
    layers: int = 8
    features: int = 64
    length_scale: float = 0.45
    log_scale_bound: float = 2.0
    damping: bool = True
    iterations: int = 1000
    lr: float = 1e-2
    batch: int = 512
    traj_weight: float = 1.0
    traj_points: int = 25

    def __post_init__(self) -> None:
        if not (isinstance(self.rate, (int, float)) and math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"rate must be a positive number (1/s), got {self.rate!r}")
        for name in ("layers", "features", "iterations", "batch", "traj_points"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < (0 if name == "iterations" else 1):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not (self.log_scale_bound > 0 and self.length_scale > 0 and self.lr > 0 and self.traj_weight >= 0):
            raise ValueError("log_scale_bound, length_scale and lr must be positive, traj_weight non-negative")
        self.rate = float(self.rate)


class ContractionModule(nn.Module):
    """f_n of Eq. (C3) on normalised coordinates: x_n, shape (B, d) -> dx_n/dt, shape (B, d)."""

    def __init__(self, dim: int, config: ContractionConfig) -> None:
        super().__init__()
        self.dim = dim
        self.rate = config.rate
        self.flow = CouplingFlow(dim, config.layers, config.features, config.length_scale,
                                 config.log_scale_bound)
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
        eigenvalues clipped below at 1e-3. With phi = identity, f(x) = A x starts as the best
        linear contracting field (up to that projection).
        """
        a_ls = torch.linalg.lstsq(x, v).solution.T
        self.skew.copy_(0.5 * (a_ls - a_ls.T) / 2)
        if self.damping is not None:
            evals, evecs = torch.linalg.eigh(-(0.5 * (a_ls + a_ls.T)) - self.rate * torch.eye(self.dim, dtype=x.dtype))
            p = evecs @ torch.diag(evals.clamp_min(1e-3)) @ evecs.T
            self.damping.copy_(torch.linalg.cholesky(p))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Eq. (C3). x : tensor, shape (B, d); returns f(x), shape (B, d)."""
        y, jac = self.flow.forward_with_jacobian(torch.cat([x, x.new_zeros(1, self.dim)]))
        v = (y[:-1] - y[-1:]) @ self.latent_matrix().T          # A (phi(x) - y*), y* = phi(0)
        return torch.linalg.solve(jac[:-1], v.unsqueeze(-1)).squeeze(-1)

    def metric(self, x: torch.Tensor) -> torch.Tensor:
        """M_n(x) = J_phi(x)' J_phi(x), shape (B, d, d), for x : tensor, shape (B, d)."""
        _, jac = self.flow.forward_with_jacobian(x)
        return jac.transpose(-1, -2) @ jac

    def trajectory(self, x0: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Eq. (C4): exact solutions from x0, shape (N, d), at times t, shape (N, K): (N, K, d)."""
        y = self.flow(torch.cat([x0, x0.new_zeros(1, self.dim)]))
        y0, ys = y[:-1], y[-1:]
        at = self.latent_matrix() * t.reshape(-1, 1, 1)                             # (N K, d, d)
        e = torch.linalg.matrix_exp(at).reshape(*t.shape, self.dim, self.dim)      # (N, K, d, d)
        yt = ys + (e @ (y0 - ys)[:, None, :, None]).squeeze(-1)                     # (N, K, d)
        return self.flow.inverse(yt.reshape(-1, self.dim)).reshape(yt.shape)


class ContractionField(VelocityField):
    """A field contracting by construction (Eq. (C1)), with its metric and rate.

    ``rate`` is lambda in 1/s; ``metric(x)`` is M(x) in user units; ``point_fn()`` is a numpy
    single-point evaluator that agrees with the torch path to 1e-10.
    """

    module: ContractionModule

    @property
    def rate(self) -> float:
        """The guaranteed contraction rate lambda, 1/s (the same in user and normalised time)."""
        return float(self.config["rate"])

    @property
    def latent_matrix(self) -> np.ndarray:
        """A of Eq. (C2), shape (d, d); -max eig sym(A) >= rate is the rate actually built in."""
        with torch.no_grad():
            return self.module.latent_matrix().numpy().copy()

    def metric_normalized_torch(self, xn: torch.Tensor) -> torch.Tensor:
        """M_n(x_n) = J_phi' J_phi, shape (B, d, d); differentiable (used by ``lfd.certify``)."""
        return self.module.metric(xn)

    def metric(self, x: np.ndarray) -> np.ndarray:
        """M(x) = J_phi(x_n)' J_phi(x_n) / s^2 in user units. x : array, shape (..., d) -> (..., d, d)."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"metric expects points of dimension {self.dim}, got shape {x.shape}")
        xn = torch.from_numpy(self.norm.to_norm(x.reshape(-1, self.dim)))
        with torch.no_grad():
            m = self.module.metric(xn).numpy()
        return m.reshape(*x.shape, self.dim) / self.norm.scale ** 2

    def _point_fn_normalized(self) -> Callable[[np.ndarray], np.ndarray]:
        """Eq. (C3) for one point in numpy: phi and J_phi by ``coupling_flow_numpy``, then a d x d solve."""
        params = self.module.flow.numpy_params()
        a = self.latent_matrix
        y_star, _ = coupling_flow_numpy(params, np.zeros(self.dim))
        if self.dim == 2:
            a00, a01, a10, a11 = (float(v) for v in a.ravel())

            def f2(xn: np.ndarray) -> np.ndarray:
                y, j = coupling_flow_numpy(params, xn)
                e0, e1 = y[0] - y_star[0], y[1] - y_star[1]
                v0, v1 = a00 * e0 + a01 * e1, a10 * e0 + a11 * e1
                j00, j01, j10, j11 = j[0, 0], j[0, 1], j[1, 0], j[1, 1]
                det = j00 * j11 - j01 * j10
                return np.array([(j11 * v0 - j01 * v1) / det, (j00 * v1 - j10 * v0) / det])

            return f2

        def fd(xn: np.ndarray) -> np.ndarray:
            y, j = coupling_flow_numpy(params, xn)
            return np.linalg.solve(j, a @ (y - y_star))

        return fd


class ContractionLearner(Learner):
    """Velocity field = diffeomorphism of a linear contracting system, Eqs. (C2)-(C3)."""

    name: ClassVar[str] = "contraction"
    Config: ClassVar[type] = ContractionConfig
    field_class: ClassVar[type[VelocityField]] = ContractionField

    @classmethod
    def build(cls, dim: int, config: ContractionConfig) -> ContractionModule:
        return ContractionModule(dim, config)

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: ContractionConfig,
            progress: bool) -> dict[str, Any]:
        """Minimise Eq. (C5) with Adam on normalised demos; Ctrl-C keeps the best module so far.

        Returns ``loss`` (per step), ``best_loss``, ``iterations``, ``interrupted`` and
        ``demo_box_normalized`` (lo, hi of the demos in normalised units, for ``lfd certify``).
        """
        assert isinstance(module, ContractionModule)
        module.train()
        dtype = next(module.parameters()).dtype
        x = torch.as_tensor(demos.x.reshape(-1, demos.dim), dtype=dtype)
        v = torch.as_tensor(demos.xd.reshape(-1, demos.dim), dtype=dtype)
        v_scale = float((v * v).sum(1).mean())
        k_idx = np.unique(np.linspace(0, demos.n_samples - 1, config.traj_points).round().astype(int))
        x0 = torch.as_tensor(demos.x[:, 0], dtype=dtype)
        tk = torch.as_tensor(demos.t[:, k_idx] - demos.t[:, :1], dtype=dtype)
        xk = torch.as_tensor(demos.x[:, k_idx], dtype=dtype)
        x_scale = float((xk * xk).sum(-1).mean())

        module.init_latent_from_data(x, v)
        opt = torch.optim.Adam(module.parameters(), lr=config.lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(config.iterations, 1),
                                                           eta_min=0.05 * config.lr)
        losses: list[float] = []
        best_loss, best_state = math.inf, copy.deepcopy(module.state_dict())
        interrupted = False
        bar = tqdm(range(config.iterations), desc=f"contraction (rate {config.rate:g}/s)",
                   disable=not progress, leave=False)
        try:
            for it in bar:
                idx = torch.randint(x.shape[0], (min(config.batch, x.shape[0]),))
                err_v = module(x[idx]) - v[idx]
                loss = (err_v * err_v).sum(1).mean() / v_scale
                if config.traj_weight > 0:
                    err_x = module.trajectory(x0, tk) - xk
                    loss = loss + config.traj_weight * (err_x * err_x).sum(-1).mean() / x_scale
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(module.parameters(), GRAD_CLIP)
                opt.step()
                sched.step()
                value = float(loss.detach())
                losses.append(value)
                if value < best_loss:
                    best_loss = value
                    best_state = {k: t.detach().clone() for k, t in module.state_dict().items()}
                if it % 25 == 0:
                    bar.set_postfix(loss=f"{value:.4g}")
        except KeyboardInterrupt:
            interrupted = True
        finally:
            bar.close()
        if losses:
            module.load_state_dict(best_state)
        module.eval()
        lo, hi = demos.bounds()
        return {"loss": losses, "best_loss": best_loss if losses else None, "iterations": len(losses),
                "interrupted": interrupted, "demo_box_normalized": [lo.tolist(), hi.tolist()]}
