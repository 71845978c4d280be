"""A globally bi-Lipschitz diffeomorphism phi : R^d -> R^d with analytic bounds (``BoundedFlow``).

phi alternates two kinds of layers, each a bijection of R^d whose Jacobian has singular values
bounded on ALL of R^d by constants computed from its parameters:

    Eq. (F1): swirl  y = c + R(theta(r)) (x - c),  r = |x - c|,  theta(r) = sum_j Theta_j exp(-r^2 / (2 rho_j^2)),
    Eq. (F3): block  y = x + e(x) W2 tanh(W1 x + b1),  e(x) = exp(-|x|^2 / (2 R^2)),

a rotation that decays with the distance (singular values in [1/sigma_max(m), sigma_max(m)] for the
shear slope m, Eq. (F2); inverse in closed form) and an invertible residual block with a Gaussian
window (Lipschitz residual c < 1: singular values in [1 - c, 1 + c], inverse by fixed-point
iteration). The user's KAPPA is split over the layers as a learned log-condition budget, and each
layer's strength is smoothly saturated below its share, so that

    Eq. (F4): s_lo = prod_k sigma_min,k <= sigma(J_phi(x)) <= prod_k sigma_max,k = s_hi   for all x,

with b/a = (s_hi / s_lo)^2 < KAPPA for every parameter value: the metric bounds a = s_lo^2,
b = s_hi^2 of the paper's Eq. (18) (``lfd.learners.contraction``). Each layer also bounds its
curvature |D J_k| (Eq. (F5)) for Eq. (C6). Derivations of Eqs. (F1)-(F5): docs/equations.md.

References
----------
Behrmann, Grathwohl, Chen, Duvenaud, Jacobsen (2019). Invertible residual networks. ICML. arXiv:1811.00995
Rana, M. A., Li, A., Fox, D., Boots, B., Ramos, F., Ratliff, N. (2020). Euclideanizing flows:
diffeomorphic reduction for learning stable dynamical systems. L4DC, PMLR 120. arXiv:2005.13143
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import torch
from torch import nn

_E_HALF = math.exp(-0.5)
TANH2_MAX = 4.0 / (3.0 * math.sqrt(3.0))   # max |tanh''|
_EPS = 1e-24                               # inside square roots: keeps gradients finite at 0
_REL = 1e-12                               # relative margin on computed norms (float64 round-off)
MAX_BLOCK_LIP = 0.97                       # a residual block's cap: the fixed-point inverse still converges
SWIRL_COMPONENTS = 4
RHO_MIN, RHO_MAX = 0.1, 3.0                # swirl widths (normalised units): bounded curvature, bounded reach
#: from this dimension on the contraction field applies J_phi^-1 layer by layer
#: (``BoundedFlow.forward_with_inverse_jacobian``) instead of forming the dense J_phi (``forward_with_jacobian``)
FACTORED_MIN_DIM = 8


def shear_sigma_max(m: float | np.ndarray) -> float | np.ndarray:
    """sigma_max of I + m v u' (u, v orthonormal): (m + sqrt(m^2 + 4)) / 2."""
    return (m + np.sqrt(m * m + 4.0)) / 2.0


@dataclass(frozen=True)
class LayerBound:
    """Analytic constants of one layer, normalised units.

    kind : "swirl" or "residual"; sigma_lo, sigma_hi : singular-value bounds of its Jacobian;
    center : its centre (the window's centre is the origin); drift : sup |y - x|;
    params : what ``curvature`` needs.
    """

    kind: str
    sigma_lo: float
    sigma_hi: float
    center: np.ndarray
    drift: float
    params: dict[str, np.ndarray] = field(default_factory=dict)

    def curvature(self, r_lo: np.ndarray, r_hi: np.ndarray) -> np.ndarray:
        """An upper bound of |D J_k| at distance r in [r_lo, r_hi] from the centre, shape (n,).

        Every bound is e(r) * poly(r) with e decreasing and poly increasing (non-negative
        coefficients), so e(r_lo) poly(r_hi) bounds the whole interval.
        """
        r_lo, r_hi = np.maximum(r_lo, 0.0), np.maximum(r_hi, 0.0)
        p = self.params
        if self.kind == "residual":
            big_r2 = float(p["window"]) ** 2
            h0, h1, h2 = float(p["h0"]), float(p["h1"]), float(p["h2"])
            env = np.exp(-0.5 * r_lo ** 2 / big_r2)
            return env * (h2 + 2 * h1 * r_hi / big_r2 + (h0 + h1 * r_hi) * (1 / big_r2 + r_hi ** 2 / big_r2 ** 2))
        theta, rho = np.abs(p["theta"]), p["rho"]                     # (J,)
        q_sup = float((theta / rho ** 2).sum())                         # sup |theta'(r) / r|
        env = np.exp(-0.5 * r_lo[:, None] ** 2 / rho ** 2)              # (n, J)
        rh = r_hi[:, None]
        # |DJ| <= |theta'| (1 + |q| r^2) + |q'| r^2 + 2 |q| r, q = theta'/r (Eq. (F1) differentiated)
        poly = (rh / rho ** 2) * (1 + q_sup * rh ** 2) + rh ** 3 / rho ** 4 + 2 * rh / rho ** 2
        return (theta * env * poly).sum(1)


class BoundedFlow(nn.Module):
    """phi of Eqs. (F1)-(F4): ``layers`` pairs (swirl, residual block), budget log sqrt(KAPPA).

    dim : d >= 2; hidden : H of a block; window : R; max_condition : KAPPA (inf allowed:
    each layer then gets its own cap, MAX_BLOCK_LIP for blocks and slope 20 for swirls).
    A swirl turns the plane of J90 (d = 2), about a learned axis (d = 3), or in a learned 2-plane
    span(a, b) with generator K = b a^T - a b^T (d >= 4; a, b orthonormalised from two learned
    vectors); every K has |K z| <= |z| and K z orthogonal to z, which is all Eq. (F2) uses.
    A fresh flow is the identity (Theta = 0, W2 = 0). Draws from torch's global generator.
    """

    def __init__(self, dim: int, layers: int, hidden: int, window: float, max_condition: float,
                 length_scale: float = 0.5) -> None:
        super().__init__()
        if dim < 2:
            raise ValueError(f"the flow needs d >= 2, got {dim}")
        self.dim, self.n_pairs, self.hidden = dim, layers, hidden
        self.window = float(window)
        self.log_budget = 0.5 * math.log(max_condition) if math.isfinite(max_condition) else math.inf
        # swirls
        self.center = nn.Parameter(0.6 * (torch.rand(layers, dim) - 0.5))
        self.theta = nn.Parameter(torch.zeros(layers, SWIRL_COMPONENTS))
        init = (torch.tensor([0.2, 0.4, 0.8, 1.6]) - RHO_MIN) / (RHO_MAX - RHO_MIN)
        self.rho_logit = nn.Parameter(torch.logit(init).repeat(layers, 1))
        self.axis = nn.Parameter(torch.randn(layers, 3)) if dim == 3 else None
        self.plane = nn.Parameter(torch.randn(layers, 2, dim)) if dim >= 4 else None
        # residual blocks
        self.w1 = nn.Parameter(torch.randn(layers, hidden, dim) / length_scale)
        self.b1 = nn.Parameter(4.0 * torch.rand(layers, hidden) - 2.0)
        self.w2 = nn.Parameter(torch.zeros(layers, dim, hidden))
        # the learned split of the budget over the 2L layers
        self.split = nn.Parameter(torch.zeros(2 * layers))

    # ---- the budget and the scaled parameters
    def caps(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(swirl slope caps m_k (L,), block Lipschitz caps c_k (L,)) from the budget split."""
        if math.isinf(self.log_budget):
            l = self.n_pairs
            return self.split.new_full((l,), 20.0), self.split.new_full((l,), MAX_BLOCK_LIP)
        beta = torch.softmax(self.split, 0) * self.log_budget
        return 2 * torch.sinh(beta[0::2] / 2), torch.tanh(beta[1::2] / 2).clamp_max(MAX_BLOCK_LIP)

    def scaled(self) -> dict[str, torch.Tensor]:
        """The effective parameters and per-layer bounds of Eqs. (F2)-(F4).

        Returns a dict of tensors: ``theta`` (L, J), ``rho`` (L, J), ``m`` (L,), ``w2`` (L, d, H),
        ``c``, ``h0``, ``h1``, ``h2`` (L,), and ``axis`` (L, 3) for d = 3 or ``gen`` (L, d, d) for d >= 4.
        While no gradient is needed (``torch.no_grad``, or no parameter requires one) the result is
        cached, keyed by every parameter's storage, version counter, dtype, device and shape: an
        optimiser step, ``load_state_dict``, any in-place write through the parameter or a dtype
        conversion invalidates it. (A write through ``param.data`` bypasses the version counter: call
        ``clear_cache`` after one.) With gradients needed it is recomputed on every call.
        """
        params = list(self.parameters())
        if (torch.is_grad_enabled() and any(p.requires_grad for p in params)) \
                or torch.is_inference_mode_enabled():
            return self._scaled()
        key = tuple((p.data_ptr(), p._version, p.dtype, p.device, tuple(p.shape)) for p in params)
        cache = self.__dict__.get("_scaled_cache")
        if cache is not None and cache[0] == key:
            return dict(cache[2])
        out = self._scaled()
        # the detached references keep the storages alive, so no other tensor can reuse their addresses
        self.__dict__["_scaled_cache"] = (key, [p.detach() for p in params], out)
        return dict(out)

    def clear_cache(self) -> None:
        """Forget the cached ``scaled`` parameters."""
        self.__dict__.pop("_scaled_cache", None)

    def __getstate__(self) -> dict[str, Any]:
        """The module's state without the cache of ``scaled``."""
        state = dict(super().__getstate__())
        state.pop("_scaled_cache", None)
        return state

    def _scaled(self) -> dict[str, torch.Tensor]:
        """``scaled`` computed now (never cached)."""
        m_cap, c_cap = self.caps()
        # swirls: raw slope S = (2/e) sum |Theta_j| (smooth |.|), scaled below its cap
        abs_theta = torch.sqrt(self.theta ** 2 + _EPS)
        s = (2 / math.e) * abs_theta.sum(1) * (1 + _REL)
        m = m_cap * torch.tanh(s / m_cap)
        theta = self.theta * (m / s)[:, None]
        # blocks: raw Lipschitz B of Eq. (F3), scaled below its cap
        w1, w2 = self.w1, self.w2
        n1 = torch.sqrt(torch.linalg.eigvalsh(w1.transpose(1, 2) @ w1)[:, -1].clamp_min(0) + _EPS) * (1 + _REL)
        n2 = torch.sqrt(torch.linalg.eigvalsh(w2 @ w2.transpose(1, 2))[:, -1].clamp_min(0) + _EPS) * (1 + _REL)
        col = torch.sqrt((w2 * w2).sum(1) + _EPS) * torch.sqrt((w1 * w1).sum(2) + _EPS)
        h1 = torch.minimum(n1 * n2, col.sum(1) * (1 + _REL))
        h0 = torch.sqrt(((w2 @ torch.tanh(self.b1).unsqueeze(-1)).squeeze(-1) ** 2).sum(-1) + _EPS) * (1 + _REL)
        big_b = 2 * _E_HALF * h1 + _E_HALF * h0 / self.window
        c = c_cap * torch.tanh(big_b / c_cap)
        alpha = c / big_b
        out = {"theta": theta, "rho": RHO_MIN + (RHO_MAX - RHO_MIN) * torch.sigmoid(self.rho_logit), "m": m,
               "w2": w2 * alpha[:, None, None], "c": c, "h0": alpha * h0, "h1": alpha * h1,
               "h2": TANH2_MAX * alpha * n2 * n1 * n1}
        if self.axis is not None:
            out["axis"] = self.axis / torch.sqrt((self.axis ** 2).sum(1, keepdim=True) + _EPS)
        if self.plane is not None:
            out["gen"] = plane_generators(self.plane)
        return out

    def bounds(self) -> list[LayerBound]:
        """Every layer's ``LayerBound``, in the order they act."""
        with torch.no_grad():
            p = {k: v.detach().double().numpy() for k, v in self.scaled().items()}
            center = self.center.detach().double().numpy()
        out = []
        for k in range(self.n_pairs):
            sm = float(shear_sigma_max(p["m"][k]))
            out.append(LayerBound("swirl", 1.0 / sm, sm, center[k],
                                  float((np.abs(p["theta"][k]) * p["rho"][k]).sum() * _E_HALF),
                                  {"theta": p["theta"][k], "rho": p["rho"][k]}))
            c = float(p["c"][k])
            out.append(LayerBound("residual", 1.0 - c, 1.0 + c, np.zeros(self.dim),
                                  float(p["h0"][k] + p["h1"][k] * self.window * _E_HALF),
                                  {"window": cast(np.ndarray, np.float64(self.window)), "h0": p["h0"][k],
                                   "h1": p["h1"][k], "h2": p["h2"][k]}))
        return out

    def singular_value_bounds(self) -> tuple[float, float]:
        """(s_lo, s_hi) of Eq. (F4)."""
        b = self.bounds()
        return float(np.prod([l.sigma_lo for l in b])), float(np.prod([l.sigma_hi for l in b]))

    # ---- the maps
    def _rotation(self, p: dict[str, torch.Tensor], k: int, ang: torch.Tensor) -> torch.Tensor:
        """R(ang), shape (B, d, d), for angles ang (B,)."""
        cs, sn = torch.cos(ang), torch.sin(ang)
        if self.dim == 2:
            return torch.stack([torch.stack([cs, -sn], -1), torch.stack([sn, cs], -1)], -2)
        if self.dim == 3:
            a = p["axis"][k]
            kk = torch.stack([torch.stack([a.new_zeros(()), -a[2], a[1]]),
                              torch.stack([a[2], a.new_zeros(()), -a[0]]),
                              torch.stack([-a[1], a[0], a.new_zeros(())])])
        else:
            kk = p["gen"][k]
        eye = torch.eye(self.dim, dtype=kk.dtype)
        return eye + sn[:, None, None] * kk + (1 - cs)[:, None, None] * (kk @ kk)

    def _generator(self, p: dict[str, torch.Tensor], k: int, z: torch.Tensor) -> torch.Tensor:
        """K z: J90 z (d = 2), a x z (d = 3) or the plane generator's K z (d >= 4), shape (B, d)."""
        if self.dim == 2:
            return torch.stack([-z[:, 1], z[:, 0]], -1)
        if self.dim == 3:
            return torch.cross(p["axis"][k].expand_as(z), z, dim=-1)
        return z @ p["gen"][k].T

    def _angle(self, p: dict[str, torch.Tensor], k: int, r2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """theta(r) and q(r) = theta'(r) / r for squared radii r2 (B,)."""
        rho2 = p["rho"][k] ** 2
        e = torch.exp(-0.5 * r2[:, None] / rho2)                       # (B, J)
        th = p["theta"][k]
        return (th * e).sum(1), -(th / rho2 * e).sum(1)

    def forward_with_jacobian(self, x: torch.Tensor, jacobian: bool = True,
                              params: dict[str, torch.Tensor] | None = None
                              ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """y = phi(x), shape (B, d), and J_phi(x), shape (B, d, d) (None unless ``jacobian``).

        ``params`` : the effective parameters of ``scaled`` when the caller holds them already (a
        fitted field keeps them, so that its forward pass needs no eigen-decomposition and exports
        to ONNX); by default ``scaled()``.
        """
        p = self.scaled() if params is None else params
        eye = torch.eye(self.dim, dtype=x.dtype)
        jac = eye.expand(x.shape[0], -1, -1) if jacobian else None
        for k in range(self.n_pairs):
            z = x - self.center[k]
            ang, q = self._angle(p, k, (z * z).sum(1))
            rot = self._rotation(p, k, ang)
            y = self.center[k] + (rot @ z.unsqueeze(-1)).squeeze(-1)
            if jac is not None:
                kz = self._generator(p, k, z)                          # K z
                jk = rot @ (eye + q[:, None, None] * kz[:, :, None] * z[:, None, :])
                jac = jk @ jac
            x = y
            env = torch.exp(-0.5 * (x * x).sum(1) / self.window ** 2)
            th = torch.tanh(torch.addmm(self.b1[k], x, self.w1[k].T))
            h = th @ p["w2"][k].T
            if jac is not None:
                jh = (p["w2"][k] * (1 - th * th)[:, None, :]) @ self.w1[k]
                jg = env[:, None, None] * (jh - h[:, :, None] * x[:, None, :] / self.window ** 2)
                jac = (eye + jg) @ jac
            x = x + env[:, None] * h
        return x, jac

    def forward_with_tangent(self, x: torch.Tensor, v: torch.Tensor,
                             params: dict[str, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """y = phi(x) and the Jacobian-vector product J_phi(x) v, both shape (B, d), in forward mode:
        layer by layer, without forming J_phi (nor the (B, d, H) products of ``forward_with_jacobian``):

        - swirl, Eq. (F1): J u = R (u + q Kz (z'u)), R w = w + sin(ang) K w + (1 - cos(ang)) K (K w)
          (d = 2: R w = cos(ang) w + sin(ang) K w);
        - residual block, Eq. (F3): J u = u + e(x) (W2 ((1 - th^2) * W1 u) - h (x'u) / R^2).

        x, v : tensors, shape (B, d); ``params`` as in ``forward_with_jacobian``. Written for few
        tensor operations (the fit of a Lyapunov function calls it once per optimiser step).
        """
        p = self.scaled() if params is None else params
        inv_r2 = 1.0 / self.window ** 2
        half_inv_rho2 = 0.5 / p["rho"] ** 2                                   # (L, J)
        layers = zip(self.center.unbind(0), p["theta"].unbind(0), half_inv_rho2.unbind(0),
                     (p["theta"] * half_inv_rho2).unbind(0), self.w1.unbind(0), self.b1.unbind(0),
                     p["w2"].unbind(0))
        for k, (c, theta, inv, theta_inv, w1, b1, w2) in enumerate(layers):
            z = x - c
            e = torch.exp(-(z * z).sum(1, keepdim=True) * inv)                # (B, J)
            ang, q = e @ theta, -2.0 * (e @ theta_inv)                        # theta(r), theta'(r) / r
            cs, sn = torch.cos(ang)[:, None], torch.sin(ang)[:, None]
            kz = self._generator(p, k, z)
            u = torch.addcmul(v, (q * (z * v).sum(1))[:, None], kz)
            ku = self._generator(p, k, u)
            if self.dim == 2:                                                 # K^2 = -I
                x = c + cs * z + sn * kz
                v = cs * u + sn * ku
            else:
                x = c + z + sn * kz + (1 - cs) * self._generator(p, k, kz)
                v = u + sn * ku + (1 - cs) * self._generator(p, k, ku)
            th = torch.tanh(torch.addmm(b1, x, w1.T))
            env = torch.exp(-0.5 * inv_r2 * (x * x).sum(1, keepdim=True))
            dh = ((1 - th * th) * (v @ w1.T) - th * ((x * v).sum(1, keepdim=True) * inv_r2)) @ w2.T
            x = torch.addcmul(x, env, th @ w2.T)
            v = torch.addcmul(v, env, dh)
        return x, v

    def forward_with_inverse_jacobian(self, x: torch.Tensor
                                      ) -> tuple[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]]:
        """y = phi(x), shape (B, d), and v -> J_phi(x)^-1 v for v of shape (B, d), without forming J_phi.

        The same values as ``forward_with_jacobian`` followed by a solve with J_phi (to rounding), for
        d >= 4 (a swirl turns a 2-plane), without the O(B d^3) products of the dense chain: O(B (H^3 + d H))
        work per block once 2 d > H + 1, linear in d for a fixed hidden width H. J_phi = J_2L ... J_1
        (Eq. (F4)), so J_phi^-1 v applies the layers' inverses in reverse order:

        - swirl, Eq. (F1): J = R (I + q Kz z'), and z' K z = 0 (K skew), so
          J^-1 = (I - q Kz z') R', with R' u = u - sin(ang) K u + (1 - cos(ang)) K^2 u by Rodrigues and
          K u = b (a'u) - a (b'u), K^2 u = -a (a'u) - b (b'u) for the plane's orthonormal a, b: O(d);
        - residual block, Eq. (F3): J = I + U V', U = e(x) [W2 diag(1 - tanh^2), -h / R^2] (d, H + 1),
          V = [W1', x] (d, H + 1), so by Woodbury J^-1 v = v - U (I + V'U)^-1 V'v: an (H + 1) x (H + 1)
          solve per point, whose matrix I + V'U is built from the shared H x H product W1 W2 (its
          determinant is det J, which the singular-value bound 1 - c > 0 of Eq. (F3) keeps from zero);
          while 2 d <= H + 1, the block's own d x d Jacobian is solved instead (the smaller work).

        Parameters
        ----------
        x : tensor, shape (B, d)
            Points, d >= 4.

        Returns
        -------
        y : tensor, shape (B, d)
            phi(x).
        solve : callable
            v (B, d) -> J_phi(x)^-1 v (B, d), differentiable in v and in the parameters.
        """
        if self.dim < 4:
            raise ValueError(f"forward_with_inverse_jacobian needs d >= 4, got {self.dim}")
        p = self.scaled()
        a_vec, b_vec = plane_basis(cast(torch.Tensor, self.plane))           # (L, d) each
        inv_r2 = 1.0 / self.window ** 2
        steps: list[Callable[[torch.Tensor], torch.Tensor]] = []
        for k in range(self.n_pairs):
            z = x - self.center[k]
            ang, q = self._angle(p, k, (z * z).sum(1))
            cs, sn = torch.cos(ang)[:, None], torch.sin(ang)[:, None]
            a, b = a_vec[k], b_vec[k]
            za, zb = z @ a, z @ b                                            # (B,)
            kz = b * za[:, None] - a * zb[:, None]                           # K z
            k2z = -(a * za[:, None] + b * zb[:, None])                       # K^2 z
            x = self.center[k] + z + sn * kz + (1 - cs) * k2z                # c + R z, Eq. (F1)
            steps.append(_swirl_inverse(a, b, cs, sn, q, z, kz))
            env = torch.exp(-0.5 * (x * x).sum(1) * inv_r2)                  # (B,)
            th = torch.tanh(torch.addmm(self.b1[k], x, self.w1[k].T))        # (B, H)
            w2 = p["w2"][k]                                                  # (d, H)
            h = th @ w2.T                                                    # (B, d)
            steps.append(_block_inverse(self.w1[k], w2, x, env, th, h, inv_r2))
            x = x + env[:, None] * h                                         # Eq. (F3)

        def solve(v: torch.Tensor) -> torch.Tensor:
            for step in reversed(steps):
                v = step(v)
            return v

        return x, solve

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """y = phi(x); x : tensor, shape (B, d)."""
        return self.forward_with_jacobian(x, jacobian=False)[0]

    @torch.no_grad()
    def inverse(self, y: torch.Tensor, tol: float = 1e-14, max_iter: int = 2000) -> torch.Tensor:
        """x = phi^-1(y): blocks by fixed-point iteration (ratio c_k < 1), swirls in closed form."""
        p = self.scaled()
        for k in reversed(range(self.n_pairs)):
            x = y.clone()
            for _ in range(max_iter):
                env = torch.exp(-0.5 * (x * x).sum(1) / self.window ** 2)
                h = torch.tanh(torch.addmm(self.b1[k], x, self.w1[k].T)) @ p["w2"][k].T
                x_new = y - env[:, None] * h
                done = float((x_new - x).abs().max()) <= tol * (1.0 + float(y.abs().max()))
                x = x_new
                if done:
                    break
            z = x - self.center[k]
            ang, _ = self._angle(p, k, (z * z).sum(1))
            y = self.center[k] + (self._rotation(p, k, -ang) @ z.unsqueeze(-1)).squeeze(-1)
        return y

    def numpy_params(self) -> list[dict[str, np.ndarray | float]]:
        """Per (swirl, block) pair, the effective parameters as float64 arrays, for the compiled kernels
        (``lfd.learners.flow_kernel.pack_flow``): ``c`` (d,), ``theta`` and ``inv_2rho2`` (J,), ``w1b``
        (H, d + 1) (W1 and b1), ``w2`` (d, H), ``inv_r2`` (1 / R^2) and, for d >= 3, the generator
        ``K`` (d, d)."""
        with torch.no_grad():
            p = {k: v.detach().double().numpy() for k, v in self.scaled().items()}
            w1, b1 = self.w1.double().numpy(), self.b1.double().numpy()
            center = self.center.double().numpy()
        out = []
        d = self.dim
        for k in range(self.n_pairs):
            item: dict[str, np.ndarray | float] = {
                "c": center[k].copy(), "theta": p["theta"][k].copy(), "inv_2rho2": 0.5 / p["rho"][k] ** 2,
                "w1b": np.ascontiguousarray(np.hstack([w1[k], b1[k][:, None]])),
                "w2": np.ascontiguousarray(p["w2"][k]), "inv_r2": 1.0 / self.window ** 2}
            if d == 3:
                a = p["axis"][k]
                item["K"] = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            elif d >= 4:
                item["K"] = np.ascontiguousarray(p["gen"][k])
            out.append(item)
        return out


def plane_basis(plane: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The orthonormal pair (a, b), shapes (L, d) each, of the swirls' planes, plane of shape (L, 2, d):
    a = u / |u|, b = the unit part of v orthogonal to a (Gram-Schmidt)."""
    u, v = plane[:, 0], plane[:, 1]
    a = u / torch.sqrt((u * u).sum(1, keepdim=True) + _EPS)
    w = v - (v * a).sum(1, keepdim=True) * a
    b = w / torch.sqrt((w * w).sum(1, keepdim=True) + _EPS)
    return a, b


def plane_generators(plane: torch.Tensor) -> torch.Tensor:
    """K_k = b a^T - a b^T, shape (L, d, d), from two vectors per layer, plane of shape (L, 2, d)
    (``plane_basis``). K_k^3 = -K_k, so exp(ang K) = I + sin(ang) K + (1 - cos(ang)) K^2 (Rodrigues),
    a rotation in span(a, b)."""
    a, b = plane_basis(plane)
    return b[:, :, None] * a[:, None, :] - a[:, :, None] * b[:, None, :]


def _swirl_inverse(a: torch.Tensor, b: torch.Tensor, cs: torch.Tensor, sn: torch.Tensor, q: torch.Tensor,
                   z: torch.Tensor, kz: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
    """v -> J^-1 v, shapes (B, d), for a swirl's J = R (I + q Kz z') (Eq. (F1), d >= 4):
    (I - q Kz z') R' v, O(d) per point (``BoundedFlow.forward_with_inverse_jacobian``).

    a, b : (d,), the plane's orthonormal pair; cs, sn : (B, 1), cos and sin of the angle;
    q : (B,), theta'(r) / r; z : (B, d), the point relative to the centre; kz : (B, d), K z.
    """
    def inverse(v: torch.Tensor) -> torch.Tensor:
        va, vb = (v @ a)[:, None], (v @ b)[:, None]
        u = v - sn * (b * va - a * vb) - (1 - cs) * (a * va + b * vb)      # R' v = exp(-ang K) v
        return u - (q * (z * u).sum(1))[:, None] * kz

    return inverse


def _block_inverse(w1: torch.Tensor, w2: torch.Tensor, x: torch.Tensor, env: torch.Tensor, th: torch.Tensor,
                   h: torch.Tensor, inv_r2: float) -> Callable[[torch.Tensor], torch.Tensor]:
    """v -> J^-1 v, shapes (B, d), for a residual block's J = I + e(x) (W2 diag(1 - th^2) W1 - h x' / R^2)
    (Eq. (F3)): while 2 d <= H + 1 by a d x d solve with J, else by Woodbury: J = I + U V' with
    U = e [W2 diag(1 - th^2), -h / R^2], V = [W1', x], so J^-1 v = v - U (I + V'U)^-1 V'v, an
    (H + 1) x (H + 1) solve per point.

    w1 : (H, d); w2 : (d, H), scaled; x : (B, d), the block's input; env : (B,), e(x);
    th : (B, H), tanh(W1 x + b1); h : (B, d), W2 th; inv_r2 : 1 / R^2.
    """
    n_hidden = th.shape[1]
    ds = 1 - th * th                                                       # (B, H)
    if 2 * x.shape[1] <= n_hidden + 1:
        # 2 d <= H + 1: the block's own d x d Jacobian (one d x H x d product per point) costs less
        # than the (H + 1) x (H + 1) system
        jg = (w2 * ds[:, None, :]) @ w1 - h[:, :, None] * (x[:, None, :] * inv_r2)             # (B, d, d)
        jac = torch.eye(x.shape[1], dtype=x.dtype, device=x.device) + env[:, None, None] * jg

        def dense_inverse(v: torch.Tensor) -> torch.Tensor:
            return torch.linalg.solve(jac, v)

        return dense_inverse
    g = w1 @ w2                                                            # W1 W2, (H, H)
    top = torch.cat([g * ds[:, None, :], -(th @ g.T)[:, :, None] * inv_r2], 2)          # W1 U / e, (B, H, H + 1)
    bottom = torch.cat([(x @ w2) * ds, -(x * h).sum(1, keepdim=True) * inv_r2], 1)      # x'U / e, (B, H + 1)
    cap = env[:, None, None] * torch.cat([top, bottom[:, None, :]], 1)                  # V'U, (B, H + 1, H + 1)
    cap = cap + torch.eye(n_hidden + 1, dtype=x.dtype, device=x.device)

    def inverse(v: torch.Tensor) -> torch.Tensor:
        vt_v = torch.cat([v @ w1.T, (x * v).sum(1, keepdim=True)], 1)     # V'v, (B, H + 1)
        u = torch.linalg.solve(cap, vt_v)
        return v - env[:, None] * ((ds * u[:, :n_hidden]) @ w2.T - h * (u[:, n_hidden:] * inv_r2))

    return inverse

