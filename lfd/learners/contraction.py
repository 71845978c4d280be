"""Contracting velocity fields by construction: a learned diffeomorphism of a linear contracting system.

A field dx/dt = f(x) contracts with rate lambda > 0 in a metric M(x), a I <= M(x) <= b I, when

    Eq. (C1): J_f' M + M J_f + dM/dt <= -2 lambda M   for all x,   dM/dt = sum_k (dM/dx_k) f_k,

and then |dx(t)| <= sqrt(b / a) |dx(0)| exp(-lambda t) for any two neighbouring trajectories.

This learner never has to check Eq. (C1): it holds for every x by construction. With a learned
diffeomorphism phi (``lfd.learners.flows``, affine coupling layers) and a latent linear system

    Eq. (C2): dy/dt = A (y - y*),  y* = phi(0),  A = -lambda I + S - P,
              S = W - W' (skew-symmetric), P = L L' (L lower-triangular; PSD extra damping),

the field in normalised coordinates (goal at the origin) is

    Eq. (C3): f(x) = J_phi(x)^-1 A (phi(x) - y*),

so y = phi(x) obeys Eq. (C2) exactly and a displacement dx maps to dy = J_phi dx with
d/dt dy = A dy. In the metric M(x) = J_phi(x)' J_phi(x),

    J_f' M + M J_f + dM/dt = J_phi' (A + A') J_phi <= -2 lambda J_phi' J_phi = -2 lambda M,

because sym(A) = -lambda I - P <= -lambda I. The trajectory from x0 has the closed form

    Eq. (C4): x(t) = phi^-1(y* + exp(A t) (phi(x0) - y*)),

which training uses for trajectory matching. The loss, in normalised units, is

    Eq. (C5): L = mean_i |f(x_i) - xd_i|^2 / mean |xd|^2
                  + w_x mean_{n,k} |x_n(t_k) - x_demo,n(t_k)|^2 / mean |x_demo|^2
                  + w_D mean_j D(J_phi(z_j)),

with x_n(t) of Eq. (C4) started at demo n's first sample, t_k at ``traj_points`` samples of the
demo and at T_n (1 + r), r in ``REST_TIMES``, where the target is the goal (a demo rests there
after its last sample; this stops fits that sweep past the goal and loop back), and

    Eq. (C6): D(J) = |J|_F^2 / |det J|^(2/d) - d >= 0,

the conformal distortion of phi (zero iff J is a scaled rotation; for d = 2 it is
s1/s2 + s2/s1 - 2 in the singular values), at points z_j drawn uniformly from the demos' box
grown to 3x its size. It keeps the metric well conditioned, i.e. b/a and the overshoot factor
sqrt(b/a) of Eq. (C1) small, at a small cost in accuracy. L is minimised by full-batch L-BFGS.

Units: x_n = (x - goal) / s is an isotropic scaling and time is not rescaled, so lambda is the
same in user time (1/s), and the metric in user units is M(x) = M_n(x_n) / s^2 (``metric``).
"""

from __future__ import annotations

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

DEFAULT_RATE = 0.5             # 1/s: below the ~1/s decay of 3-5 s demos, so it leaves room to fit them
REST_TIMES = (0.1, 0.25, 0.5, 1.0)  # Eq. (C5): at T (1 + r) a demo rests at its goal (the origin)
DISTORTION_POINTS = 256       # Eq. (C6): points z_j per fit ...
DISTORTION_BOX_GROWTH = 2.0   # ... drawn from the demos' box grown by 200% (3x its size)


def distortion(jac: torch.Tensor) -> torch.Tensor:
    """Eq. (C6): D(J) = |J|_F^2 / |det J|^(2/d) - d, shape (B,), for J : tensor, shape (B, d, d)."""
    d = jac.shape[-1]
    return (jac * jac).sum((-2, -1)) / torch.linalg.det(jac).abs() ** (2.0 / d) - d


@dataclass
class ContractionConfig:
    """Options of the contraction learner.

    rate : lambda of Eqs. (C1)-(C2), 1/s, > 0 (the guaranteed contraction rate)
    layers, features, length_scale, window, log_scale_bound : the coupling flow phi
        (``lfd.learners.flows``; window 0: none), in normalised units
    damping : learn the extra damping P of Eq. (C2) (else P = 0 and sym(A) = -lambda I)
    iterations : loss evaluations of L-BFGS; batch : velocity points (a fixed seeded subsample)
    traj_weight, traj_points : w_x of Eq. (C5) and the samples per demo it compares (0 disables)
    distortion_weight : w_D of Eq. (C5), the weight of the conformal distortion Eq. (C6) (0 disables)
    """

    rate: float = DEFAULT_RATE
    layers: int = 6
    features: int = 32
    length_scale: float = 0.45
    log_scale_bound: float = 2.0
    damping: bool = True
    iterations: int = 200
    batch: int = 1000
    traj_weight: float = 10.0
    traj_points: int = 25
    distortion_weight: float = 0.01
    window: float = 1.5

    def __post_init__(self) -> None:
        for name in ("rate", "length_scale", "log_scale_bound", "traj_weight", "distortion_weight", "window"):
            v = getattr(self, name)
            may_be_zero = name.endswith("_weight") or name == "window"
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0 or (v == 0 and not may_be_zero):
                raise ValueError(f"{name} must be a {'non-negative' if may_be_zero else 'positive'} "
                                 f"number, got {v!r}")
            setattr(self, name, float(v))
        for name in ("layers", "features", "iterations", "batch", "traj_points"):
            v = getattr(self, name)
            low = 0 if name == "iterations" else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {v!r}")
        if not isinstance(self.damping, bool):
            raise ValueError(f"damping must be true or false, got {self.damping!r}")


class ContractionModule(nn.Module):
    """f_n of Eq. (C3) on normalised coordinates: x_n, shape (B, d) -> dx_n/dt, shape (B, d)."""

    def __init__(self, dim: int, config: ContractionConfig) -> None:
        super().__init__()
        self.dim = dim
        self.rate = config.rate
        self.flow = CouplingFlow(dim, config.layers, config.features, config.length_scale,
                                 config.log_scale_bound, config.window)
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
        a_ls = torch.linalg.lstsq(x, v).solution.T
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
                            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """f(x) of Eq. (C3), shape (B, d), with y = phi(x), shape (B, d), y* = phi(0), shape (1, d),
        and J_phi(x), shape (B, d, d)."""
        y, jac = self.flow.forward_with_jacobian(torch.cat([x, x.new_zeros(1, self.dim)]))
        y, y_star, jac = y[:-1], y[-1:], jac[:-1]
        v = (y - y_star) @ self.latent_matrix().T              # A (phi(x) - y*)
        return torch.linalg.solve(jac, v.unsqueeze(-1)).squeeze(-1), y, y_star, jac

    def metric(self, x: torch.Tensor) -> torch.Tensor:
        """M_n(x) = J_phi(x)' J_phi(x), shape (B, d, d), for x : tensor, shape (B, d)."""
        _, jac = self.flow.forward_with_jacobian(x)
        return jac.transpose(-1, -2) @ jac

    def latent_trajectory(self, y0: torch.Tensor, y_star: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Eq. (C4) mapped back: x at times t, shape (N, K), from latent starts y0, shape (N, d): (N, K, d)."""
        at = self.latent_matrix() * t.reshape(-1, 1, 1)                             # (N K, d, d)
        e = torch.linalg.matrix_exp(at).reshape(*t.shape, self.dim, self.dim)      # (N, K, d, d)
        yt = y_star + (e @ (y0 - y_star)[:, None, :, None]).squeeze(-1)             # (N, K, d)
        return self.flow.inverse(yt.reshape(-1, self.dim)).reshape(yt.shape)

    def trajectory(self, x0: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Eq. (C4): the exact solutions from x0, shape (N, d), at times t, shape (N, K): (N, K, d)."""
        y = self.flow(torch.cat([x0, x0.new_zeros(1, self.dim)]))
        return self.latent_trajectory(y[:-1], y[-1:], t)


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

    def exact_rollout(self, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Eq. (C4), no ODE solver: x0 : array, shape (B, d); t : array, shape (T,), t[0] the start.

        Returns shape (B, T, d) in user units.
        """
        x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
        tt = torch.from_numpy(np.broadcast_to(np.asarray(t, dtype=np.float64) - t[0], (len(x0), len(t))).copy())
        with torch.no_grad():
            xn = self.module.trajectory(torch.from_numpy(self.norm.to_norm(x0)), tt).numpy()
        return self.norm.from_norm(xn)

    def _point_fn_normalized(self) -> Callable[[np.ndarray], np.ndarray]:
        """Eq. (C3) for one point: phi and J_phi by ``coupling_flow_numpy``, then a d x d solve
        (Cramer's rule for d = 2)."""
        params = self.module.flow.numpy_params()
        a = self.latent_matrix
        y_star, _ = coupling_flow_numpy(params, [0.0] * self.dim)
        if self.dim == 2:
            a00, a01, a10, a11 = (float(v) for v in a.ravel())
            s0, s1 = y_star

            def f2(xn: np.ndarray) -> np.ndarray:
                (y0, y1), ((j00, j01), (j10, j11)) = coupling_flow_numpy(params, xn)
                e0, e1 = y0 - s0, y1 - s1
                v0, v1 = a00 * e0 + a01 * e1, a10 * e0 + a11 * e1
                det = j00 * j11 - j01 * j10
                return np.array([(j11 * v0 - j01 * v1) / det, (j00 * v1 - j10 * v0) / det])

            return f2
        ys = np.asarray(y_star)

        def fd(xn: np.ndarray) -> np.ndarray:
            y, j = coupling_flow_numpy(params, xn)
            return np.linalg.solve(np.asarray(j), a @ (np.asarray(y) - ys))

        return fd


class _NonFinite(Exception):
    """The loss became NaN or inf: stop and keep the best parameters."""


class ContractionLearner(Learner):
    """Velocity field = diffeomorphism of a linear contracting system, Eqs. (C2)-(C3)."""

    name: ClassVar[str] = "contraction"
    Config: ClassVar[type] = ContractionConfig
    field_class: ClassVar[type[VelocityField]] = ContractionField

    @classmethod
    def build(cls, dim: int, config: ContractionConfig) -> ContractionModule:
        """A fresh float64 module (phi = identity, A = -lambda I - 0.09 I); trains in float64."""
        return ContractionModule(dim, config).double()

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: ContractionConfig,
            progress: bool) -> dict[str, Any]:
        """Minimise Eq. (C5) by L-BFGS on normalised demos; Ctrl-C keeps the best module so far.

        Runs single-threaded (the tensors are small: one thread is as fast and immune to
        oversubscription). Returns ``loss`` (per evaluation), ``best_loss``, ``iterations``,
        ``interrupted`` and ``stopped_nonfinite`` (``lfd.train`` adds the demos' box).
        """
        assert isinstance(module, ContractionModule)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return cls._fit(module, demos, config, progress)
        finally:
            torch.set_num_threads(threads)

    @classmethod
    def _fit(cls, module: ContractionModule, demos: DemoSet, config: ContractionConfig,
             progress: bool) -> dict[str, Any]:
        dtype = next(module.parameters()).dtype

        def tensor(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(a, dtype=dtype)

        d, n0 = demos.dim, demos.n_demos
        # velocity matching: a fixed, seeded subsample of ``batch`` demo points
        x_all, v_all = tensor(demos.x.reshape(-1, d)), tensor(demos.xd.reshape(-1, d))
        pick = torch.randperm(len(x_all))[:config.batch] if len(x_all) > config.batch else slice(None)
        x, v = x_all[pick], v_all[pick]
        v_scale = float((v_all * v_all).sum(1).mean())
        # trajectory matching: traj_points samples per demo, then the goal (the origin) at rest
        k_idx = np.unique(np.linspace(0, demos.n_samples - 1, config.traj_points).round().astype(int))
        t_rel = demos.t[:, k_idx] - demos.t[:, :1]
        tk = tensor(np.concatenate([t_rel, t_rel[:, -1:] * (1.0 + np.asarray(REST_TIMES))], axis=1))
        xk = tensor(np.concatenate([demos.x[:, k_idx], np.zeros((n0, len(REST_TIMES), d))], axis=1))
        x_scale = float((xk * xk).sum(-1).mean())
        # distortion: points drawn from the grown box
        lo, hi = (tensor(b) for b in demos.bounds(DISTORTION_BOX_GROWTH))
        z = lo + (hi - lo) * torch.rand(DISTORTION_POINTS, d, dtype=dtype)
        # one pass of phi and J_phi serves all three terms: rows [x | demo starts | z]
        nv = len(x)
        x_in = torch.cat([x, tensor(demos.x[:, 0]), z])

        module.train()
        module.init_latent_from_data(x_all, v_all)
        opt = torch.optim.LBFGS(module.parameters(), lr=1.0, max_iter=max(config.iterations, 1),
                                max_eval=config.iterations, history_size=50, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-10, tolerance_change=1e-12)
        losses: list[float] = []
        best: dict[str, Any] = {"loss": math.inf, "state": None}
        bar = tqdm(total=config.iterations, desc=f"contraction (rate {config.rate:g}/s)",
                   disable=not progress, leave=False)

        def closure() -> torch.Tensor:
            opt.zero_grad()
            f, y, y_star, jac = module.velocity_and_latent(x_in)
            err_v = f[:nv] - v
            loss = (err_v * err_v).sum(1).mean() / v_scale
            if config.traj_weight > 0:
                err_x = module.latent_trajectory(y[nv:nv + n0], y_star, tk) - xk
                loss = loss + config.traj_weight * (err_x * err_x).sum(-1).mean() / x_scale
            if config.distortion_weight > 0:
                loss = loss + config.distortion_weight * distortion(jac[nv + n0:]).mean()
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
