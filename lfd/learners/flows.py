"""A smooth diffeomorphism phi : R^d -> R^d built from affine coupling layers (RealNVP style).

Layer k transforms one coordinate u = k mod d conditioned on the others, c:

    Eq. (F1): y_u = x_u exp(s_k(x_c)) + t_k(x_c),   y_c = x_c,
    Eq. (F2): s_k = beta tanh(r_k / beta)            (bounded log-scale, |s_k| < beta),
    Eq. (F3): (r_k, t_k) = e(x_c) W_k [cos(Omega_k x_c); sin(Omega_k x_c)] / sqrt(H) + b_k,
              e(x_c) = exp(-|x_c|^2 / (2 R^2))   (R = ``window``; e = 1 without one),

a linear read-out of H random Fourier features with fixed frequencies Omega_k ~ N(0, 1/l^2),
shape (H, d-1), as in Euclideanizing flows (Rana et al., 2020), under a Gaussian window: far
from the data (|x_c| >> R) each layer tends to a fixed affine map, so phi does not keep folding
space where there is nothing to fit (without the window the periodic features make J_phi grow
without bound, and the field stiff, away from the data). W_k starts at zero, so a fresh flow is
the identity. Each layer is a bijection of R^d with the inverse

    Eq. (F4): x_u = (y_u - t_k(y_c)) exp(-s_k(y_c)),

and a Jacobian that differs from the identity in row u only,

    Eq. (F5): dy_u/dx = exp(s_k) e_u' + (x_u exp(s_k) ds_k/dx_c + dt_k/dx_c) E_c,

so J_phi = J_K ... J_1 is invertible everywhere (det J_phi = exp(sum_k s_k) > 0), and J_phi and
its inverse are bounded on every bounded set. The feature derivatives are analytic,
d/dx_c [cos z; sin z] = [-sin z; cos z] Omega_k and de/dx_c = -e x_c / R^2, so (r, t) and their
derivatives come out of one matrix product. The flow carries J_phi forward (no autograd needed), so the same code serves
training, the certificate (where torch.func differentiates it once more) and, in numpy, the
single-point control-loop path. The K layers' weights are stacked in one tensor so that the
per-step work that does not depend on x is a handful of tensor operations, not K of them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import nn

# The conditioning coordinates c = {0..d-1} \ {u} as a slice (a view, no copy), for d in {2, 3}.
_COND_SLICES: dict[tuple[int, int], slice] = {
    (2, 0): slice(1, 2), (2, 1): slice(0, 1),
    (3, 0): slice(1, 3), (3, 1): slice(0, 3, 2), (3, 2): slice(0, 2),
}


class CouplingFlow(nn.Module):
    """phi = layer_K o ... o layer_1, a diffeomorphism of R^d (Eqs. (F1)-(F5)).

    dim : d in {2, 3}; layers : K; features : H; length_scale : l and window : R of Eq. (F3)
    (0: no window); log_scale_bound : beta of Eq. (F2). The frequencies are drawn from torch's global
    generator (seed it first) and saved with the weights.
    """

    def __init__(self, dim: int, layers: int, features: int, length_scale: float,
                 log_scale_bound: float, window: float = 0.0) -> None:
        super().__init__()
        if dim not in (2, 3):
            raise ValueError(f"the coupling flow supports d = 2 or 3, got {dim}")
        self.dim, self.n_layers, self.features = dim, layers, features
        self.beta = float(log_scale_bound)
        self.window = float(window)
        self.feature_scale = float(1.0 / np.sqrt(features))
        self.register_buffer("omega", torch.randn(layers, features, dim - 1) / length_scale)
        self.weight = nn.Parameter(torch.zeros(layers, 2, 2 * features))
        self.bias = nn.Parameter(torch.zeros(layers, 2))
        self.register_buffer("masks", torch.eye(dim, dtype=torch.bool)[[k % dim for k in range(layers)]],
                             persistent=False)

    def _u_c(self, k: int) -> tuple[int, slice]:
        u = k % self.dim
        return u, _COND_SLICES[(self.dim, u)]

    def readout(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Every layer's stacked read-out [W; dW/dx_c], shape (K, 2 + 2(d-1), 2H), and bias, (K, 2 + 2(d-1)).

        Rows per layer: r, t, dr/dx_c (d-1 rows), dt/dx_c (d-1 rows), from Eq. (F3) and
        d/dx_c (W [cos z; sin z]) = [W_sin, -W_cos] [cos z; sin z] Omega.
        """
        k, h = self.n_layers, self.features
        w = self.weight * self.feature_scale                              # (K, 2, 2H)
        wc, ws = w[:, :, None, :h], w[:, :, None, h:]                     # (K, 2, 1, H)
        om = self.omega.transpose(1, 2)[:, None]                          # (K, 1, d-1, H)
        wd = torch.cat([ws * om, -wc * om], dim=-1).reshape(k, -1, 2 * h)  # (K, 2 (d-1), 2H)
        zero = self.bias.new_zeros(k, wd.shape[1])
        return torch.cat([w, wd], dim=1), torch.cat([self.bias, zero], dim=1)

    def _features(self, k: int, xc: torch.Tensor) -> torch.Tensor:
        z = xc @ self.omega[k].T                                          # (B, H)
        return torch.cat([torch.cos(z), torch.sin(z)], dim=1)            # (B, 2H)

    def _conditioner(self, k: int, xc: torch.Tensor, w: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(r, t[, dr/dx_c, dt/dx_c]) of layer k: (B, 2) or (B, 2 + 2(d-1)), windowed if ``window``."""
        if self.window <= 0:
            return torch.addmm(b[k][:w.shape[1]], self._features(k, xc), w[k].T)
        raw = self._features(k, xc) @ w[k].T
        env = torch.exp(-0.5 * (xc * xc).sum(1, keepdim=True) / self.window ** 2)    # (B, 1)
        out = env * raw[:, :2] + b[k][:2]
        if raw.shape[1] == 2:
            return out
        n = self.dim - 1
        g = xc / self.window ** 2                                                 # (B, d-1), -de/dx_c / e
        d_rt = raw[:, 2:].view(-1, 2, n) - raw[:, :2, None] * g[:, None, :]       # (B, 2, d-1)
        return torch.cat([out, (env[:, :, None] * d_rt).reshape(-1, 2 * n)], dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """y = phi(x), Eq. (F1) layer by layer; x : tensor, shape (B, d)."""
        w, b = self.weight * self.feature_scale, self.bias
        for k in range(self.n_layers):
            u, c = self._u_c(k)
            out = self._conditioner(k, x[:, c], w, b)                    # (B, 2)
            es = torch.exp(self.beta * torch.tanh(out[:, 0] / self.beta))
            x = torch.where(self.masks[k], (x[:, u] * es + out[:, 1]).unsqueeze(-1), x)
        return x

    def forward_with_jacobian(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """y = phi(x), shape (B, d), and J_phi(x) = dphi/dx, shape (B, d, d): Eqs. (F1), (F5)."""
        n = self.dim - 1
        w, b = self.readout()
        jac = torch.eye(self.dim, dtype=x.dtype).expand(x.shape[0], -1, -1)
        for k in range(self.n_layers):
            u, c = self._u_c(k)
            xu = x[:, u]
            out = self._conditioner(k, x[:, c], w, b)                    # (B, 2 + 2(d-1))
            th = torch.tanh(out[:, 0] / self.beta)
            es = torch.exp(self.beta * th)
            shear = (xu * es * (1.0 - th * th)).unsqueeze(-1) * out[:, 2:2 + n] + out[:, 2 + n:]
            row = es.unsqueeze(-1) * jac[:, u] + (shear.unsqueeze(1) @ jac[:, c]).squeeze(1)
            jac = torch.where(self.masks[k][:, None], row.unsqueeze(1), jac)
            x = torch.where(self.masks[k], (xu * es + out[:, 1]).unsqueeze(-1), x)
        return x, jac

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        """x = phi^-1(y), Eq. (F4) layer by layer in reverse; y : tensor, shape (B, d)."""
        w, b = self.weight * self.feature_scale, self.bias
        for k in reversed(range(self.n_layers)):
            u, c = self._u_c(k)
            out = self._conditioner(k, y[:, c], w, b)
            s = self.beta * torch.tanh(out[:, 0] / self.beta)
            y = torch.where(self.masks[k], ((y[:, u] - out[:, 1]) * torch.exp(-s)).unsqueeze(-1), y)
        return y

    def numpy_params(self) -> list[dict[str, Any]]:
        """Each layer as plain float64 data for ``coupling_flow_numpy``: u, c (list), beta,
        ``inv_window2`` (1/R^2, 0 without a window), ``omega_aug`` (2H, d) with
        cos(omega_aug [x_c; 1]) = [cos z; sin z] (the last column holds the phases 0 and -pi/2),
        and the stacked read-out ``w`` (2 + 2(d-1), 2H), ``b`` (list)."""
        with torch.no_grad():
            w, b = self.readout()
        h = self.features
        phase = np.concatenate([np.zeros(h), np.full(h, -np.pi / 2)])[:, None]
        layers = []
        for k in range(self.n_layers):
            u, c = self._u_c(k)
            om = self.omega[k].double().numpy()
            layers.append({"u": u, "c": [int(i) for i in np.arange(self.dim)[c]], "beta": self.beta,
                           "inv_window2": 1.0 / self.window ** 2 if self.window > 0 else 0.0,
                           "omega_aug": np.ascontiguousarray(np.hstack([np.vstack([om, om]), phase])),
                           "w": w[k].double().numpy().copy(), "b": [float(v) for v in b[k]]})
        return layers


def coupling_flow_numpy(params: list[dict[str, Any]], x: np.ndarray | list[float]
                        ) -> tuple[list[float], list[list[float]]]:
    """phi(x) and J_phi(x) for ONE point: Eqs. (F1)-(F3), (F5) as ``CouplingFlow``, in float64.

    The control-loop path: per layer three numpy calls (features, cos, read-out), everything of
    size d in Python floats (numpy calls on d-vectors cost more than their arithmetic).
    params : ``CouplingFlow.numpy_params()``; x : d floats.
    Returns y (d floats) and J (d rows of d floats).
    """
    y = [float(v) for v in x]
    d = len(y)
    n = d - 1
    jac = [[1.0 if i == j else 0.0 for j in range(d)] for i in range(d)]
    arg = np.ones(d)                                   # [x_c; 1]
    for p in params:
        u, c, beta, b, inv_r2 = p["u"], p["c"], p["beta"], p["b"], p["inv_window2"]
        for m, ci in enumerate(c):
            arg[m] = y[ci]
        feats = p["omega_aug"] @ arg
        raw = (p["w"] @ np.cos(feats, out=feats)).tolist()
        env = math.exp(-0.5 * inv_r2 * sum(y[ci] * y[ci] for ci in c)) if inv_r2 else 1.0
        th = math.tanh((env * raw[0] + b[0]) / beta)
        es = math.exp(beta * th)
        ds = y[u] * es * (1.0 - th * th)
        row = [es * v for v in jac[u]]
        for m, ci in enumerate(c):
            g = y[ci] * inv_r2
            shear = env * (ds * (raw[2 + m] - g * raw[0]) + raw[2 + n + m] - g * raw[1])
            jc = jac[ci]
            for j in range(d):
                row[j] += shear * jc[j]
        jac[u] = row
        y[u] = y[u] * es + env * raw[1] + b[1]
    return y, jac
