"""Neural ODE learner: an MLP velocity field fitted by integrating it through the demos.

The field is dx_n/dt = f_theta(x_n), the paper's NODE, Eq. (12): an MLP as its Eqs. (7) and (14)
but with a linear output layer (a ReLU or tanh output would make every velocity component
non-negative or bounded by 1; a field that reaches a goal needs both signs), any number of hidden
layers, and with ``goal_equilibrium`` f_theta(x) = g_theta(x) - g_theta(0), so the goal is an
equilibrium exactly. It is trained by multiple shooting on the paper's loss, Eqs. (4) and (13):

    L(theta) = 1 / (B (S - 1) d) sum_b sum_{j=1}^{S-1} || phi_theta(t_{k+j} - t_k; x_k) - x_{k+j} ||^2,

each of the B segments integrating S samples from a demo sample x_k with torchdiffeq (phi_theta the
flow of f_theta, the paper's Eq. (5), stepping as its Eq. (3)), rather than one integration through a
whole demo, whose errors compound. Gradients backpropagate through the solver's steps, or, with
``adjoint``, by the paper's adjoint ODE, Eq. (6). S grows from ``seg_start`` to ``seg`` (a curriculum);
batches are stratified over demo and time; Adam with a cosine learning rate. Training is bound by
per-op overhead (the batches are small): with the default fixed-step ``rk4`` (torchdiffeq's, the
3/8 rule) a whole batch of segments integrates as one autograd node with its exact discrete adjoint
(``lfd.learners.node_kernel.RK4Segments``); with another solver or the adjoint, torchdiffeq
integrates the MLP as one fused node (``ScaledMLP``). Both are checked against autograd through
torchdiffeq in the tests. Details: docs/equations.md, "The NODE's loss".

References
----------
Chen, R. T. Q., Rubanova, Y., Bettencourt, J., Duvenaud, D. (2018). Neural ordinary differential
equations. NeurIPS. arXiv:1806.07366
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np
import torch
from torch import nn
from torchdiffeq import odeint, odeint_adjoint
from tqdm.auto import tqdm

from lfd import integrate
from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.field import VelocityField
from lfd.learners.base import Learner
from lfd.learners.node_kernel import RK4Segments, ScaledMLP, tanh_as_sigmoid
from lfd.learners.optim import Adam
from lfd.threads import torch_threads
from lfd.validate import check_bools, check_ints, check_numbers, check_positive, is_int

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh, "relu": nn.ReLU, "softplus": nn.Softplus, "elu": nn.ELU, "silu": nn.SiLU,
}
DTYPES: dict[str, torch.dtype] = {"float32": torch.float32, "float64": torch.float64}
# Training runs on one thread: with batches of a few hundred points the MLP is bound by
# per-op overhead, so a second thread does not help, and it slows down under load.
TRAIN_THREADS = 1
POSTFIX_EVERY = 25
MAX_LR = 1e3


@dataclass
class NodeConfig:
    """Options of the NODE learner (all JSON-able).

    hidden : widths of the hidden layers       activation : tanh, relu, softplus, elu or silu
    lr, lr_final : Adam learning rate, cosine-annealed from lr to lr_final over ``iterations``
    solver : torchdiffeq method; ``substeps`` fixed steps per sample, ``rtol``/``atol`` if adaptive
    adjoint : backpropagate with odeint_adjoint (O(1) memory in the segment length, slower)
    seg : samples per shooting segment at the end; ``seg_start`` at the start, growing linearly
          over the first ``curriculum`` fraction of the iterations
    batch : segments per iteration, one drawn from each of ``batch`` equal strata (0: all of them)
    samples : longer demos are resampled to this many samples (0: keep every sample)
    dtype : float32 or float64 for training (the fitted field always evaluates in float64)
    goal_equilibrium : subtract g(0) so that f(0) = 0 exactly: the goal is an equilibrium
    """

    hidden: tuple[int, ...] = (32, 32)
    activation: str = "tanh"
    lr: float = 2e-2
    lr_final: float = 1e-4
    iterations: int = 1500
    solver: str = "rk4"
    substeps: int = 1
    rtol: float = 1e-5
    atol: float = 1e-6
    adjoint: bool = False
    seg: int = 10
    seg_start: int = 2
    curriculum: float = 0.5
    batch: int = 64
    samples: int = 100
    dtype: str = "float32"
    goal_equilibrium: bool = True
    weight_decay: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.hidden, (list, tuple)) or not self.hidden \
                or any(not is_int(w) or w < 1 for w in self.hidden):
            raise ValueError(f"hidden must list at least one positive integer width, got {self.hidden!r}")
        self.hidden = tuple(int(w) for w in self.hidden)
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation '{self.activation}'; known: {', '.join(ACTIVATIONS)}")
        integrate.check_method(self.solver)  # ValueError naming the solvers of lfd.integrate.SOLVERS
        if self.dtype not in DTYPES:
            raise ValueError(f"dtype must be one of {', '.join(DTYPES)}, got '{self.dtype}'")
        check_positive(self, ("lr", "lr_final", "rtol", "atol"))
        if self.lr > MAX_LR:  # beyond it Adam's step overflows float32 (a traceback, not a model)
            raise ValueError(f"lr must be at most {MAX_LR:g}, got {self.lr!r}")
        if self.lr_final > self.lr:
            raise ValueError(f"lr_final ({self.lr_final}) must not exceed lr ({self.lr})")
        check_numbers(self, ("weight_decay",), "a number >= 0", lambda v: v >= 0)
        check_numbers(self, ("curriculum",), "a number in [0, 1]", lambda v: 0.0 <= v <= 1.0)
        check_ints(self, (("iterations", 1, None), ("substeps", 1, None), ("seg", 2, None), ("seg_start", 2, None),
                          ("batch", 0, None), ("samples", 0, None)))
        if self.seg_start > self.seg:
            raise ValueError(f"seg_start ({self.seg_start}) must not exceed seg ({self.seg})")
        if 0 < self.samples < self.seg:
            raise ValueError(f"samples ({self.samples}) must be at least seg ({self.seg})")
        check_bools(self, ("adjoint", "goal_equilibrium"))


class NodeMLP(nn.Module):
    """f(x) = g(x) - g(0) (or g(x)), g an MLP with linear output; x : (B, d) -> (B, d).

    The paper's Eqs. (7) and (14) without the activation on the output layer (module docstring).
    """

    def __init__(self, dim: int, hidden: tuple[int, ...], activation: str, goal_equilibrium: bool) -> None:
        super().__init__()
        self.activation = activation
        self.goal_equilibrium = goal_equilibrium
        layers: list[nn.Module] = []
        width = dim
        for w in hidden:
            layers += [nn.Linear(width, w), ACTIVATIONS[activation]()]
            width = w
        layers.append(nn.Linear(width, dim))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.net(x)
        if self.goal_equilibrium:
            y = y - self.net(torch.zeros_like(x[:1]))
        return y

    def linears(self) -> list[nn.Linear]:
        return [m for m in self.net if isinstance(m, nn.Linear)]


class SegmentDynamics(nn.Module):
    """dx/dtau = h f(x) in sample units tau; h : (B, 1), the sample step of each segment's demo.

    Integrated over one sample, it is the paper's NODE step, Eq. (3).

    With ``fused`` the field is one ``ScaledMLP`` node and the goal offset g(0) of a NodeMLP
    is computed once per ``begin`` (the parameters are fixed during one integration);
    odeint_adjoint needs the plain f(x) instead, since it differentiates each evaluation alone.
    """

    def __init__(self, field: NodeMLP, fused: bool) -> None:
        super().__init__()
        self.field = field
        self.fused = fused
        self.h = torch.ones(1, 1)
        self.offset = torch.zeros(1, 1)
        self.params: list[torch.Tensor] = []

    def begin(self, h: torch.Tensor) -> None:
        """Set the steps h (B, 1) of the next batch, the transposed weights and g(0) (1, d)."""
        self.h = h
        if self.fused:
            lin = self.field.linears()
            self.params = [p for m in lin for p in (m.weight.t(), m.bias)]
            d = lin[0].in_features
            zero = torch.zeros(1, d, dtype=h.dtype)
            self.offset = self.field.net(zero) if self.field.goal_equilibrium else zero

    def forward(self, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        if self.fused:
            return ScaledMLP.apply(x, self.h, self.offset, self.field.activation, *self.params)
        return self.field(x) * self.h


@dataclass(frozen=True)
class Segments:
    """All shooting segments of S samples: windows (S, M, d) and their sample steps h (M, 1)."""

    windows: torch.Tensor
    h: torch.Tensor

    @classmethod
    def of(cls, x: torch.Tensor, h: torch.Tensor, seg: int) -> Segments:
        """x : (N, T, d) uniform-grid demos; h : (N,) their sample steps."""
        n, T, d = x.shape
        w = x.unfold(1, seg, 1)                       # (N, T - S + 1, d, S)
        windows = w.permute(3, 0, 1, 2).reshape(seg, -1, d).contiguous()
        return cls(windows, h.repeat_interleave(T - seg + 1).reshape(-1, 1))


def uniform_grid(demos: DemoSet, samples: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Demos on uniform per-demo time grids: x (N, T', d) and sample steps h (N,).

    T' = min(T, samples) (T' = T if ``samples`` is 0); uniform demos with T' = T are returned
    unchanged, the others are interpolated linearly in time.
    """
    T = min(samples, demos.n_samples) if samples else demos.n_samples
    xs, hs = [], []
    for t, x in zip(demos.t, demos.x):
        steps = np.diff(t)
        uniform = np.ptp(steps) <= 1e-6 * steps.mean()
        if uniform and T == len(t):
            xs.append(x)
        else:
            tn = np.linspace(t[0], t[-1], T)
            xs.append(np.stack([np.interp(tn, t, x[:, j]) for j in range(x.shape[1])], axis=1))
        hs.append((t[-1] - t[0]) / (T - 1))
    return np.stack(xs), np.asarray(hs)


class Schedule(Protocol):
    """What multiple shooting reads of a learner's config (``NodeConfig``'s names): the iterations,
    the batch of segments and the segment curriculum."""

    iterations: int
    batch: int
    seg: int
    seg_start: int
    curriculum: float


class Shooter(Protocol):
    """One learner's loss on a batch of segments and its optimiser step (``shoot_segments``)."""

    def loss(self, w: torch.Tensor, hb: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """The loss of windows w (S, B, d) with sample steps hb (B, 1) at tau (S,), a scalar."""

    def step(self, loss: torch.Tensor) -> None:
        """One optimiser step on ``loss``."""


def segment_length(config: Schedule, k: int) -> int:
    """S_k = round(seg_start + (seg - seg_start) min(1, k / (curriculum iterations)))."""
    ramp = config.curriculum * config.iterations
    frac = 1.0 if ramp <= 0 else min(1.0, k / ramp)
    return int(round(config.seg_start + (config.seg - config.seg_start) * frac))


def stratified_sample(m: int, batch: int, gen: torch.Generator) -> torch.Tensor:
    """``batch`` indices in [0, m): one uniform draw from each of ``batch`` equal consecutive strata.

    Segments are ordered by demo, then by start time, so every batch covers every part of every
    demo (fast starts and slow approaches alike), with far less variance than i.i.d. draws.
    """
    edges = torch.div(torch.arange(batch + 1) * m, batch, rounding_mode="floor")
    lo, size = edges[:-1], edges[1:] - edges[:-1]
    return lo + (torch.rand(batch, generator=gen, dtype=torch.float64) * size).long()


def solver_options(config: NodeConfig) -> dict[str, Any]:
    """Keyword arguments of odeint for the configured solver, in sample units tau.

    From ``lfd.integrate.odeint_kwargs``: a fixed-step solver takes ``substeps`` steps per sample
    (one step per sample needs no step_size: the solver then steps on the output grid itself);
    an adaptive one takes ``rtol`` and ``atol`` (and ignores ``substeps``).
    """
    if integrate.check_method(config.solver).adaptive:
        return integrate.odeint_kwargs(config.solver, rtol=config.rtol, atol=config.atol)
    return integrate.odeint_kwargs(config.solver, step=1.0 / config.substeps if config.substeps > 1 else None)


class _Shooting:
    """The optimisation of ``fit_segments``: the segment dynamics, the solver, Adam and its schedule."""

    def __init__(self, module: nn.Module, config: NodeConfig) -> None:
        self.dynamics = SegmentDynamics(cast(NodeMLP, module), fused=not config.adjoint)
        # torchdiffeq's rk4 through a whole segment as one node (lfd.learners.node_kernel)
        self.fused_rk4 = config.solver == "rk4" and not config.adjoint
        self.substeps = config.substeps
        self.solve = odeint_adjoint if config.adjoint else odeint
        self.kwargs = solver_options(config)
        if config.adjoint:
            self.kwargs["adjoint_params"] = tuple(module.parameters())
        self.opt = Adam(module.parameters(), lr=config.lr, lr_final=config.lr_final, t_max=config.iterations,
                        weight_decay=config.weight_decay)

    def loss(self, w: torch.Tensor, hb: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """The loss L of the module docstring (the paper's Eq. (4), by multiple shooting) on
        windows w, shape (S, B, d), with sample steps hb, shape (B, 1), at tau, shape (S,)."""
        self.dynamics.begin(hb)
        if self.fused_rk4:
            d, activation = self.dynamics, self.dynamics.field.activation
            params = d.params
            if activation == "tanh":
                params, activation = tanh_as_sigmoid(params), "sigmoid"
            pred = RK4Segments.apply(w[0], hb / self.substeps, d.offset, self.substeps, w.shape[0],
                                     activation, *params)
        else:
            pred = self.solve(self.dynamics, w[0], tau, **self.kwargs)
        return torch.mean((pred[1:] - w[1:]) ** 2)

    def step(self, loss: torch.Tensor) -> None:
        """One Adam step on ``loss``, then one step of the cosine schedule (``lfd.learners.optim``)."""
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()


def _batch(segments: Segments, config: Schedule, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The windows (S, B, d) and steps (B, 1) of one iteration: stratified, or all segments."""
    m = segments.windows.shape[1]
    if 0 < config.batch < m:
        idx = stratified_sample(m, config.batch, gen)
        return segments.windows[:, idx], segments.h[idx]
    return segments.windows, segments.h


def fit_segments(module: nn.Module, x: torch.Tensor, h: torch.Tensor, config: NodeConfig,
                 progress: bool = True, desc: str = "node") -> dict[str, Any]:
    """Train ``module`` in place by multiple shooting on uniform-grid demos (see module docstring).

    x : tensor, shape (N, T, d), normalised demos; h : tensor, shape (N,), sample steps.
    Returns ``shoot_segments``' history.
    """
    dtype = DTYPES[config.dtype]
    module.to(dtype).train()
    return shoot_segments(module, x.to(dtype), h.to(dtype), config, _Shooting(module, config), progress, desc,
                          "node")


def shoot_segments(module: nn.Module, x: torch.Tensor, h: torch.Tensor, config: Schedule, shooter: Shooter,
                   progress: bool, desc: str, name: str) -> dict[str, Any]:
    """The multiple-shooting loop: ``config.iterations`` steps of ``shooter`` on stratified batches of
    segments whose length follows the curriculum (``segment_length``), one torch thread.

    x : tensor, shape (N, T, d), normalised demos; h : tensor, shape (N,), sample steps (both in the
    training dtype). Draws its batches from a generator seeded from torch's global one. Returns the
    history: ``loss`` (per iteration), ``seg`` (last), ``best_loss``, ``best_iter``, ``iterations``
    (done), ``interrupted`` (Ctrl-C) and ``stopped_nonfinite`` (a non-finite loss, warned of as
    ``name``). Whether training ends, is interrupted or diverges, the module is left at its best
    iterate among those at the last segment length reached (losses only compare at equal length),
    in eval mode.
    """
    gen = torch.Generator().manual_seed(int(torch.randint(0, 2**62, (1,)).item()))
    losses: list[float] = []
    best: tuple[float, int, dict[str, torch.Tensor]] | None = None
    interrupted = nonfinite = False
    segments: Segments | None = None
    try:
        with torch_threads(TRAIN_THREADS), \
                tqdm(total=config.iterations, desc=desc, disable=not progress, leave=False) as bar:
            for k in range(config.iterations):
                seg = segment_length(config, k)
                if segments is None or segments.windows.shape[0] != seg:
                    segments, best = Segments.of(x, h, seg), None
                    tau = torch.arange(seg, dtype=x.dtype)
                loss = shooter.loss(*_batch(segments, config, gen), tau)
                value = float(loss.item())
                if not math.isfinite(value):
                    nonfinite = True
                    warnings.warn(f"{name}: the loss became non-finite at iteration {k}; training stopped "
                                  "and kept the best iterate (a lower lr may help)",
                                  RuntimeWarning, stacklevel=3)
                    break
                losses.append(value)
                if best is None or value < best[0]:
                    best = (value, k, {n: p.detach().clone() for n, p in module.state_dict().items()})
                shooter.step(loss)
                bar.update(1)
                if k % POSTFIX_EVERY == 0:
                    bar.set_postfix(loss=f"{value:.3g}", seg=seg, refresh=False)
    except KeyboardInterrupt:
        interrupted = True
    if best is not None:
        module.load_state_dict(best[2])
    module.eval()
    return {
        "loss": losses,
        "seg": segment_length(config, max(len(losses) - 1, 0)),
        "best_loss": best[0] if best else None,
        "best_iter": best[1] if best else None,
        "iterations": len(losses),
        "interrupted": interrupted,
        "stopped_nonfinite": nonfinite,
    }


class NodeField(VelocityField):
    """A NODE velocity field with a compiled single-point path for control loops."""

    def jacobian_lipschitz_bound(self) -> float:
        """An upper bound of Lip(J_f) = sup |D^2 f| on all of R^d, user units (1/(s unit)).

        For f = W_L sigma(... sigma(W_1 x + b_1)) with |sigma'| <= s1 and |sigma''| <= s2 and
        n_i = |W_i|_2: D^2 f = sum_k W_L D_{L-1} ... diag(sigma''(z_k) dz_k) ... D_1 W_1, so
        |D^2 f| <= s2 sum_{k<L} (prod_{i>k} n_i) s1^(L-1-k) (prod_{i<=k} n_i s1^(k-1))^2.
        In user units D^2 f scales by 1/s. Returns inf for an activation without a bounded
        second derivative (relu) or non-finite weights.
        """
        module: NodeMLP = self.module  # type: ignore[assignment]
        slopes = {"tanh": (1.0, 4.0 / (3.0 * math.sqrt(3.0))), "softplus": (1.0, 0.25),
                  "silu": (1.1, 0.5), "elu": (1.0, 1.0)}
        if module.activation not in slopes:
            return math.inf
        s1, s2 = slopes[module.activation]
        norms = [float(torch.linalg.matrix_norm(m.weight.detach().double(), ord=2)) * (1 + 1e-12)
                 for m in module.linears()]
        if not all(math.isfinite(n) for n in norms):
            return math.inf
        n_layers = len(norms)
        total = 0.0
        for k in range(1, n_layers):
            after = math.prod(norms[k:]) * s1 ** (n_layers - 1 - k)
            before = math.prod(norms[:k]) * s1 ** (k - 1)
            total += s2 * after * before * before
        return total / float(self.norm.scale)

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """The fast path for one point, for control loops: ``field(x)`` on x of shape (d,) calls it.

        One compiled call (``lfd.learners.mlp_kernel``) on a snapshot of the weights
        (``numpy_layers``, g(0) folded into the output bias). The normalisation x_n = (x - goal) / s,
        f = s f_n(x_n) is folded into the first and last layers: W_1' = W_1 / s,
        b_1' = b_1 - W_1 goal / s, W_L' = s W_L, b_L' = s b_L.

        Returns
        -------
        callable
            x, array of shape (d,), user units -> dx/dt, array of shape (d,), user units.
        """
        from lfd.learners.mlp_kernel import mlp_point_fn  # here: ``import lfd`` does not import numba

        module = cast(NodeMLP, self.module)
        layers = numpy_layers(module)
        goal, s = self.norm.goal, float(self.norm.scale)
        (w1, b1), (wl, bl) = layers[0], layers[-1]
        layers[0] = (w1 / s, b1 - w1.dot(goal) / s)
        layers[-1] = (wl * s, bl * s)
        return mlp_point_fn(layers, module.activation)


def numpy_layers(module: NodeMLP) -> list[tuple[np.ndarray, np.ndarray]]:
    """The layers (W_i (out, in), b_i (out,)) of ``module`` in float64, input first, with g(0)
    folded into the output bias when ``goal_equilibrium``: f(x_n) = W_L z_{L-1} + b_L - g(0), g(0)
    by the compiled kernel (``lfd.learners.mlp_kernel``), which is then compiled or loaded."""
    from lfd.learners.mlp_kernel import mlp_point_fn  # here: ``import lfd`` does not import numba

    layers = [(m.weight.detach().double().numpy().copy(), m.bias.detach().double().numpy().copy())
              for m in module.linears()]
    if module.goal_equilibrium:
        w_out, b_out = layers[-1]
        g0 = mlp_point_fn(layers, module.activation)(np.zeros(layers[0][0].shape[1]))
        layers[-1] = (w_out, b_out - g0)
    return layers


class NodeLearner(Learner, name="node", config=NodeConfig, field=NodeField):
    """Neural ODE: an MLP field trained by multiple shooting through torchdiffeq."""

    @classmethod
    def parameter_count(cls, dim: int, config: NodeConfig) -> int:
        """Weights and biases of the MLP d -> hidden... -> d of ``build``."""
        widths = [dim, *config.hidden, dim]
        return sum((i + 1) * o for i, o in zip(widths[:-1], widths[1:]))

    @classmethod
    def build(cls, dim: int, config: NodeConfig) -> nn.Module:
        """A fresh NodeMLP x_n (B, d) -> dx_n/dt (B, d), in the training dtype."""
        module = NodeMLP(dim, config.hidden, config.activation, config.goal_equilibrium)
        return module.to(DTYPES[config.dtype])

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: NodeConfig, progress: bool) -> dict[str, Any]:
        """Multiple shooting on the normalised ``demos`` (see ``fit_segments``)."""
        x, h = uniform_grid(demos, config.samples)
        if config.seg > x.shape[1]:
            raise ConfigError(f"node: seg ({config.seg}) exceeds the {x.shape[1]} samples per demo")
        return fit_segments(module, torch.tensor(x), torch.tensor(h), config, progress)
