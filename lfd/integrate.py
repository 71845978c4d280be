"""The one place that integrates a velocity field: a solver table and the integrators that use it.

Every rollout of the package goes through this module:

- ``SOLVERS``: the torchdiffeq methods we accept, each marked fixed-step or adaptive (as
  torchdiffeq keeps its own ``SOLVERS``), with ``FIXED_STEP`` and ``ADAPTIVE`` derived from it.
- ``odeint_kwargs``: ``torchdiffeq.odeint``'s keyword arguments for a method, a step or ``substeps``
  steps per output interval (fixed-step) or tolerances (adaptive); NODE training uses it too.
- ``solve``: one batched torchdiffeq solve of dy/dt = f(t, y); ``rollout`` wraps it for a field in
  user units, ``rollout_sample_units`` for demos on different uniform time grids at once.
- ``rk38_grid`` and ``rk38_phase_grid``: torchdiffeq's ``rk4`` on ONE point in numpy, through a
  field's compiled single-point path, for rollouts of a few starts (``POINTWISE_MAX``).
- ``rk4`` and ``rk4_phase``: classic Runge-Kutta on ONE point in numpy (no torch), for control loops
  that call a field's ``single_point_evaluator`` thousands of times; ``rk4_step`` is their step, shared with the
  obstacle-avoiding field's batched numpy rollout.

A field with a closed-form flow (``ContractionField.closed_form_rollout``, Eq. (C4)) needs no solver.

The solvers discretise the paper's Eq. (5); torchdiffeq's ``rk4`` is the 3/8-rule variant, ``rk4``
here the classic scheme of the paper's Eq. (8) (both of order 4).

References
----------
Chen, R. T. Q., Rubanova, Y., Bettencourt, J., Duvenaud, D. (2018). Neural ordinary differential
equations. NeurIPS. arXiv:1806.07366
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lfd.threads import torch_threads

if TYPE_CHECKING:
    import torch

    from lfd.normalization import Normalization


class TorchField(Protocol):
    """What the batched integrators need of a field (``lfd.field.VelocityField`` has it): its
    normalised torch module, its normalisation and its own torch rollout."""

    module: torch.nn.Module
    norm: Normalization

    def rollout_torch(self, x0: torch.Tensor, t: torch.Tensor, method: str = "rk4",
                      options: dict[str, Any] | None = None) -> torch.Tensor:
        """Integrate from x0, shape (B, d), over t, shape (T,): (B, T, d), user units."""
        ...

__all__ = [
    "ADAPTIVE", "FIXED_STEP", "POINTWISE_MAX", "SOLVERS", "Solver", "check_method", "odeint_kwargs", "rk4",
    "rk4_phase", "rk38_grid", "rk38_phase_grid", "rk4_step", "rollout", "rollout_sample_units", "solve",
]

POINTWISE_MAX = 32   #: rk4 rollouts of up to this many starts go point by point (``rk38_grid``)


@dataclass(frozen=True)
class Solver:
    """One torchdiffeq method.

    Attributes
    ----------
    order : int
        Order of accuracy.
    adaptive : bool
        True: error-controlled steps (``rtol``, ``atol``); False: fixed steps, on the output grid
        or of a given ``step_size``.
    one_step : bool
        A one-step (Runge-Kutta) method: its steps depend only on the step size, so a time
        rescaling tau = t / h with step 1 in tau takes exactly the steps of step h in t
        (``rollout_sample_units`` relies on it). False for the Adams multistep methods.
    """

    order: int
    adaptive: bool
    one_step: bool = True


SOLVERS: dict[str, Solver] = {
    "euler": Solver(1, adaptive=False),
    "midpoint": Solver(2, adaptive=False),
    "heun2": Solver(2, adaptive=False),
    "heun3": Solver(3, adaptive=False),
    "rk4": Solver(4, adaptive=False),
    # the Adams methods of torchdiffeq 0.2.5 diverge on a stable focus at every step we tried
    # (tests/test_integrate.py): accepted for completeness, not recommended
    "explicit_adams": Solver(4, adaptive=False, one_step=False),
    "implicit_adams": Solver(4, adaptive=False, one_step=False),
    "dopri5": Solver(5, adaptive=True),
    "dopri8": Solver(8, adaptive=True),
    "bosh3": Solver(3, adaptive=True),
    "fehlberg2": Solver(2, adaptive=True),
    "adaptive_heun": Solver(2, adaptive=True),
}
FIXED_STEP: tuple[str, ...] = tuple(name for name, s in SOLVERS.items() if not s.adaptive)
ADAPTIVE: tuple[str, ...] = tuple(name for name, s in SOLVERS.items() if s.adaptive)


def check_method(method: str) -> Solver:
    """The ``SOLVERS`` entry of ``method``; ValueError naming the known methods otherwise."""
    try:
        return SOLVERS[method]
    except (KeyError, TypeError):
        raise ValueError(f"unknown solver '{method}'; known: {', '.join(SOLVERS)}") from None


def odeint_kwargs(method: str, *, step: float | None = None, substeps: int = 1,
                  t: np.ndarray | None = None, rtol: float | None = None, atol: float | None = None,
                  max_steps: int | None = None, interp: str | None = None) -> dict[str, Any]:
    """Keyword arguments of ``torchdiffeq.odeint`` for ``method``.

    Parameters
    ----------
    method : str
        A key of ``SOLVERS``.
    step : float, optional
        Fixed-step methods: the step size (outputs are then interpolated, with ``interp``).
    substeps : int
        Fixed-step methods without ``step``: steps per interval of the output grid t, shape (T,);
        1 (the default) steps on t itself, and more take steps of min(diff(t)) / substeps.
    t : array, shape (T,), optional
        The output times; needed for ``substeps`` > 1.
    rtol, atol : float, optional
        Adaptive methods: tolerances (torchdiffeq's defaults if None).
    max_steps : int, optional
        Adaptive methods: the most steps before torchdiffeq gives up (AssertionError).
    interp : str, optional
        Fixed-step methods with a step: ``linear`` (torchdiffeq's default) or ``cubic``.

    Returns
    -------
    dict
        ``method`` and, where set, ``options``, ``rtol`` and ``atol``.

    Raises
    ------
    ValueError
        For an unknown method, ``substeps`` < 1, or fixed-step options with an adaptive method
        (and the reverse): an option a solver would ignore is refused, never dropped.
    """
    solver = check_method(method)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
    if solver.adaptive:
        if step is not None or substeps > 1 or interp is not None:
            raise ValueError(f"'{method}' is adaptive: step, substeps and interp apply to fixed-step "
                             f"solvers only ({', '.join(FIXED_STEP)})")
        kwargs = {k: v for k, v in (("rtol", rtol), ("atol", atol)) if v is not None}
        options = {} if max_steps is None else {"max_num_steps": max_steps}
    else:
        if rtol is not None or atol is not None or max_steps is not None:
            raise ValueError(f"'{method}' takes fixed steps: rtol, atol and max_steps apply to adaptive "
                             f"solvers only ({', '.join(ADAPTIVE)})")
        kwargs, options = {}, _fixed_step_options(step, substeps, t, interp)
    return {"method": method, **({"options": options} if options else {}), **kwargs}


def _fixed_step_options(step: float | None, substeps: int, t: np.ndarray | None,
                        interp: str | None) -> dict[str, Any]:
    """torchdiffeq's options of a fixed-step solver (see ``odeint_kwargs``); {} to step on t."""
    if step is None and substeps > 1:
        if t is None or len(t) < 2:
            raise ValueError("substeps > 1 needs the output times t (at least two)")
        step = float(np.min(np.diff(np.asarray(t, dtype=np.float64)))) / substeps
    if step is None:
        return {}
    return {"step_size": float(step), **({} if interp is None else {"interp": interp})}


def solve(f: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], y0: torch.Tensor, t: torch.Tensor,
          method: str = "rk4", options: dict[str, Any] | None = None, rtol: float | None = None,
          atol: float | None = None) -> torch.Tensor:
    """One batched solve of dy/dt = f(t, y) with torchdiffeq: the paper's Eq. (5), forward.

    Parameters
    ----------
    f : callable
        (t, y) -> dy/dt, y of shape (B, n).
    y0 : tensor, shape (B, n)
        Initial states.
    t : tensor, shape (T,)
        Output times, increasing; y(t[0]) = y0.
    method, options, rtol, atol
        torchdiffeq's arguments, as built by ``odeint_kwargs``; ``method`` must be in ``SOLVERS``.

    Returns
    -------
    tensor, shape (T, B, n)
        y at the output times (torchdiffeq's layout: time first). Differentiable unless called
        under ``torch.no_grad``.
    """
    from torchdiffeq import odeint

    check_method(method)
    tol = {k: v for k, v in (("rtol", rtol), ("atol", atol)) if v is not None}
    return odeint(f, y0, t, method=method, options=options, **tol)


def rollout(field: TorchField, x0: np.ndarray, t: np.ndarray, method: str = "rk4",
            substeps: int = 1, step: float | None = None) -> np.ndarray:
    """Roll a field out in user units: what ``VelocityField.rollout`` does.

    The field integrates in normalised units (``field.rollout_torch``, which calls ``solve``).

    Parameters
    ----------
    field : TorchField
        The field (a ``VelocityField``); a subclass may override ``rollout_torch`` (e.g. to carry a phase state).
    x0 : array, shape (B, d) or (d,)
        Starts, user units.
    t : array, shape (T,)
        Output times, s.
    method : str
        A key of ``SOLVERS``.
    substeps : int
        Fixed-step methods: steps per interval of t (see ``odeint_kwargs``); refused (ValueError)
        with an adaptive method.
    step : float, optional
        Fixed-step methods: the step size, s, instead of ``substeps`` (outputs interpolated).

    Returns
    -------
    array, shape (B, T, d) (or (T, d) for one start)
        The trajectories, user units.
    """
    import torch

    x0 = np.asarray(x0, dtype=np.float64)
    single = x0.ndim == 1
    t = np.asarray(t, dtype=np.float64)
    kw = odeint_kwargs(method, step=step, substeps=substeps, t=t)
    with torch.no_grad(), torch_threads(1):   # small batches: one thread is fastest (lfd.threads)
        y = field.rollout_torch(torch.tensor(np.atleast_2d(x0)), torch.tensor(t), method,
                                kw.get("options")).numpy()
    return y[0] if single else y


def rollout_sample_units(field: TorchField, x0: np.ndarray, h: np.ndarray, n: int,
                         method: str = "rk4") -> np.ndarray:
    """Roll a field out from N starts, each on its own uniform time grid, in one batch.

    In sample units tau = (t - t_0) / h_i the field obeys dx_n/dtau = h_i f_n(x_n); a one-step
    fixed-step solver with step 1 in tau takes exactly the steps it would take with step h_i in t.

    Parameters
    ----------
    field : TorchField
        A field that keeps the base ``VelocityField.rollout`` (no extra state).
    x0 : array, shape (N, d)
        Starts, user units.
    h : array, shape (N, 1)
        The sample interval of each start's grid, s.
    n : int
        Samples per trajectory (the starts included).
    method : str
        A fixed-step one-step method of ``SOLVERS``.

    Returns
    -------
    array, shape (N, n, d)
        x_i at t_0 + k h_i, k = 0 .. n-1, user units.
    """
    import torch

    solver = check_method(method)
    if solver.adaptive or not solver.one_step:
        raise ValueError(f"rollout_sample_units needs a one-step fixed-step solver, not '{method}'")
    hs = torch.tensor(np.ascontiguousarray(h, dtype=np.float64))
    xn0 = field.norm.to_norm_torch(torch.tensor(np.asarray(x0, dtype=np.float64)))
    with torch.no_grad(), torch_threads(1):
        yn = solve(lambda _tau, y: field.module(y) * hs, xn0, torch.arange(n, dtype=torch.float64),
                   method=method)
    return field.norm.from_norm_torch(yn).permute(1, 0, 2).numpy()


# ---- numpy, one point (or one batch): classic RK4, the paper's Eq. (8)

def rk4_step(f: Callable[[np.ndarray, float], np.ndarray], x: np.ndarray, t: float, h: float) -> np.ndarray:
    """One classic RK4 step of dx/dt = f(x, t), the paper's Eq. (8).

    x_{k+1} = x_k + h/6 (k1 + 2 k2 + 2 k3 + k4), k1 = f(x_k, t), k2 = f(x_k + h/2 k1, t + h/2),
    k3 = f(x_k + h/2 k2, t + h/2), k4 = f(x_k + h k3, t + h).

    Parameters
    ----------
    f : callable
        (x, t) -> dx/dt, same shape as x.
    x : array, shape (d,) or (B, d)
        The state at time t.
    t : float
        Time of x, s.
    h : float
        Step, s.

    Returns
    -------
    array, same shape as x
        The state at t + h.
    """
    k1 = f(x, t)
    k2 = f(x + 0.5 * h * k1, t + 0.5 * h)
    k3 = f(x + 0.5 * h * k2, t + 0.5 * h)
    k4 = f(x + h * k3, t + h)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rk4(f: Callable[..., np.ndarray], x0: np.ndarray, t: np.ndarray,
        substeps: int = 1, timed: bool = False) -> np.ndarray:
    """Classic RK4 (Eq. (8)) of dx/dt = f(x) (or of dx/dt = f(x, t) when ``timed``) on one point, in numpy.

    For a field's single-point evaluator (``VelocityField.single_point_evaluator``): over
    thousands of control steps it is far faster than the batched torch ``rollout``.

    Parameters
    ----------
    f : callable
        x, shape (d,) -> dx/dt, shape (d,); with ``timed``, (x, t [s]) -> dx/dt (a time-varying
        field: a moving goal, ``lfd.goal``, or moving obstacles, ``lfd.obstacles``).
    x0 : array, shape (d,)
        The start.
    t : array, shape (T,)
        Output times, s; ``substeps`` equal steps per interval.
    substeps : int
        Steps per interval of t, >= 1.
    timed : bool
        Whether f takes the time as its second argument.

    Returns
    -------
    array, shape (T, d)
        x at the output times (x0 first).
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    t = np.asarray(t, dtype=np.float64)

    def g(y: np.ndarray, _t: float) -> np.ndarray:
        return f(y)
    step_fn = f if timed else g

    out = np.empty((len(t), len(x)))
    out[0] = x
    for k in range(1, len(t)):
        h = (t[k] - t[k - 1]) / substeps
        for j in range(substeps):
            x = rk4_step(step_fn, x, t[k - 1] + j * h, h)
        out[k] = x
    return out


def rk4_phase(fn: Callable[[np.ndarray, float], tuple[np.ndarray, float]], x0: np.ndarray,
              t: np.ndarray, substeps: int = 1, s0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Classic RK4 (Eq. (8)) of a phase field (x, s) -> (dx/dt, ds/dt) on one point, in numpy.

    The phase of ``lfd.learners.tracking`` (Eqs. (T3)-(T4)) stops at 1: s is clipped to at most 1
    after each step.

    Parameters
    ----------
    fn : callable
        (x (d,), s float) -> (dx/dt (d,), ds/dt float), e.g. a tracking field's ``phase_point_fn``.
    x0 : array, shape (d,)
        The start.
    t : array, shape (T,)
        Output times, s.
    substeps : int
        Steps per interval of t, >= 1.
    s0 : float
        The initial phase.

    Returns
    -------
    x : array, shape (T, d)
    s : array, shape (T,)
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    t = np.asarray(t, dtype=np.float64)
    s = float(s0)
    xs, ss = np.empty((len(t), len(x))), np.empty(len(t))
    xs[0], ss[0] = x, s
    for k in range(1, len(t)):
        h = (t[k] - t[k - 1]) / substeps
        for _ in range(substeps):
            v1, s1 = fn(x, s)
            v2, s2 = fn(x + 0.5 * h * v1, s + 0.5 * h * s1)
            v3, s3 = fn(x + 0.5 * h * v2, s + 0.5 * h * s2)
            v4, s4 = fn(x + h * v3, s + h * s3)
            x = x + (h / 6.0) * (v1 + 2.0 * v2 + 2.0 * v3 + v4)
            s = min(1.0, s + (h / 6.0) * (s1 + 2.0 * s2 + 2.0 * s3 + s4))
        xs[k], ss[k] = x, s
    return xs, ss


def rk38_grid(f: Callable[[np.ndarray], np.ndarray], y0: np.ndarray, t: np.ndarray,
              step: float | None = None) -> np.ndarray:
    """torchdiffeq's ``rk4`` (the 3/8 rule) of dy/dt = f(y) on one point, in numpy: the same steps,
    grid and output interpolation as ``solve`` with ``odeint_kwargs("rk4", step=step,
    interp="cubic")`` (``step`` None: steps on t itself), so the two agree to round-off.

    f : y (n,) -> dy/dt (n,), a fresh array (a field's ``single_point_evaluator``); y0 : (n,);
    t : (T,) increasing output times, s. Returns y (T, n); non-finite values pass through silently,
    as in the torch path.
    """
    t = np.asarray(t, dtype=np.float64)
    if step is None:
        grid = t
    else:
        grid = np.arange(int(math.ceil((t[-1] - t[0]) / step + 1))) * step + t[0]
        grid[-1] = t[-1]
    y0 = np.array(y0, dtype=np.float64)
    out = np.empty((len(t), len(y0)))
    out[0] = y0
    j, third = 1, 1.0 / 3.0
    with np.errstate(all="ignore"):
        for t0, t1 in zip(grid[:-1], grid[1:]):
            dt = t1 - t0
            k1 = f(y0)
            k2 = f(y0 + dt * k1 * third)
            k3 = f(y0 + dt * (k2 - k1 * third))
            k4 = f(y0 + dt * (k1 - k2 + k3))
            y1 = y0 + (k1 + 3.0 * (k2 + k3) + k4) * dt * 0.125
            if j < len(t) and t1 >= t[j]:
                f1 = f(y1) if step is not None else None
                while j < len(t) and t1 >= t[j]:
                    if f1 is None:
                        out[j] = y1
                    else:      # torchdiffeq's cubic Hermite interpolation between the grid points
                        h = (t[j] - t0) / dt
                        out[j] = ((1 + 2 * h) * (1 - h) * (1 - h) * y0 + h * (1 - h) * (1 - h) * dt * k1
                                  + h * h * (3 - 2 * h) * y1 + h * h * (h - 1) * dt * f1)
                    j += 1
            y0 = y1
    return out


def rk38_phase_grid(fn: Callable[[np.ndarray, float], tuple[np.ndarray, float]], x0: np.ndarray, t: np.ndarray,
                    step: float | None = None, s0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``rk38_grid`` of a phase field (x, s) on one point: fn (x (d,), s) -> (dx/dt (d,), ds/dt), e.g.
    a tracking field's ``phase_point_fn``; x0 : (d,); s0 : the initial phase. Returns x (T, d), s (T,)."""
    d = len(x0)

    def f(y: np.ndarray) -> np.ndarray:
        v, sd = fn(y[:d], float(y[d]))
        out = np.empty(d + 1)
        out[:d], out[d] = v, sd
        return out

    y = rk38_grid(f, np.append(np.asarray(x0, dtype=np.float64), float(s0)), t, step)
    return y[:, :d], y[:, d]
