"""The NODE's training kernels: the MLP field and whole RK4 shooting segments as single autograd nodes.

Training the NODE is bound by per-op overhead: the batches are small (a few hundred points of a
two-layer MLP), and every iteration integrates each segment over S - 1 samples, four field
evaluations per step. Through torchdiffeq and autograd each evaluation costs a dozen graph nodes
forward and as many backward. The two functions here cut that:

- ``ScaledMLP``: one evaluation y = (MLP(x) - c) h as one autograd node with a hand-written backward.
- ``RK4Segments``: the whole fixed-step integration of a batch of segments, torchdiffeq's ``rk4``
  (the 3/8-rule Runge-Kutta step, the same floats up to summation order), forward without a graph,
  and its exact discrete adjoint backward. The weight gradients of every evaluation are summed in
  one matrix product per layer at the end, instead of one small product per evaluation.

Both are checked against autograd through torchdiffeq (values and gradients) in the tests. They
are not twins of ``NodeMLP``'s forward pass: that stays the path of ``odeint_adjoint`` (which
differentiates each evaluation alone) and of batched evaluation; one point goes through
``lfd.learners.mlp_kernel``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


def activation_and_slope(name: str, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """z = sigma(a) and sigma'(a), both shape of a, for the activations of ``lfd.learners.node``."""
    if name == "tanh":
        z = torch.tanh(a)
        return z, 1.0 - z * z
    if name == "relu":
        return torch.relu(a), (a > 0).to(a.dtype)
    if name == "softplus":
        return nn.functional.softplus(a), torch.where(a > 20.0, 1.0, torch.sigmoid(a))
    if name == "elu":
        z = nn.functional.elu(a)
        return z, torch.where(a > 0, 1.0, z + 1.0)
    s = torch.sigmoid(a)
    return a * s, s * (1.0 + a * (1.0 - s))


class ScaledMLP(torch.autograd.Function):
    """y = (z_L W_L^T + b_L - c) h with z_i = sigma(z_{i-1} W_i^T + b_i), z_0 = x, as one autograd node.

    Weights come in transposed, wt_i = W_i^T : (in, out); x : (B, d); h : (B, 1); c : (1, d)
    (the goal offset g(0)). Used where a solver other than the fused RK4 integrates the field.
    """

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor, activation: str,
                *params: torch.Tensor) -> torch.Tensor:
        zs, slopes = [x], []
        for wt, b in zip(params[0:-2:2], params[1:-2:2]):
            z, slope = activation_and_slope(activation, torch.addmm(b, zs[-1], wt))
            zs.append(z)
            slopes.append(slope)
        ctx.save_for_backward(h, *zs, *slopes, *params[0::2])
        ctx.n_hidden = len(slopes)
        return (torch.addmm(params[-1], zs[-1], params[-2]) - c) * h

    @staticmethod
    def backward(ctx: Any, gy: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        n = ctx.n_hidden
        saved = ctx.saved_tensors
        h, zs, slopes, wts = saved[0], saved[1:n + 2], saved[n + 2:2 * n + 2], saved[2 * n + 2:]
        g = gy * h
        gc = -g.sum(0, keepdim=True) if ctx.needs_input_grad[2] else None
        grads: list[torch.Tensor] = []
        for i in range(n, -1, -1):  # layer i maps zs[i] -> pre-activation of layer i + 1
            grads += [g.sum(0), zs[i].t().mm(g)]
            g = g.mm(wts[i].t())
            if i > 0:
                g = g * slopes[i - 1]
        grads.reverse()
        return (g if ctx.needs_input_grad[0] else None, None, gc, None, *grads)


def tanh_as_sigmoid(params: list[torch.Tensor]) -> list[torch.Tensor]:
    """The same MLP with its tanh layers written as logistic ones: tanh(a) = 2 s(2a) - 1.

    For transposed weights and biases (wt_i, b_i) of a tanh MLP, returns (A_i, beta_i) with
    s_1 = s(x A_1 + beta_1), s_i = s(s_{i-1} A_i + beta_i), y = s_L A_L + beta_L equal to the
    tanh MLP's output: A_1 = 2 wt_1, beta_1 = 2 b_1; A_i = 4 wt_i, beta_i = 2 (b_i - 1'wt_i) for the
    other hidden layers; A_L = 2 wt_L, beta_L = b_L - 1'wt_L for the output layer. Differentiable
    (autograd carries the gradients back to the tanh weights); the logistic function costs a
    third of tanh on CPU.
    """
    out: list[torch.Tensor] = []
    n_layers = len(params) // 2
    for i in range(n_layers):
        wt, b = params[2 * i], params[2 * i + 1]
        if i == 0:
            out += [2.0 * wt, 2.0 * b] if n_layers > 1 else [wt, b]
        elif i < n_layers - 1:
            out += [4.0 * wt, 2.0 * (b - wt.sum(0))]
        else:
            out += [2.0 * wt, b - wt.sum(0)]
    return out


def _slope(name: str, a: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """sigma'(a) of the activation ``name`` at the pre-activations a, whose activations are z."""
    if name == "tanh":
        return torch.addcmul(torch.ones_like(z), z, z, value=-1.0)
    if name == "sigmoid":
        return torch.addcmul(z, z, z, value=-1.0)
    return activation_and_slope(name, a)[1]


class RK4Segments(torch.autograd.Function):
    """Integrate dx/dtau = h (MLP(x) - c) from x0 with torchdiffeq's fixed-step ``rk4``, as one node.

    The 3/8-rule step of size 1 in tau (h carries the step: h = sample step / substeps):

        k1 = F(y),  k2 = F(y + k1/3),  k3 = F(y + k2 - k1/3),  k4 = F(y + k1 - k2 + k3),
        y' = y + (k1 + 3 k2 + 3 k3 + k4) / 8,

    ``substeps`` steps per sample, ``samples`` - 1 samples. The backward is the exact adjoint of
    these steps (discretise-then-optimise), with F's vector-Jacobian products written out for the
    MLP. Every evaluation writes its layer inputs into one buffer per layer, shape (E, B, width)
    for E evaluations, so the slopes of all evaluations and the weight gradients are each computed
    in one operation per layer.

    Inputs: x0 (B, d) (no gradient), h (B, 1) (no gradient), c (1, d), substeps, samples,
    activation (one of ``lfd.learners.node.ACTIVATIONS`` or ``sigmoid``), then the transposed
    weights and biases wt_1, b_1, ..., wt_L, b_L.
    Output: the states at the samples, shape (samples, B, d), the first x0.
    """

    @staticmethod
    def forward(ctx: Any, x0: torch.Tensor, h: torch.Tensor, c: torch.Tensor, substeps: int, samples: int,
                activation: str, *params: torch.Tensor) -> torch.Tensor:
        hidden = list(zip(params[0:-2:2], params[1:-2:2]))
        wt_out, b_eff = params[-2], params[-1] - c
        steps = substeps * (samples - 1)
        n_eval, batch = 4 * steps, x0.shape[0]
        # inputs[i][e]: the input of layer i at evaluation e (inputs[0]: the RK4 stage states)
        inputs = [x0.new_empty((n_eval, batch, wt.shape[0])) for wt in params[0::2]]
        own_out = activation in ("tanh", "sigmoid")   # written straight into the buffers
        act = torch.tanh if activation == "tanh" else torch.sigmoid
        pre = [] if own_out else [x0.new_empty((n_eval, batch, wt.shape[1])) for wt, _ in hidden]

        views = [buf.unbind(0) for buf in inputs]    # one view per evaluation, made at once
        pre_views = [buf.unbind(0) for buf in pre]
        states = views[0]

        def field(e: int) -> torch.Tensor:
            z = states[e]
            for i, (wt, b) in enumerate(hidden):
                if own_out:
                    z = act(torch.addmm(b, z, wt), out=views[i + 1][e])
                else:
                    a = torch.addmm(b, z, wt, out=pre_views[i][e])
                    z = views[i + 1][e].copy_(activation_and_slope(activation, a)[0])
            return torch.addmm(b_eff, z, wt_out).mul_(h)

        out = [x0]
        states[0].copy_(x0)
        third = 1.0 / 3.0
        for m in range(steps):
            e = 4 * m
            y = states[e]
            k1 = field(e)
            torch.add(y, k1, alpha=third, out=states[e + 1])
            k2 = field(e + 1)
            torch.add(y, k2, out=states[e + 2]).add_(k1, alpha=-third)
            k3 = field(e + 2)
            torch.add(y, k1, out=states[e + 3]).sub_(k2).add_(k3)
            k4 = field(e + 3)
            k2.add_(k3).mul_(3.0).add_(k1).add_(k4)
            nxt = states[e + 4] if m + 1 < steps else torch.empty_like(y)
            torch.add(y, k2, alpha=0.125, out=nxt)
            if (m + 1) % substeps == 0:
                out.append(nxt)
        ctx.save_for_backward(h, *params[0::2])
        ctx.buffers = (inputs, pre)
        ctx.substeps, ctx.samples, ctx.activation = substeps, samples, activation
        return torch.stack(out)

    @staticmethod
    def backward(ctx: Any, gout: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        h, *wts = ctx.saved_tensors
        inputs, pre = ctx.buffers
        n_hidden = len(wts) - 1
        n_eval = inputs[0].shape[0]
        slopes = [_slope(ctx.activation, pre[i] if pre else inputs[i + 1], inputs[i + 1]) for i in range(n_hidden)]
        # grads[i][e]: the gradient of the output of layer i (pre-activation) at evaluation e
        grads = [inputs[i + 1].new_empty(slopes[i].shape) for i in range(n_hidden)]
        grads.append(gout.new_empty((n_eval, *gout.shape[1:])))
        wts_t = [w.t() for w in wts]
        slope_views = [s.unbind(0) for s in slopes]
        grad_views = [g.unbind(0) for g in grads]

        def vjp(e: int, gk: torch.Tensor) -> torch.Tensor:
            g = torch.mul(gk, h, out=grad_views[n_hidden][e])
            for i in range(n_hidden - 1, -1, -1):
                g = torch.mul(g.mm(wts_t[i + 1]), slope_views[i][e], out=grad_views[i][e])
            return g.mm(wts_t[0])

        gy = gout[-1].clone()
        m = n_eval // 4
        for j in range(ctx.samples - 1, 0, -1):
            for _ in range(ctx.substeps):
                m -= 1
                e = 4 * m
                u4 = vjp(e + 3, gy * 0.125)
                u3 = vjp(e + 2, gy * 0.375 + u4)
                u2 = vjp(e + 1, torch.add(u3, gy, alpha=0.375).sub_(u4))
                u1 = vjp(e, torch.add(u2, u3, alpha=-1.0).mul_(1.0 / 3.0).add_(u4).add_(gy, alpha=0.125))
                gy.add_(u1).add_(u2).add_(u3).add_(u4)
            gy.add_(gout[j - 1])
        param_grads: list[torch.Tensor] = []
        for z, g in zip(inputs, grads):
            g2 = g.reshape(-1, g.shape[-1])
            param_grads += [z.reshape(-1, z.shape[-1]).t().mm(g2), g2.sum(0)]
        gc = -param_grads[-1].reshape(1, -1) if ctx.needs_input_grad[2] else None
        ctx.buffers = None
        return (None, None, gc, None, None, None, *param_grads)
