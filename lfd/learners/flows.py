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
curvature |D J_k| (Eq. (F5), ``LayerBound.curvature``) for the field's Lipschitz bound, Eq. (C6).
The derivations of Eqs. (F1)-(F5): docs/equations.md.

References
----------
Behrmann, Grathwohl, Chen, Duvenaud, Jacobsen (2019). Invertible residual networks. ICML. arXiv:1811.00995
Rana, M. A., Li, A., Fox, D., Boots, B., Ramos, F., Ratliff, N. (2020). Euclideanizing flows:
diffeomorphic reduction for learning stable dynamical systems. L4DC, PMLR 120. arXiv:2005.13143
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import cast

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
        """The effective parameters and per-layer bounds of Eqs. (F2)-(F4)."""
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

    def forward_with_jacobian(self, x: torch.Tensor, jacobian: bool = True
                              ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """y = phi(x), shape (B, d), and J_phi(x), shape (B, d, d) (None unless ``jacobian``)."""
        p = self.scaled()
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
        """Per pair, float64 arrays for ``bounded_flow_numpy``."""
        with torch.no_grad():
            p = {k: v.detach().double().numpy() for k, v in self.scaled().items()}
            w1, b1 = self.w1.double().numpy(), self.b1.double().numpy()
            center = self.center.double().numpy()
        out = []
        d = self.dim
        for k in range(self.n_pairs):
            m = (p["w2"][k][:, None, :] * w1[k].T[None, :, :]).reshape(d * d, -1)
            item: dict[str, np.ndarray | float] = {
                "c": center[k].copy(), "theta": p["theta"][k].copy(), "inv_2rho2": 0.5 / p["rho"][k] ** 2,
                "w1b": np.ascontiguousarray(np.hstack([w1[k], b1[k][:, None]])),
                "w2": np.ascontiguousarray(p["w2"][k]), "m": np.ascontiguousarray(m),
                "inv_r2": 1.0 / self.window ** 2}
            if d == 3:
                a = p["axis"][k]
                item["K"] = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            elif d >= 4:
                item["K"] = np.ascontiguousarray(p["gen"][k])
            out.append(item)
        return out


def plane_generators(plane: torch.Tensor) -> torch.Tensor:
    """K_k = b a^T - a b^T, shape (L, d, d), from two vectors per layer, plane of shape (L, 2, d):
    a = u / |u|, b = the unit part of v orthogonal to a (Gram-Schmidt). K_k^3 = -K_k, so
    exp(ang K) = I + sin(ang) K + (1 - cos(ang)) K^2 (Rodrigues), a rotation in span(a, b)."""
    u, v = plane[:, 0], plane[:, 1]
    a = u / torch.sqrt((u * u).sum(1, keepdim=True) + _EPS)
    w = v - (v * a).sum(1, keepdim=True) * a
    b = w / torch.sqrt((w * w).sum(1, keepdim=True) + _EPS)
    return b[:, :, None] * a[:, None, :] - a[:, :, None] * b[:, None, :]


def bounded_flow_numpy(params: list[dict[str, np.ndarray | float]], x: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """phi(x) and J_phi(x) for ONE point, as ``BoundedFlow.forward_with_jacobian`` in float64.

    params : ``BoundedFlow.numpy_params()``; x : array, shape (d,). Returns y (d,) and J (d, d).
    """
    d = x.shape[0]
    y = np.array(x, dtype=np.float64)
    jac = np.eye(d)
    arg = np.ones(d + 1)
    eye = np.eye(d)
    for p in params:
        z = y - p["c"]
        r2 = float(z @ z)
        e = np.exp(-r2 * p["inv_2rho2"])
        te = p["theta"] * e
        ang = float(te.sum())
        q = -2.0 * float((te * p["inv_2rho2"]).sum())
        cs, sn = math.cos(ang), math.sin(ang)
        if d == 2:
            rot = np.array([[cs, -sn], [sn, cs]])
            kz = np.array([-z[1], z[0]])
        else:
            kk = cast(np.ndarray, p["K"])
            rot = eye + sn * kk + (1 - cs) * (kk @ kk)
            kz = kk @ z
        jac = (rot @ (eye + q * np.outer(kz, z))) @ jac
        y = p["c"] + rot @ z
        arg[:d] = y
        th = np.tanh(p["w1b"] @ arg)
        env = math.exp(-0.5 * p["inv_r2"] * float(y @ y))
        h = p["w2"] @ th
        jg = (p["m"] @ (1.0 - th * th)).reshape(d, d) - np.outer(h, y * p["inv_r2"])
        jac = (eye + env * jg) @ jac
        y = y + env * h
    return y, jac
