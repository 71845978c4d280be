"""A goal that moves during execution: any velocity field re-centred on a goal trajectory g(t).

The field is shifted by delta(t) = g(t) - g0 (g0 the field's own goal):

.. math::

    f_s(x, t) = f\\big(x - \\delta(t)\\big) + \\dot\\delta(t)

In the moving frame z = x - delta(t) this is exactly dz/dt = f(z): the motion relative to the goal
is the learned one, so the state converges to g(t) as the field converges to g0, and a robot resting
at the goal moves with it at speed |delta'(t)| (no jump). The shift is blended in with the quintic
smooth step s(u) = 10u^3 - 15u^4 + 6u^5 (zero first and second derivative at both ends), so the
commanded velocity changes continuously; for a step ``dx`` blended over T seconds the extra speed
peaks at 15/8 |dx| / T.

``--goal-shift t:dx,dy[,dz]`` moves the goal by dx at time t; ``--goal-path FILE`` follows a goal
trajectory (CSV rows ``t,x,y[,z]`` with an optional header, or NPZ with ``t`` (T,) and ``x`` (T, d)),
interpolated by a monotone cubic (PCHIP, C1) and blended in from g0 over the first T seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lfd.errors import ConfigError
from lfd.field import FieldKind, FieldWrapper, require_kind
from lfd.obstacles import AvoidingField, avoid

__all__ = ["MovingGoalField", "shift_goal", "follow_goal_path", "parse_goal_shift", "load_goal_path"]

#: default blend time [s] of a goal shift
BLEND_S = 0.5


def smooth_step(u: float) -> tuple[float, float]:
    """s(u) = 10u^3 - 15u^4 + 6u^5 on [0, 1] (clamped outside) and its derivative ds/du."""
    if u <= 0.0:
        return 0.0, 0.0
    if u >= 1.0:
        return 1.0, 0.0
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u)), 30.0 * u * u * (1.0 - u) * (1.0 - u)


class MovingGoalField(FieldWrapper):
    """``field`` with its goal moved along g0 + delta(t): f_s(x, t) = f(x - delta(t)) + delta'(t).

    Parameters
    ----------
    field : VelocityField
        The nominal autonomous field f(x) [units/s] with goal g0, shape (d,); a field of another
        kind is refused (``ConfigError``): a phase or a time of its own would not follow the shift.
    shift : callable t -> (delta, delta_dot)
        The goal displacement [units] and its rate [units/s] at time t [s], arrays of shape (d,).
    samples : array, shape (k, d)
        Goals the shift visits (for ``lfd.obstacles``' check that no goal lies in an obstacle).
    """

    def __init__(self, field: Any, shift: Callable[[float], tuple[np.ndarray, np.ndarray]],
                 samples: np.ndarray) -> None:
        require_kind(field, (FieldKind.AUTONOMOUS,), "a moving goal (--goal-shift, --goal-path)")
        self.field = field
        self.shift = shift
        self._samples = np.atleast_2d(np.asarray(samples, dtype=np.float64))

    @property
    def goal(self) -> np.ndarray:
        """The goal at t = 0, shape (d,)."""
        return self.goal_at(0.0)

    def goal_at(self, t: float) -> np.ndarray:
        """The goal g(t) = g0 + delta(t), shape (d,)."""
        return self.field.goal + self.shift(float(t))[0]

    def goal_samples(self) -> np.ndarray:
        """Goals visited, shape (k, d)."""
        return self._samples

    def __call__(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        """dx/dt at x : array, shape (d,) or (..., d), at time t [s]."""
        delta, rate = self.shift(float(t))
        return np.asarray(self.field(np.asarray(x, dtype=np.float64) - delta)) + rate

    def single_point_evaluator(self) -> Callable[..., np.ndarray]:
        """The fast path for one point, for control loops: ``field(x, t)`` on x of shape (d,) calls it.

        Returns
        -------
        callable
            (x, array of shape (d,), user units; t, float, s, default 0.0) -> dx/dt, array of
            shape (d,), user units: the wrapped field's ``single_point_evaluator`` at the shifted x.
        """
        base, shift = self.field.single_point_evaluator(), self.shift

        def f(x: np.ndarray, t: float = 0.0) -> np.ndarray:
            delta, rate = shift(t)
            return base(x - delta) + rate
        return f

    def rollout(self, x0: np.ndarray, t: np.ndarray, method: str = "rk4", substeps: int = 1) -> np.ndarray:
        """RK4 from x0, shape (B, d) or (d,), over t, shape (T,): returns (B, T, d) (or (T, d))."""
        return AvoidingField(self, []).rollout(x0, t, method, substeps)

    def avoiding(self, obstacles: Sequence[Any], **kw: Any) -> Any:
        """This field modulated to avoid ``obstacles`` (see ``lfd.obstacles.AvoidingField``)."""
        return avoid(self, obstacles, **kw)

    def __repr__(self) -> str:
        return f"MovingGoalField({self.field!r})"


def shift_goal(field: Any, t: float, dx: Sequence[float] | np.ndarray, blend: float = BLEND_S) -> MovingGoalField:
    """Move ``field``'s goal by ``dx`` (shape (d,)) [units], starting at time ``t`` [s] and blended
    over ``blend`` seconds: delta(t') = s((t' - t) / blend) dx. Peak extra speed 15/8 |dx| / blend."""
    dv = np.asarray(dx, dtype=np.float64).reshape(-1)
    if dv.size != field.dim or not np.all(np.isfinite(dv)):
        raise ConfigError(f"goal shift must be {field.dim} finite numbers, got {dv.tolist()}")
    if not (math.isfinite(t) and t >= 0 and math.isfinite(blend) and blend > 0):
        raise ConfigError(f"goal shift needs a time >= 0 and a blend > 0, got t={t}, blend={blend}")
    t0, T = float(t), float(blend)

    def shift(tt: float) -> tuple[np.ndarray, np.ndarray]:
        s, ds = smooth_step((tt - t0) / T)
        return s * dv, (ds / T) * dv
    return MovingGoalField(field, shift, np.stack([field.goal, field.goal + dv]))


def follow_goal_path(field: Any, times: np.ndarray, goals: np.ndarray,
                     blend: float = BLEND_S) -> MovingGoalField:
    """Follow the goal trajectory ``goals`` (shape (T, d)) at ``times`` (shape (T,), increasing) [s].

    delta(t) = s(t / blend) (g(t) - g0), with g the PCHIP interpolant, held constant outside the
    sampled times; s blends the path in from the field's goal g0 over the first ``blend`` seconds."""
    from scipy.interpolate import PchipInterpolator

    times = np.asarray(times, dtype=np.float64).reshape(-1)
    goals = np.asarray(goals, dtype=np.float64)
    if goals.ndim != 2 or goals.shape != (times.size, field.dim):
        raise ConfigError(f"goal path must be {field.dim}-D points, one per time; got shape {goals.shape} "
                          f"for {times.size} times")
    if times.size < 2 or not np.all(np.isfinite(times)) or not np.all(np.isfinite(goals)) \
            or np.any(np.diff(times) <= 0):
        raise ConfigError("goal path needs at least 2 finite samples at strictly increasing times")
    if not (math.isfinite(blend) and blend > 0):
        raise ConfigError(f"goal path blend must be > 0, got {blend}")
    g = PchipInterpolator(times, goals - field.goal, axis=0, extrapolate=False)
    dg = g.derivative()
    lo, hi, T = float(times[0]), float(times[-1]), float(blend)
    first, last = goals[0] - field.goal, goals[-1] - field.goal
    zero = np.zeros(field.dim)

    def shift(tt: float) -> tuple[np.ndarray, np.ndarray]:
        if tt <= lo:
            e, de = first, zero
        elif tt >= hi:
            e, de = last, zero
        else:
            e, de = g(tt), dg(tt)
        s, ds = smooth_step(tt / T)
        return s * e, (ds / T) * e + s * de
    return MovingGoalField(field, shift, goals)


def parse_goal_shift(text: str, dim: int | None = None) -> tuple[float, np.ndarray]:
    """``t:dx,dy[,dz]`` -> (t [s], dx (d,)); ``ConfigError`` (one line) on bad text."""
    t_text, sep, rest = str(text).partition(":")
    try:
        if not sep:
            raise ValueError
        t = float(t_text)
        dx = np.array([float(v) for v in rest.split(",")])
    except ValueError:
        raise ConfigError(f"bad goal shift '{str(text)[:60]}': use t:dx,dy[,dz] (seconds, task units)") from None
    if not math.isfinite(t) or t < 0 or dx.size not in (2, 3) or not np.all(np.isfinite(dx)):
        raise ConfigError(f"bad goal shift '{str(text)[:60]}': t must be >= 0 and dx 2 or 3 finite numbers")
    if dim is not None and dx.size != dim:
        raise ConfigError(f"bad goal shift '{str(text)[:60]}': {dx.size}-D shift for a {dim}-D field")
    return t, dx


def load_goal_path(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a goal trajectory: CSV ``t,x,y[,z]`` rows (optional header line) or NPZ with ``t`` (T,)
    and ``x`` (T, d). Returns (times (T,), goals (T, d)); ``ConfigError`` (one line) on bad files."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"goal path {p}: no such file")
    try:
        if p.suffix.lower() == ".npz":
            with np.load(p, allow_pickle=False) as z:
                if "t" not in z or "x" not in z:
                    raise ConfigError(f"goal path {p}: an NPZ needs arrays 't' (T,) and 'x' (T, d)")
                t, x = np.asarray(z["t"], dtype=np.float64), np.asarray(z["x"], dtype=np.float64)
        else:
            with open(p, encoding="utf-8") as f:
                lines = [ln for ln in f.read().splitlines() if ln.strip()]
            if lines and not lines[0].lstrip()[:1].replace("-", "").replace(".", "").isdigit():
                lines = lines[1:]   # header
            rows = np.array([[float(v) for v in ln.split(",")] for ln in lines], dtype=np.float64)
            if rows.ndim != 2 or rows.shape[1] not in (3, 4):
                raise ConfigError(f"goal path {p}: expected rows t,x,y[,z]")
            t, x = rows[:, 0], rows[:, 1:]
    except ConfigError:
        raise
    except (ValueError, OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"goal path {p}: unreadable "
                          f"({str(e).splitlines()[0][:80] if str(e) else type(e).__name__})") from None
    if t.ndim != 1 or x.ndim != 2 or x.shape[0] != t.size or x.shape[1] not in (2, 3):
        raise ConfigError(f"goal path {p}: expected t (T,) and x (T, 2 or 3), got {t.shape} and {x.shape}")
    if t.size < 2 or not np.all(np.isfinite(t)) or not np.all(np.isfinite(x)) or np.any(np.diff(t) <= 0):
        raise ConfigError(f"goal path {p}: needs at least 2 finite samples at strictly increasing times")
    return t, x
