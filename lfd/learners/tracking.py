"""Tracking learner: a field that contracts, at a user rate K, toward a learned reference motion, in phase.

The reference r(s) is the mean of the demos, each a cubic B-spline in its phase s in [0, 1]
(Eq. (T1)); with ``condition_start`` it is conditioned on the start x0 as a ProMP is (Eq. (T2): a
demo's start follows that demo's shape), the offset clamped to the demos' spread (Eq. (T2a)). The
state is (x, s), s(0) = 0; the phase stands in for the time of the paper's Eq. (10), so the field
stays autonomous:

    Eq. (T3): dx/dt = s_dot r'(s) + K (r(s) - x),
    Eq. (T4): ds/dt = h(|x - r(s)|) c(s) / T,   h(e) = 1 / (1 + (e / eps)^2),

c(s) stopping the phase at s = 1 (``PHASE_END``), h the phase stopping of DMPs (Eq. (T4b) around
obstacles). For ANY phase law the error e = x - r(s) obeys de/dt = -K e, Eq. (T5):
|x(t) - r(s(t))| = |x(0) - r(0)| exp(-K t), the paper's Eq. (18) with lambda = K and overshoot 1
(``check_tracking_contraction``). K is in 1/s. Derivations of Eqs. (T1)-(T5): docs/equations.md.

References
----------
Ijspeert, A. J., Nakanishi, J., Hoffmann, H., Pastor, P., Schaal, S. (2013). Dynamical movement
primitives: learning attractor models for motor behaviors. Neural Computation 25(2), 328-373.
doi:10.1162/NECO_a_00393
Paraschos, A., Daniel, C., Peters, J., Neumann, G. (2013). Probabilistic movement primitives. NeurIPS.
Wang, W., Slotine, J.-J. E. (2005). On partial contraction analysis for coupled nonlinear
oscillators. Biological Cybernetics 92, 38-53. doi:10.1007/s00422-004-0527-x
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from lfd import integrate
from lfd.demos import DemoSet
from lfd.field import ContractingField, PhasedRuns
from lfd.learners.base import Learner
from lfd.learners.tracking_reference import ALIGNMENTS, learn_reference
from lfd.validate import check_bools, check_ints, check_positive

DEFAULT_RATE = 3.0            # K, 1/s
ERROR_FLOOR = 1e-5            # normalised units: Eq. (T5) is checked as |e(t)| <= bound + floor (RK4 error)
PHASE_END = 0.01              # Eq. (T4): the phase slows linearly over its last 1% and stops at 1 exactly
CONTRACTION_PROPERTY = (
    "for any phase law s(t), the tracking error e = x - r(s) obeys de/dt = -K e, so "
    "|x(t) - r(s(t))| = |x(0) - r(0)| exp(-K t); for a given phase signal the x-subsystem "
    "dx/dt = s_dot r'(s) + K (r(s) - x) contracts at rate K in the Euclidean metric "
    "(Jacobian -K I, metric bounds a = b = 1); the phase reaches 1 and the goal r(1) is globally "
    "exponentially stable")


@dataclass
class TrackingConfig:
    """Options of the tracking learner.

    rate : K of Eq. (T3), 1/s, > 0 (the contraction rate toward the reference)
    knots : interior knots of each demo's cubic B-spline (capped at a third of its samples)
    table : phases at which the reference and r' are tabulated (cubic Hermite between them)
    phase_tolerance : eps of Eq. (T4), normalised units (fraction of the demos' size)
    phase_stop : use h of Eq. (T4) (else h = 1: a time-indexed reference)
    condition_start : condition the reference on the start, Eq. (T2)
    start_noise : sigma of Eq. (T2), normalised units
    start_radius : rho of Eq. (T2a), the Mahalanobis radius beyond which the offset is clamped (inf: never)
    end_at_goal : blend the reference onto the goal over the last ``END_BLEND`` of the phase, Eq. (T1b):
        r(1 | x0) is then the goal exactly, for every start (``lfd.train`` sets it for poses, whose
        demos end at different orientations)
    align : ``path`` (match the demos at equal fractions of their path length, timed by their mean
        time fraction, Eq. (T1c)) or ``time`` (at equal fractions of their duration, Eq. (T1))
    """

    rate: float = DEFAULT_RATE
    knots: int = 40
    table: int = 1024
    phase_tolerance: float = 0.3
    phase_stop: bool = True
    condition_start: bool = True
    start_noise: float = 0.02
    start_radius: float = 3.0
    end_at_goal: bool = False
    align: str = "path"

    def __post_init__(self) -> None:
        check_positive(self, ("rate", "phase_tolerance", "start_noise"), to_float=True)
        check_ints(self, (("knots", 1, None), ("table", 16, None)))
        check_bools(self, ("phase_stop", "condition_start", "end_at_goal"))
        check_positive(self, ("start_radius",), to_float=True, allow_inf=True)
        if self.align not in ALIGNMENTS:
            raise ValueError(f"align must be one of {', '.join(ALIGNMENTS)}, got {self.align!r}")


def _hermite_weights(w: Any) -> tuple[Any, Any, Any, Any, Any, Any, Any, Any]:
    """Cubic Hermite basis on [0, 1] at w and its derivatives in w (torch or numpy, elementwise)."""
    w2, w3 = w * w, w * w * w
    return (2 * w3 - 3 * w2 + 1, w3 - 2 * w2 + w, -2 * w3 + 3 * w2, w3 - w2,
            6 * w2 - 6 * w, 3 * w2 - 4 * w + 1, -6 * w2 + 6 * w, 3 * w2 - 2 * w)


def _hermite(values: torch.Tensor, slopes: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Cubic Hermite interpolation of a table: values, slopes, shape (M, ...), at s_j = j / (M - 1),
    evaluated at phases s, shape (B,), clamped to [0, 1]. Returns the value and its exact derivative
    in s, each shape (B, ...): C1 in s, so Eq. (T5) holds to the integrator's accuracy."""
    m = values.shape[0]
    hs = 1.0 / (m - 1)
    u = s.clamp(0.0, 1.0) * (m - 1)
    i0 = u.floor().long().clamp(0, m - 2)
    w = (u - i0.to(u.dtype)).reshape(-1, *([1] * (values.dim() - 1)))
    a0, b0, a1, b1, da0, db0, da1, db1 = _hermite_weights(w)
    p0, p1, m0, m1 = values[i0], values[i0 + 1], slopes[i0] * hs, slopes[i0 + 1] * hs
    return a0 * p0 + b0 * m0 + a1 * p1 + b1 * m1, (da0 * p0 + db0 * m0 + da1 * p1 + db1 * m1) / hs


class TrackingModule(nn.Module):
    """Eqs. (T1)-(T4) on normalised coordinates; the reference tables are buffers.

    ref, dref : (M, d) r(s_j) and r'(s_j) at s_j = j / (M - 1); gain, dgain : (M, d, d) G(s_j) and
    G'(s_j) of Eq. (T2) (zero without ``condition_start``); duration : T, s (scalar).
    """

    # the buffers registered in __init__ (nn.Module's __getattr__ is typed Tensor | Module)
    ref: torch.Tensor
    dref: torch.Tensor
    gain: torch.Tensor
    dgain: torch.Tensor
    duration: torch.Tensor
    start_precision: torch.Tensor

    def __init__(self, dim: int, config: TrackingConfig) -> None:
        super().__init__()
        self.dim = dim
        self.rate = config.rate
        self.eps = config.phase_tolerance
        self.phase_stop = config.phase_stop
        m = config.table
        self.register_buffer("ref", torch.zeros(m, dim))
        self.register_buffer("dref", torch.zeros(m, dim))
        self.register_buffer("gain", torch.zeros(m, dim, dim))
        self.register_buffer("dgain", torch.zeros(m, dim, dim))
        self.register_buffer("duration", torch.ones(()))
        self.register_buffer("start_precision", torch.zeros(dim, dim))     # P of Eq. (T2a)
        self.start_radius = config.start_radius

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any) -> None:
        # model files written before Eq. (T2a) have no P: zeros, i.e. the offset is never clamped
        state_dict.setdefault(prefix + "start_precision", torch.zeros_like(self.start_precision))
        super()._load_from_state_dict(state_dict, prefix, *args)

    def clamp_offset(self, delta: np.ndarray) -> np.ndarray:
        """Eq. (T2a): delta_c = delta min(1, rho / |delta|_P), shape (B, d) -> (B, d)."""
        prec = self.start_precision.numpy()
        m = np.sqrt(np.maximum(np.einsum("bi,ij,bj->b", delta, prec, delta), 0.0))
        with np.errstate(divide="ignore"):
            scale = np.minimum(1.0, self.start_radius / m)
        return delta * scale[:, None]

    def reference(self, s: torch.Tensor, delta: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """r(s | x0) and r'(s | x0) of Eqs. (T1)-(T2), each (B, d), at phases s, shape (B,),
        for start offsets delta = x0_n - r(0), shape (B, d) (None: the mean reference)."""
        r, dr = _hermite(self.ref, self.dref, s)
        if delta is not None:
            g, dg = _hermite(self.gain, self.dgain, s)
            r = r + (g @ delta.unsqueeze(-1)).squeeze(-1)
            dr = dr + (dg @ delta.unsqueeze(-1)).squeeze(-1)
        return r, dr

    def phase_rate(self, err: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """Eq. (T4): ds/dt, shape (B,), for tracking errors err, shape (B, d), at phases s, shape (B,)."""
        h = 1.0 / (1.0 + (err * err).sum(-1) / self.eps ** 2) if self.phase_stop else torch.ones_like(s)
        return h * ((1.0 - s) / PHASE_END).clamp(0.0, 1.0) / self.duration

    def velocity(self, x: torch.Tensor, s: torch.Tensor, delta: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """Eqs. (T3)-(T4): (dx/dt (B, d), ds/dt (B,)) at x, shape (B, d), and phases s, shape (B,)."""
        r, dr = self.reference(s, delta)
        sdot = self.phase_rate(x - r, s)
        return sdot.unsqueeze(-1) * dr + self.rate * (r - x), sdot

    def driven(self, x: torch.Tensor, s: torch.Tensor, sdot: torch.Tensor,
               delta: torch.Tensor | None = None) -> torch.Tensor:
        """The x-subsystem of Eq. (T3) for a given phase signal: s_dot r'(s) + K (r(s) - x), (B, d)."""
        r, dr = self.reference(s, delta)
        return sdot.unsqueeze(-1) * dr + self.rate * (r - x)

    def project(self, x: torch.Tensor) -> torch.Tensor:
        """The phase of the reference point nearest to each x, shape (B, d) -> (B,)."""
        j = torch.cdist(x, self.ref).argmin(dim=1)
        return j.to(x.dtype) / (self.ref.shape[0] - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """An autonomous view x -> dx/dt, (B, d) -> (B, d): Eq. (T3) at the phase of the nearest
        reference point (``project``). Rollouts never use it; it serves streamline plots."""
        with torch.no_grad():
            s = self.project(x)
        return self.velocity(x, s)[0]


class TrackingField(PhasedRuns, ContractingField):
    """A field contracting toward a learned reference motion, in phase (module docstring).

    The state is (x, s). ``rollout`` integrates both from s = 0 and returns x; ``velocity(x, s)``
    and ``phase_point_fn()`` serve closed loops that carry the phase themselves; ``__call__(x)``
    is the autonomous view of ``TrackingModule.forward`` (the phase of the nearest reference point).
    """

    module: TrackingModule

    # ---- the contraction certificate's constants (``rate`` is K of Eq. (T3), 1/s)
    @property
    def metric_bounds(self) -> tuple[float, float]:
        """(a, b) with a I <= M <= b I: the Euclidean metric, (1, 1), so b / a = 1 and the
        overshoot factor sqrt(b / a) of Eq. (18) is 1."""
        return 1.0, 1.0

    @property
    def lipschitz_bound(self) -> float:
        """A Lipschitz constant in x of the closed-loop velocity (Eqs. (T3)-(T4)), 1/s:
        K + max_s |r'(s)| max_e |h'(e)| / T with max |h'| = 3 sqrt(3) / (8 eps) (normalised units, so
        unit-free). The x-subsystem for a given phase signal has K alone. For the mean reference
        (a start-conditioned one adds G'(s) delta to r')."""
        mod = self.module
        if not mod.phase_stop:
            return self.rate
        r_max = float(torch.linalg.vector_norm(mod.dref, dim=1).max())
        return self.rate + r_max * 3.0 * math.sqrt(3.0) / (8.0 * mod.eps) / self.duration

    @property
    def contraction_property(self) -> str:
        """What holds (Eq. (T5)), in words."""
        return CONTRACTION_PROPERTY

    @property
    def duration(self) -> float:
        """T of Eq. (T1): the demos' mean duration, s."""
        return float(self.module.duration)

    @property
    def conditioned(self) -> bool:
        return bool(self.config.get("condition_start", False))

    # ---- phase API
    def initial_phase(self) -> float:
        """s(0) = 0."""
        return 0.0

    def start_offset(self, x0: np.ndarray) -> np.ndarray | None:
        """delta_c of Eq. (T2a) (delta = x0_n - r(0), clamped), normalised units, shape (B, d), or None
        if unconditioned."""
        if not self.conditioned:
            return None
        return self.module.clamp_offset(self.norm.to_norm(np.atleast_2d(x0)) - self.module.ref[0].numpy())

    def reference(self, s: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """r(s) (or r(s | x0)) in user units: s : array, shape (P,) -> shape (P, d)."""
        st = torch.tensor(np.atleast_1d(np.asarray(s, dtype=np.float64)))
        delta = None
        if x0 is not None and self.conditioned:
            off = cast(np.ndarray, self.start_offset(x0))
            delta = torch.tensor(np.broadcast_to(off[0], (len(st), self.dim)).copy())
        with torch.no_grad():
            return self.norm.from_norm(self.module.reference(st, delta)[0].numpy())

    def velocity(self, x: np.ndarray, s: np.ndarray | float, x0: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (T3)-(T4) in user units: x : (B, d) or (d,), s : (B,) or scalar; x0 : the run's start
        (used with ``condition_start``). Returns (dx/dt, same shape as x; ds/dt, shape (B,) or scalar)."""
        x = np.asarray(x, dtype=np.float64)
        single = x.ndim == 1
        xb = np.atleast_2d(x)
        sb = np.broadcast_to(np.asarray(s, dtype=np.float64), (len(xb),)).copy()
        delta = None
        if x0 is not None and self.conditioned:
            delta = torch.tensor(np.broadcast_to(cast(np.ndarray, self.start_offset(x0))[0], xb.shape).copy())
        with torch.no_grad():
            v, sd = self.module.velocity(torch.tensor(self.norm.to_norm(xb)), torch.tensor(sb), delta)
        va, sda = v.numpy() * self.norm.scale, sd.numpy()
        return (va[0], float(sda[0])) if single else (va, sda)  # type: ignore[return-value]

    def phase_point_fn(self, x0: np.ndarray | None = None, clock_weight: Callable[[np.ndarray], float] | None = None
                       ) -> Callable[[np.ndarray, float], tuple[np.ndarray, float]]:
        """A fast evaluator (x (d,), s) -> (dx/dt (d,), ds/dt) in user units for control loops
        (Eqs. (T3)-(T4); with ``condition_start``, for the run that started at x0): one compiled
        call (``lfd.learners.tracking_kernel``), the same floats as ``velocity`` up to round-off
        (tests/test_tracking.py).

        ``clock_weight``: x (d,) -> omega in [0, 1]; the phase stopping h of Eq. (T4) is then
        blended toward the clock, h + omega (1 - h) (Eq. (T4b) of docs/equations.md: an obstacle
        wrapper passes its detour weight, so the phase keeps its pace while the tool detours),
        the weight called in Python, then the same compiled call. None (the default): Eq. (T4) as is."""
        mod = self.module
        ref, dref = mod.ref.numpy().copy(), mod.dref.numpy().copy()
        if x0 is not None and self.conditioned:
            delta = cast(np.ndarray, self.start_offset(x0))[0]
            ref = ref + mod.gain.numpy() @ delta
            dref = dref + mod.dgain.numpy() @ delta
        goal, sc, k, eps2 = self.norm.goal.copy(), float(self.norm.scale), mod.rate, mod.eps ** 2
        inv_t, stop = 1.0 / float(mod.duration), mod.phase_stop
        from lfd.learners.tracking_kernel import phase_point_fn  # here: ``import lfd`` does not import numba

        return phase_point_fn(ref, dref, goal, sc, k, eps2, inv_t, stop, PHASE_END, clock_weight)

    # ---- rollouts integrate (x, s) jointly
    def rollout_with_phase(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1,
                           s0: np.ndarray | float = 0.0, start: np.ndarray | None = None,
                           step: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Integrate Eqs. (T3)-(T4) from x0, shape (B, d) or (d,), and phase s0 (default 0) over t, shape (T,).

        ``start`` : the run's start, shape (B, d) or (d,), for Eq. (T2) (default x0; give it when
        continuing a run, e.g. after a kick). Returns x, shape (B, T, d) (or (T, d)), user units,
        and s, shape (B, T) (or (T,)). Fixed-step solvers take ``substeps`` steps per interval of t,
        or steps of ``step`` seconds if given (then outputs are interpolated: use it for irregular t).
        ``rk4`` with one substep on at most ``lfd.integrate.POINTWISE_MAX`` starts runs each start through the
        compiled ``phase_point_fn`` (``lfd.integrate.rk38_phase_grid``: torchdiffeq's steps to round-off).
        """
        x0 = np.asarray(x0, dtype=np.float64)
        single = x0.ndim == 1
        xb = np.atleast_2d(x0)
        t = np.asarray(t, dtype=np.float64)
        if method == "rk4" and substeps == 1 and len(xb) <= integrate.POINTWISE_MAX:   # the compiled point, per start
            starts = np.broadcast_to(xb if start is None else np.atleast_2d(start), xb.shape)
            phases = np.broadcast_to(np.asarray(s0, dtype=np.float64), (len(xb),))
            runs = [integrate.rk38_phase_grid(self.phase_point_fn(p), x, t, step, float(s))
                    for x, p, s in zip(xb, starts, phases)]
            xa, sa = np.stack([r[0] for r in runs]), np.stack([r[1] for r in runs])
            return (xa[0], sa[0]) if single else (xa, sa)
        options = integrate.odeint_kwargs(method, step=step, substeps=substeps, t=t,
                                          interp=None if step is None else "cubic").get("options")
        delta = self.start_offset(np.broadcast_to(xb if start is None else start, xb.shape))
        sb = torch.tensor(np.broadcast_to(np.asarray(s0, dtype=np.float64), (len(xb),)).copy())
        with torch.no_grad():
            xs, ss = self._rollout_torch(torch.tensor(xb), torch.tensor(t),
                                         None if delta is None else torch.tensor(delta), method, options, sb)
        xa, sa = xs.numpy(), ss.numpy()
        return (xa[0], sa[0]) if single else (xa, sa)

    def _rollout_torch(self, x0: torch.Tensor, t: torch.Tensor, delta: torch.Tensor | None, method: str,
                       options: dict[str, Any] | None, s0: torch.Tensor | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """(x (B, T, d) user units, s (B, T)) from x0 (B, d) user units and phases s0 (B,) (default 0)."""
        d = self.dim
        s_init = x0.new_zeros(len(x0), 1) if s0 is None else s0.reshape(-1, 1).to(x0.dtype)
        y0 = torch.cat([self.norm.to_norm_torch(x0), s_init], dim=1)

        def rhs(_t: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
            v, sd = self.module.velocity(y[:, :d], y[:, d], delta)
            return torch.cat([v, sd.unsqueeze(-1)], dim=1)

        y = integrate.solve(rhs, y0, t - t[0], method, options)           # (T, B, d + 1)
        return self.norm.from_norm_torch(y[..., :d]).permute(1, 0, 2), y[..., d].permute(1, 0)

    def rollout_torch(self, x0: torch.Tensor, t: torch.Tensor, method: str = "rk4",
                      options: dict[str, Any] | None = None) -> torch.Tensor:
        """Integrate (x, s) from x0, shape (B, d), s = 0, over t, shape (T,): x, shape (B, T, d)."""
        delta = self.start_offset(x0.detach().numpy())
        return self._rollout_torch(x0, t, None if delta is None else torch.tensor(delta), method, options)[0]

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1) -> np.ndarray:
        """Integrate (x, s) from x0, shape (B, d) or (d,), and s = 0 over t, shape (T,); returns x,
        shape (B, T, d) (or (T, d)) in user units (``rollout_with_phase`` also returns s)."""
        return self.rollout_with_phase(x0, t, method, substeps)[0]

    def single_point_evaluator(self) -> Callable[[np.ndarray], np.ndarray]:
        """The autonomous view (``TrackingModule.forward``) for one point, x (d,) -> dx/dt (d,), user
        units, in one compiled call (``lfd.learners.tracking_kernel``): Eq. (T3) at the phase of the
        nearest tabulated reference point."""
        from lfd.learners.tracking_kernel import nearest_point_fn  # here: ``import lfd`` does not import numba

        mod = self.module
        return nearest_point_fn(mod.ref.numpy(), mod.dref.numpy(), self.norm.goal, float(self.norm.scale), mod.rate,
                                mod.eps ** 2, 1.0 / self.duration, mod.phase_stop, PHASE_END)


# ---------------------------------------------------------------- learning: lfd.learners.tracking_reference

class TrackingLearner(Learner, name="tracking", config=TrackingConfig, field=TrackingField):
    """The mean phase-indexed demo as the reference, tracked at rate K with phase stopping."""

    @classmethod
    def parameter_count(cls, dim: int, config: TrackingConfig) -> int:
        """0: the module holds its tables as buffers, filled in closed form (``fit``)."""
        return 0

    @classmethod
    def build(cls, dim: int, config: TrackingConfig) -> TrackingModule:
        """An empty float64 module (all-zero reference tables)."""
        return TrackingModule(dim, config).double()

    @classmethod
    def fit(cls, module: nn.Module, demos: DemoSet, config: TrackingConfig, progress: bool) -> dict[str, Any]:
        """Fill the tables of Eqs. (T1)-(T2) from the normalised ``demos`` (closed form, no iterations;
        ``lfd.learners.tracking_reference.learn_reference``).

        History: ``loss`` = [mean squared distance of the demo samples from the reference at their
        phase, normalised units^2], ``spline_rmse`` (each demo from its own spline), ``spread``
        (mean squared distance of the demos from the reference: the floor of the reference's RMSE).
        """
        assert isinstance(module, TrackingModule)
        tables = learn_reference(demos, config.knots, config.table, config.condition_start, config.start_noise,
                                 config.end_at_goal, config.align)
        with torch.no_grad():
            module.ref.copy_(torch.tensor(tables.ref))
            module.dref.copy_(torch.tensor(tables.dref))
            module.gain.copy_(torch.tensor(tables.gain))
            module.dgain.copy_(torch.tensor(tables.dgain))
            module.start_precision.copy_(torch.tensor(tables.precision))
            module.duration.fill_(float(np.mean(demos.t[:, -1] - demos.t[:, 0])))
        # residuals at the demo samples
        phases, d = np.linspace(0.0, 1.0, config.table), demos.dim
        s_all = (demos.t - demos.t[:, :1]) / (demos.t[:, -1:] - demos.t[:, :1])
        r_at = np.stack([np.stack([np.interp(s, phases, tables.ref[:, j]) for j in range(d)], -1) for s in s_all])
        own = np.stack([b(s) for b, s in zip(tables.splines, s_all)])
        loss = float(np.mean(np.sum((demos.x - r_at) ** 2, -1)))
        return {"loss": [loss], "spline_rmse": float(np.sqrt(np.mean(np.sum((demos.x - own) ** 2, -1)))),
                "spread": loss, "iterations": 1, "interrupted": False, "stopped_nonfinite": False}


# ---------------------------------------------------------------- numerical check of Eq. (T5)

def _batch_jacobian(f: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """d f_b / d x_b for a row-wise map f : (B, d) -> (B, d), by reverse mode, one pass per output
    coordinate (rows do not interact, so the gradient of sum_b f_b,i is row i of each Jacobian).
    Returns shape (B, d, d)."""
    x = x.detach().requires_grad_(True)
    y = f(x)
    rows = [torch.autograd.grad(y[:, i].sum(), x, retain_graph=i < y.shape[1] - 1)[0] for i in range(y.shape[1])]
    return torch.stack(rows, dim=1).detach()


def check_tracking_contraction(field: TrackingField, lo: np.ndarray | None = None, hi: np.ndarray | None = None,
                               n_points: int = 20_000, n_starts: int = 32, horizon: float | None = None,
                               seed: int = 0, tolerance: float = 1e-6, steps: int = 600) -> dict[str, Any]:
    """Check the stated contraction property of a tracking field numerically on a box.

    1. Jacobian: at ``n_points`` random (x, s, s_dot), x ~ U(lo, hi), s ~ U(0, 1), s_dot ~ U(0, 2/T),
       the x-subsystem of Eq. (T3) (phase signal held) must satisfy max eig(sym(df/dx)) <= -K within
       ``tolerance`` (relative): Eq. (17) with M = I, lambda = K, by reverse-mode autodiff.
    2. Error decay: from ``n_starts`` random starts, the closed-loop (x, s) rollout (Eqs. (T3)-(T4),
       RK4, 2 substeps per step, ``steps`` steps over ``horizon``, default 1.5 T) must keep
       |x(t) - r(s(t))| <= |x(0) - r(0)| exp(-K t) + ERROR_FLOOR (normalised units), Eq. (T5).

    lo, hi : array, shape (d,), user units; default the training demos' box (``field.demo_box``)
    grown by 50%. Returns a dict: ``certified`` (bool), ``rate`` K, ``bound`` -K, ``worst_eig``,
    ``worst_error_ratio`` and ``worst_error_excess`` (normalised units), ``coupled_worst_eig`` (the
    closed-loop x-Jacobian with the phase coupling of Eq. (T4), reported, not checked), the field's
    ``property``, ``metric_bounds`` [a, b], ``condition_number`` b/a, ``lipschitz_bound``,
    ``subsystem_lipschitz`` (K), ``n_points``, ``n_starts`` and ``box`` [lo, hi] (user units).
    """
    if lo is None or hi is None:
        if field.demo_box is None:
            raise ValueError("the field stores no demo box: give lo and hi")
        blo, bhi = field.demo_box
        pad = (bhi - blo) * 0.25
        lo, hi = blo - pad, bhi + pad
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    mod, k, d = field.module, field.rate, field.dim
    rng = np.random.default_rng(seed)
    xn = torch.tensor(field.norm.to_norm(rng.uniform(lo, hi, size=(n_points, d))))
    s = torch.tensor(rng.uniform(0.0, 1.0, n_points))
    sdot = torch.tensor(rng.uniform(0.0, 2.0 / field.duration, n_points))
    jac = _batch_jacobian(lambda x: mod.driven(x, s, sdot), xn)                        # (P, d, d)
    worst = float(torch.linalg.eigvalsh((jac + jac.transpose(1, 2)) / 2).max())
    jc = _batch_jacobian(lambda x: mod.velocity(x, s)[0], xn)
    coupled_worst = float(torch.linalg.eigvalsh((jc + jc.transpose(1, 2)) / 2).max())
    # error decay from random starts, Eq. (T5), above the integrator's floor
    x0 = rng.uniform(lo, hi, size=(n_starts, d))
    horizon = horizon if horizon is not None else 1.5 * field.duration
    t = np.linspace(0.0, horizon, steps + 1)
    xs, ss = field.rollout_with_phase(x0, t, method="rk4", substeps=2)
    r = np.stack([field.reference(si, x0i) for si, x0i in zip(ss, x0)])            # (B, T, d)
    e = np.linalg.norm(xs - r, axis=-1) / field.norm.scale
    bound = e[:, :1] * np.exp(-k * t)
    above = bound[:, 1:] > 100 * ERROR_FLOOR
    ratio = float(np.max(e[:, 1:][above] / bound[:, 1:][above])) if above.any() else 1.0
    excess = float(np.max(e[:, 1:] - bound[:, 1:]))
    certified = worst <= -k + tolerance * max(1.0, k) and excess <= ERROR_FLOOR
    a, b = field.metric_bounds
    return {"property": field.contraction_property, "rate": k, "bound": -k, "worst_eig": worst,
            "certified": bool(certified), "metric_bounds": [a, b], "condition_number": b / a,
            "lipschitz_bound": field.lipschitz_bound, "subsystem_lipschitz": k,
            "worst_error_ratio": ratio, "worst_error_excess": excess,
            "coupled_worst_eig": coupled_worst, "n_points": n_points, "n_starts": n_starts,
            "box": [lo.tolist(), hi.tolist()]}
