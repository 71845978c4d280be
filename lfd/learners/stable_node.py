"""Stable NODE learner: the NODE's MLP field corrected onto a learned Lyapunov function's decrease.

In normalised coordinates (goal at the origin), Eqs. (L1)-(L4) of docs/equations.md:

    Eq. (L1): V(x) = |phi(x) - phi(0)|^2,  phi a ``BoundedFlow`` (s_lo <= sigma(J_phi(x)) <= s_hi for every x),
    Eq. (L2): f(x) = fhat(x) - gamma relu(grad V . fhat + alpha(V) V) / |grad V|^2 grad V,
              alpha(V) = alpha + alpha_g V_g / (V_g + V),  alpha = 2 rate,  gamma >= 1,

fhat the NODE's MLP with fhat(0) = 0 (gamma = 1 is Manek & Kolter's projection). Then dV/dt =
grad V . f <= -alpha(V) V <= -alpha V at every x, so every trajectory obeys Eq. (L3),
|x(t)| <= (s_hi / s_lo) |x(0)| e^(-rate t): the goal is the only equilibrium and attracts every
start. Training, Eq. (L4): fhat by the NODE's multiple shooting through the ODE solver
(``lfd.learners.node.fit_segments``), then phi by a hinge on d log V / dt along the demos and fhat's
rollouts; the shooting segments on which the correction acts are counted, and, with
``finetune_iterations``, fhat and phi are trained on them through the corrected field.

References
----------
Manek, G., Kolter, J. Z. (2019). Learning stable deep dynamics models. NeurIPS. arXiv:2001.06116
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.field import VelocityField
from lfd.learners.base import Learner
from lfd.learners.flows import SWIRL_COMPONENTS, BoundedFlow
from lfd.learners.node import (
    NodeConfig,
    NodeLearner,
    NodeMLP,
    Segments,
    fit_segments,
    numpy_layers,
    stratified_sample,
    uniform_grid,
)
from lfd.learners.optim import Adam
from lfd.threads import torch_threads
from lfd.validate import check_ints, check_numbers

TRAIN_THREADS = 1
HINGE_GOAL_RADIUS = 1e-3   # normalised units: demo points this close to the goal are left out of the hinge
LYAPUNOV_MIN_STEPS = 100   # phi's fit checks fhat's rollouts from this step on ...
LYAPUNOV_CHECK = 25        # ... every this many steps, and stops once the correction acts on none


@dataclass
class StableNodeConfig(NodeConfig):
    """Options of the stable NODE: the NODE's (for fhat, trained as the NODE is), then these.

    rate : alpha / 2 of Eq. (L2), 1/s: |x(t)| <= (s_hi/s_lo) |x(0)| e^(-rate t); None: ``rate_factor``
           / the demos' mean duration
    goal_rate_factor : the rate at the goal over ``rate``, (alpha + alpha_g) / alpha, >= 1
    goal_radius : r_g, V_g = r_g^2 of alpha(V) (normalised units)
    correction_gain : gamma - 1 >= 0 of Eq. (L2) (0: the minimal correction, a projection)
    max_condition : KAPPA >= (s_hi / s_lo)^2 of phi (inf: each layer's own cap, ``lfd.learners.flows``)
    flow_layers, flow_hidden, window, length_scale : phi's (swirl, block) pairs, block width, window
    lyapunov_iterations, lyapunov_lr, lyapunov_points : at most this many Adam steps on phi's hinge
    (Eq. (L4), fewer once fhat's rollouts need no correction), its learning rate, its points
    margin : the hinge asks d log V / dt <= -(1 + margin) alpha
    finetune_iterations, finetune_lr, hinge_weight : multiple shooting through f on the segments
    where the correction acts (0: none), its learning rate, the hinge's weight there
    """

    rate: float | None = None
    rate_factor: float = 1.0
    goal_rate_factor: float = 4.0
    goal_radius: float = 0.05
    correction_gain: float = 3.0
    max_condition: float = math.inf
    flow_layers: int = 3
    flow_hidden: int = 16
    window: float = 1.5
    length_scale: float = 0.5
    lyapunov_iterations: int = 500
    lyapunov_lr: float = 3e-2
    lyapunov_points: int = 1024
    margin: float = 1.0
    finetune_iterations: int = 0
    finetune_lr: float = 1e-4
    hinge_weight: float = 1e-3

    def __post_init__(self) -> None:
        super().__post_init__()
        if isinstance(self.rate, str):     # ``--option rate=0.5`` arrives as text (its default is None)
            try:
                self.rate = float(self.rate)
            except ValueError:
                raise ValueError(f"rate must be a positive number, got {self.rate!r}") from None
        positive = "a positive number below 1e6"
        if self.rate is not None:
            check_numbers(self, ("rate",), positive, lambda v: 0 < v <= 1e6, to_float=True)
        check_numbers(self, ("rate_factor", "goal_radius", "window", "length_scale", "lyapunov_lr", "finetune_lr"),
                      positive, lambda v: 0 < v <= 1e6, to_float=True)
        check_numbers(self, ("goal_rate_factor",), "a number from 1 to 1e6", lambda v: 1 <= v <= 1e6, to_float=True)
        check_numbers(self, ("margin", "hinge_weight", "correction_gain"), "a non-negative number below 1e6",
                      lambda v: 0 <= v <= 1e6, to_float=True)
        check_numbers(self, ("max_condition",), "a number > 1 (or inf)", lambda v: v > 1, to_float=True,
                      allow_inf=True)
        check_ints(self, (("flow_layers", 1, 64), ("flow_hidden", 1, 4096), ("lyapunov_iterations", 0, 10**6),
                          ("lyapunov_points", 1, 10**7), ("finetune_iterations", 0, 10**6)))
        if self.goal_equilibrium is not True:
            raise ValueError("goal_equilibrium must be true: Eq. (L2) needs fhat(0) = 0")


class StableNodeModule(nn.Module):
    """f of Eq. (L2): x (B, d) -> (B, d), from the nominal MLP ``nominal`` (fhat) and the flow ``flow`` (phi).

    The buffers ``alpha`` and ``alpha_goal`` (1/s) are alpha and alpha_g of Eq. (L2), set by ``fit``
    (and restored with the state dict); ``gain`` is gamma and ``v_goal`` V_g, from the config.
    ``freeze`` keeps the flow's effective parameters (``BoundedFlow.scaled``) for the forward passes
    of a fitted field, which then need no eigen-decomposition (and export to ONNX).
    """

    alpha: torch.Tensor
    alpha_goal: torch.Tensor

    def __init__(self, dim: int, config: StableNodeConfig) -> None:
        super().__init__()
        if dim < 2:
            raise ConfigError(f"stable_node needs d >= 2 (its flow phi), got d = {dim}")
        self.nominal = NodeMLP(dim, config.hidden, config.activation, True)
        self.flow = BoundedFlow(dim, config.flow_layers, config.flow_hidden, config.window,
                                config.max_condition, config.length_scale)
        rate = config.rate or 0.0
        self.register_buffer("alpha", torch.tensor(2.0 * rate))
        self.register_buffer("alpha_goal", torch.tensor(2.0 * rate * (config.goal_rate_factor - 1.0)))
        self.gain = 1.0 + float(config.correction_gain)
        self.v_goal = float(config.goal_radius) ** 2
        self.frozen: dict[str, torch.Tensor] | None = None

    def freeze(self) -> None:
        """Keep the flow's effective parameters (no gradient) for the forward passes to come."""
        with torch.no_grad():
            self.frozen = {k: v.detach().clone() for k, v in self.flow.scaled().items()}

    def unfreeze(self) -> None:
        """Forget the frozen parameters (before training)."""
        self.frozen = None

    def set_rates(self, rate: float, goal_rate_factor: float) -> None:
        """alpha = 2 rate and alpha_g = alpha (goal_rate_factor - 1), rate in 1/s."""
        with torch.no_grad():
            self.alpha.fill_(2.0 * rate)
            self.alpha_goal.fill_(2.0 * rate * (goal_rate_factor - 1.0))

    def lyapunov(self, x: torch.Tensor, params: dict[str, torch.Tensor] | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """V(x) of Eq. (L1), shape (B,), and grad V(x) = 2 J_phi(x)' (phi(x) - phi(0)), shape (B, d).

        params : the flow's effective parameters (``BoundedFlow.scaled``); default the frozen ones,
        else computed now."""
        y, jac = self.flow.forward_with_jacobian(torch.cat([x, x.new_zeros(1, x.shape[1])]),
                                                 params=self.frozen if params is None else params)
        assert jac is not None
        r = y[:-1] - y[-1:]
        return (r * r).sum(1), 2.0 * (jac[:-1].transpose(1, 2) @ r.unsqueeze(-1)).squeeze(-1)

    def decrease_rate(self, v: torch.Tensor) -> torch.Tensor:
        """alpha(V) = alpha + alpha_goal V_g / (V_g + V) of Eq. (L2), 1/s, for V of shape (B,)."""
        return self.alpha + self.alpha_goal * (self.v_goal / (self.v_goal + v))

    def project(self, fhat: torch.Tensor, v: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
        """Eq. (L2) given fhat (B, d), V (B,) and grad V (B, d): the corrected field (B, d)
        (0 where grad V = 0, i.e. at the goal)."""
        g2 = (grad * grad).sum(1)
        excess = torch.relu((grad * fhat).sum(1) + self.decrease_rate(v) * v)
        coef = self.gain * excess / torch.where(g2 > 0, g2, torch.ones_like(g2))
        return fhat - coef[:, None] * grad

    def forward(self, x: torch.Tensor, params: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """f(x) of Eq. (L2), shape (B, d), for x of shape (B, d); ``params`` as in ``lyapunov``."""
        v, grad = self.lyapunov(x, params)
        return self.project(self.nominal(x), v, grad)


def rk4_segments(f: Callable[[torch.Tensor], torch.Tensor], x0: torch.Tensor, h: torch.Tensor,
                 samples: int) -> torch.Tensor:
    """torchdiffeq's ``rk4`` (3/8 rule) of dx/dtau = h f(x), one step per sample: (samples, B, d)."""
    out = [x0]
    y = x0
    third = 1.0 / 3.0
    for _ in range(samples - 1):
        k1 = h * f(y)
        k2 = h * f(y + k1 * third)
        k3 = h * f(y + k2 - k1 * third)
        k4 = h * f(y + k1 - k2 + k3)
        y = y + (k1 + 3.0 * (k2 + k3) + k4) * 0.125
        out.append(y)
    return torch.stack(out)


def decrease_hinge(module: StableNodeModule, x: torch.Tensor, v: torch.Tensor, target: float,
                   params: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
    """mean relu(d log V / dt + target) / target over points x (B, d) moving at v (B, d) (scale-free),
    d log V / dt = grad V . v / V = 2 r' J_phi v / |r|^2, r = phi(x) - phi(0) (Eq. (L4))."""
    zero = x.new_zeros(1, x.shape[1])
    y, jv = module.flow.forward_with_tangent(torch.cat([x, zero]), torch.cat([v, zero]),
                                             module.frozen if params is None else params)
    r = y[:-1] - y[-1:]
    rate = 2.0 * (r * jv[:-1]).sum(1) / (r * r).sum(1).clamp_min(1e-300)
    return torch.relu(rate + target).mean() / target


def demo_rate(h: np.ndarray, samples: int, factor: float) -> float:
    """``factor`` / the mean demo duration (h (N,) sample steps of ``samples`` samples)."""
    return factor / float(np.mean(h) * (samples - 1))


class StableNodeField(VelocityField):
    """A stable NODE field, Eq. (L2): globally asymptotically stable at its goal by construction.

    ``decay_rate`` (1/s) and ``overshoot_bound`` s_hi / s_lo give Eq. (L3); ``lyapunov`` samples V and
    its decrease; ``stability_constants`` collects the analytic constants (``lfd certify`` checks both).
    The field states no contraction (``rate`` stays None): two trajectories may separate for a while.
    """

    module: StableNodeModule

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.module.freeze()

    @property
    def decay_rate(self) -> float:
        """The guaranteed rate, 1/s: |x(t) - goal| <= (s_hi/s_lo) |x(0) - goal| e^(-rate t)."""
        return float(self.module.alpha) / 2.0

    @property
    def overshoot_bound(self) -> float:
        """s_hi / s_lo of phi (Eq. (F4)), the constant of Eq. (L3); unit-free."""
        s_lo, s_hi = self.module.flow.singular_value_bounds()
        return s_hi / s_lo

    def stability_constants(self) -> dict[str, Any]:
        """``stability_certificate(self)``."""
        return stability_certificate(self)

    def lyapunov(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """V, its rate of change dV/dt = grad V . f along the field, and alpha(V), at x of shape (..., d).

        x in user units; V is Eq. (L1) at the normalised point (unit-free), dV/dt and alpha(V) are in
        1/s. Eq. (L2) makes dV/dt <= -alpha(V) V at every x, up to round-off (Eq. (L3)).
        Returns three arrays of shape x.shape[:-1].
        """
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"lyapunov expects points of dimension {self.dim}, got shape {x.shape}")
        xn = torch.tensor(self.norm.to_norm(x.reshape(-1, self.dim)))
        with torch.no_grad(), torch_threads(1):
            v, grad = self.module.lyapunov(xn)
            dv = (grad * self.module.project(self.module.nominal(xn), v, grad)).sum(1)
            alpha = self.module.decrease_rate(v)
        shape = x.shape[:-1]
        return v.numpy().reshape(shape), dv.numpy().reshape(shape), alpha.numpy().reshape(shape)

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """x (d,) -> f(x) (d,) in user units: Eq. (L2) in one compiled call
        (``lfd.learners.stable_kernel``), with the normalisation folded in."""
        from lfd.learners.stable_kernel import stable_point_fn

        module = self.module
        return stable_point_fn(numpy_layers(module.nominal), module.nominal.activation, module.flow.numpy_params(),
                               float(module.alpha), float(module.alpha_goal), module.v_goal, module.gain,
                               self.norm.goal, float(self.norm.scale))


def stability_certificate(field: StableNodeField) -> dict[str, Any]:
    """The analytic conditions of Eqs. (L1)-(L3) for ``field``, from its weights (no sampling).

    Returns a dict:

    - ``rate`` (1/s) and ``alpha`` = 2 rate: dV/dt <= -alpha(V) V <= -alpha V at every x (Eq. (L2));
      ``goal_rate`` (1/s): alpha(0) / 2, the rate at the goal; ``gain``: gamma;
    - ``s_lo``, ``s_hi``: phi's singular-value bounds (Eq. (F4)), so s_lo^2 |x_n|^2 <= V <= s_hi^2 |x_n|^2
      (V positive definite and radially unbounded when s_lo > 0);
    - ``overshoot``: s_hi / s_lo, the constant of |x(t) - goal| <= overshoot |x(0) - goal| e^(-rate t);
    - ``nominal_at_goal``: |fhat(goal)|, user units/s (0 up to round-off: fhat(0) = 0 by construction);
    - ``holds``: every condition holds (finite weights, alpha > 0, gamma >= 1, 0 < s_lo <= s_hi < inf).
    """
    module = field.module
    s_lo, s_hi = module.flow.singular_value_bounds()
    with torch.no_grad():
        at_goal = float(module.nominal(torch.zeros(1, field.dim, dtype=torch.float64)).norm()) * field.norm.scale
    finite = all(bool(torch.isfinite(p).all()) for p in module.parameters())
    alpha, alpha_goal = float(module.alpha), float(module.alpha_goal)
    holds = (finite and alpha > 0 and alpha_goal >= 0 and module.gain >= 1 and math.isfinite(s_hi)
             and 0 < s_lo <= s_hi and math.isfinite(at_goal))
    return {"rate": alpha / 2.0, "alpha": alpha, "goal_rate": (alpha + alpha_goal) / 2.0, "gain": module.gain,
            "s_lo": s_lo, "s_hi": s_hi, "overshoot": s_hi / s_lo if s_lo > 0 else math.inf,
            "nominal_at_goal": at_goal, "holds": bool(holds)}


class StableNodeLearner(Learner, name="stable_node", config=StableNodeConfig, field=StableNodeField):
    """The NODE's field corrected onto a learned Lyapunov function's decrease (Eqs. (L1)-(L4))."""

    @classmethod
    def parameter_count(cls, dim: int, config: StableNodeConfig) -> int:
        """The NODE's MLP, then phi's parameters (as ``ContractionLearner.parameter_count`` counts a pair)."""
        generator = 3 if dim == 3 else 2 * dim if dim >= 4 else 0
        per_pair = dim + 2 * SWIRL_COMPONENTS + generator + config.flow_hidden * (2 * dim + 1) + 2
        return NodeLearner.parameter_count(dim, config) + config.flow_layers * per_pair

    @classmethod
    def build(cls, dim: int, config: StableNodeConfig) -> StableNodeModule:
        """A fresh float64 module (phi = identity); fhat trains in the config's dtype."""
        return StableNodeModule(dim, config).double()

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: StableNodeConfig, progress: bool) -> dict[str, Any]:
        """Eq. (L4) on normalised ``demos``: fhat by the NODE's multiple shooting (its history), then
        phi (``lyapunov_loss``), then the segments where the correction acts (``active_segments`` of
        ``segments``) and, with ``finetune_iterations``, both trained on them (``finetune_loss``).
        Also ``rate`` (1/s) and the CPU seconds of the last two stages. Ctrl-C keeps what is done:
        the field is stable by construction with any phi."""
        module = cast(StableNodeModule, module)
        x_np, h_np = uniform_grid(demos, config.samples)
        if config.seg > x_np.shape[1]:
            raise ConfigError(f"stable_node: seg ({config.seg}) exceeds the {x_np.shape[1]} samples per demo")
        rate = config.rate if config.rate is not None else demo_rate(h_np, x_np.shape[1], config.rate_factor)
        module.unfreeze()
        module.set_rates(rate, config.goal_rate_factor)
        history = fit_segments(module.nominal, torch.tensor(x_np), torch.tensor(h_np), config, progress,
                               desc="stable_node")
        module.double()
        history["rate"] = rate
        if history["interrupted"] or history["stopped_nonfinite"]:
            return history
        x, h = torch.tensor(x_np), torch.tensor(h_np)
        try:
            with torch_threads(TRAIN_THREADS):
                cpu = time.process_time()
                history["lyapunov_loss"] = _fit_lyapunov(module, x, h, config)
                history["lyapunov_cpu_s"] = time.process_time() - cpu
                cpu = time.process_time()
                history.update(_finetune(module, x, h, config))
                history["finetune_cpu_s"] = time.process_time() - cpu
        except KeyboardInterrupt:
            history["interrupted"] = True
        return history


def _velocities(x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """Central differences of uniform-grid demos x (N, T, d) with steps h (N,): (N, T, d)."""
    return torch.gradient(x, dim=1)[0] / h[:, None, None]


def _away_from_goal(pts: torch.Tensor, vel: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The points (B, d) and velocities (B, d) farther than HINGE_GOAL_RADIUS from the goal (where
    V = 0 and d log V / dt says nothing)."""
    away = (pts * pts).sum(1) > HINGE_GOAL_RADIUS ** 2
    return pts[away], vel[away]


def _fit_lyapunov(module: StableNodeModule, x: torch.Tensor, h: torch.Tensor,
                  config: StableNodeConfig) -> list[float]:
    """Adam on phi alone, Eq. (L4): the hinge at the demo samples with the demos' velocities and
    fhat's, and along fhat's rollouts from the demo starts; x (N, T, d), h (N,).

    Every ``LYAPUNOV_CHECK`` steps from ``LYAPUNOV_MIN_STEPS`` on, counts the points of fhat's
    rollouts outside the goal's ball (V >= V_g) where the correction would act; stops at the first
    check that finds none, else after ``lyapunov_iterations`` steps with the checked iterate of
    fewest such points (then lowest loss). Stops at a non-finite loss. Returns the losses."""
    n, t, d = x.shape
    target = float(module.alpha) * (1.0 + config.margin)
    with torch.no_grad():
        roll = rk4_segments(module.nominal, x[:, 0], h[:, None], t).transpose(0, 1).reshape(-1, d)
        demo = x.reshape(-1, d)
        roll_vel = module.nominal(roll)
        pts, vel = _away_from_goal(torch.cat([demo, demo, roll]),
                                   torch.cat([_velocities(x, h).reshape(-1, d), module.nominal(demo), roll_vel]))
        keep = torch.linspace(0, len(pts) - 1, min(len(pts), config.lyapunov_points)).round().long()
        pts, vel = pts[keep], vel[keep]
    opt = Adam(module.flow.parameters(), lr=config.lyapunov_lr, lr_final=config.lyapunov_lr / 10,
               t_max=config.lyapunov_iterations)
    losses: list[float] = []
    best: tuple[int, float, dict[str, torch.Tensor]] | None = None
    for k in range(config.lyapunov_iterations + 1):
        p = module.flow.scaled()
        loss = decrease_hinge(module, pts, vel, target, p)
        value = float(loss.detach())
        if not math.isfinite(value):
            break
        losses.append(value)
        if k >= LYAPUNOV_MIN_STEPS and (k % LYAPUNOV_CHECK == 0 or k == config.lyapunov_iterations):
            acting = _acting_points(module, roll, roll_vel, p)
            if best is None or (acting, value) < best[:2]:
                best = (acting, value, {key: v.detach().clone() for key, v in module.flow.state_dict().items()})
            if acting == 0:
                break
        if k == config.lyapunov_iterations:
            break
        opt.zero_grad()
        loss.backward()
        opt.step()
    if best is not None:
        module.flow.load_state_dict(best[2])
    return losses


def _acting_points(module: StableNodeModule, x: torch.Tensor, v: torch.Tensor, params: dict[str, torch.Tensor]) -> int:
    """How many points x (B, d) moving at fhat's v (B, d) with V >= V_g the correction of Eq. (L2)
    acts on (grad V . v + alpha(V) V > 0)."""
    with torch.no_grad():
        vv, grad = module.lyapunov(x, {k: t.detach() for k, t in params.items()})
        acting = ((grad * v).sum(1) + module.decrease_rate(vv) * vv > 0) & (vv >= module.v_goal)
        return int(acting.sum())


def _active_segments(module: StableNodeModule, segments: Segments) -> torch.Tensor:
    """Indices of the shooting segments whose rollout through f differs from fhat's (where the
    correction of Eq. (L2) acts along the way)."""
    with torch.no_grad():
        p = module.flow.scaled()
        w, hb = segments.windows, segments.h
        corrected = rk4_segments(partial(module, params=p), w[0], hb, w.shape[0])
        nominal = rk4_segments(module.nominal, w[0], hb, w.shape[0])
        return torch.nonzero((corrected != nominal).any(2).any(0)).flatten()


def _finetune(module: StableNodeModule, x: torch.Tensor, h: torch.Tensor,
              config: StableNodeConfig) -> dict[str, Any]:
    """Multiple shooting through f (Eq. (L4)), fhat and phi jointly, on batches of the segments where
    the correction acts and as many drawn from all, plus ``hinge_weight`` x the hinge at the demos."""
    n, t, d = x.shape
    segments = Segments.of(x, h, min(config.seg, t))
    active = _active_segments(module, segments)
    out: dict[str, Any] = {"active_segments": int(len(active)), "segments": int(segments.h.shape[0])}
    if len(active) == 0 or config.finetune_iterations == 0:
        return out
    target = float(module.alpha) * (1.0 + config.margin)
    pts, vel = _away_from_goal(x.reshape(-1, d), _velocities(x, h).reshape(-1, d))
    opt = Adam(module.parameters(), lr=config.finetune_lr)
    gen = torch.Generator().manual_seed(int(torch.randint(0, 2**62, (1,)).item()))
    half = max(1, min(len(active), config.batch // 2 if config.batch else len(active)))
    losses = []
    for _ in range(config.finetune_iterations):
        pick = active[torch.randperm(len(active), generator=gen)[:half]]
        idx = torch.cat([pick, stratified_sample(segments.h.shape[0], half, gen)])
        w, hb = segments.windows[:, idx], segments.h[idx]
        p = module.flow.scaled()
        fit = torch.mean((rk4_segments(partial(module, params=p), w[0], hb, w.shape[0])[1:] - w[1:]) ** 2)
        loss = fit + config.hinge_weight * decrease_hinge(module, pts, vel, target, p)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(fit.detach()))
    out["finetune_loss"] = losses
    out["active_segments_after"] = int(len(_active_segments(module, segments)))
    return out
