"""Via-points: a learned motion made to pass through points no demo passed through.

The tracking field follows its reference r(s | x0), Eqs. (T1)-(T2) of docs/equations.md, a cubic
Hermite table of knots r(s_k), r'(s_k) plus the start's offset G(s) delta. ``through(field, points)``
returns the field whose reference passes through each point v_i at its phase s_i, as a ProMP or KMP
conditions on a via-point, with a smooth correction that leaves the start and the goal as they were:

    r_v(s | x0) = r(s | x0) + sum_i phi_i(s) c_i,   phi_i(s) = e(s) k(s, s_i),
    k(s, s') = exp(-(s - s')^2 / (2 w^2)),          e(s) = sin(pi s)^2,

with the coefficients c solving r_v(s_j | x0) = v_j for every j (an m x m system, m the number of
points). e and its slope vanish at s = 0 and 1, so r_v(0), r_v(1) and their slopes are r's: the run
still starts where it starts and ends at the goal. The correction is linear in the residuals
v_j - r(s_j) - G(s_j) delta, so it is applied to the tables once: r and r' get the part of the mean
reference, G and G' the part that cancels the start's offset at the points (the reference passes
through them from any start). w (``width``, in phase) sets how far along the motion the detour
spreads. Eqs. (T3)-(T5) then hold as before: x contracts onto r_v at the rate K.

A point's phase is given, or else the phase of the nearest point of the mean reference.

An autonomous field (the NODE, the stable NODE, the goal contraction) goes through the points by a
goal that moves (``lfd.goal.MovingGoalField``): f_v(x, t) = f(x - delta(t)) + delta'(t), delta(t) =
sum_i phi_i(t / T) c_i with c fitted to its rollout from the start x0 over the motion's duration T, so
that it passes each point exactly from x0, and delta = 0 from T on (docs/equations.md, "Via-points").
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from lfd.errors import ConfigError
from lfd.goal import MovingGoalField

#: the correction's width in phase (w), and the phases a point may take (the ends are the start and goal)
WIDTH = 0.12
PHASE_RANGE = (0.05, 0.95)
MIN_PHASE_GAP = 0.02
PATH_SAMPLES = 1001   # an autonomous field's rollout, sampled over its duration, where the points' phases are found


def _basis(s: np.ndarray, centres: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """phi_i(s) and d phi_i / ds at phases s (P,) for centres (m,): each shape (P, m)."""
    d = s[:, None] - centres[None, :]
    k = np.exp(-0.5 * (d / width) ** 2)
    dk = -d / width ** 2 * k
    e = np.sin(np.pi * s) ** 2
    de = np.pi * np.sin(2 * np.pi * s)
    return e[:, None] * k, de[:, None] * k + e[:, None] * dk


def through(field: Any, points: Sequence[Sequence[float]] | Sequence[np.ndarray],
            phases: Sequence[float | None] | None = None, width: float = WIDTH,
            start: np.ndarray | None = None, duration: float | None = None) -> Any:
    """``field`` whose motion passes through ``points`` (module docstring): the tracking field's
    reference conditioned on them, or an autonomous field's goal moved by delta(t).

    Parameters
    ----------
    field : lfd.learners.tracking.TrackingField or an autonomous field
        A trained tracking field (positions or chart points of poses, task units), or an
        autonomous field (``FieldKind.AUTONOMOUS``) of positions.
    points : sequence of m points, each shape (d,)
        Where the reference must pass, the field's units.
    phases : sequence of m floats or None, optional
        Each point's phase in ``PHASE_RANGE``; None: the phase of the nearest mean-reference point.
    width : float
        w, the correction's width in phase, in (0, 0.5].
    start, duration : ndarray, shape (d,), and float, optional
        An autonomous field's start x0 and the motion's duration T, s (needed for it; unused by the
        tracking field, whose reference passes through the points from any start).

    Returns
    -------
    TrackingField or MovingGoalField
        A copy of the tracking ``field`` with the conditioned tables, or the autonomous field
        wrapped; ``field`` is unchanged.

    Raises
    ------
    ConfigError
        Another learner's field, points of the wrong dimension or not finite, a phase outside
        ``PHASE_RANGE``, two points closer than ``MIN_PHASE_GAP`` in phase, or a width outside (0, 0.5].
    """
    if field.learner != "tracking":
        return _through_moving_goal(field, points, phases, width, start, duration)
    if getattr(field, "module", None) is None:
        raise ConfigError("via-points apply to a trained tracking field before it is wrapped (obstacles, a "
                          "moving goal, a speed)")
    v, given = _checked(field, points, phases, width)
    mod = field.module
    m_knots = mod.ref.shape[0]
    knots = np.linspace(0.0, 1.0, m_knots)
    v_n = field.norm.to_norm(v)
    s = _phases(given, v_n, mod.ref.numpy(), knots)
    phi_v, _ = _basis(s, s, width)                         # (m, m)
    phi_k, dphi_k = _basis(knots, s, width)                # (M, m)
    solve = np.linalg.solve(phi_v, np.eye(len(s)))         # Phi^-1
    a, da = phi_k @ solve, dphi_k @ solve                  # knot offsets per unit residual, (M, m)
    d = field.dim
    with torch.no_grad():
        st = torch.tensor(s)
        r_v = mod.reference(st)[0].numpy()                 # the mean reference at the points, (m, d)
        # G(s_i), (m, d, d): column j is the reference's answer to a unit start offset along j
        g_v = np.stack([mod.reference(st, torch.tensor(np.tile(np.eye(d)[j], (len(s), 1))))[0].numpy() - r_v
                        for j in range(d)], axis=-1)
    residual = v_n - r_v
    out = copy.deepcopy(field)
    out.__dict__.pop("_point", None)                       # the cached evaluator is the old field's
    new = out.module
    with torch.no_grad():
        new.ref += torch.tensor(a @ residual)
        new.dref += torch.tensor(da @ residual)
        new.gain -= torch.tensor(np.einsum("km,mij->kij", a, g_v))
        new.dgain -= torch.tensor(np.einsum("km,mij->kij", da, g_v))
    return out


def _checked(field: Any, points: Any, phases: Sequence[float | None] | None, width: float
             ) -> tuple[np.ndarray, list[float | None]]:
    """The points as an (m, d) array and their phases (None: the nearest), checked."""
    v = np.asarray(points, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != field.dim or not np.isfinite(v).all() or len(v) == 0:
        raise ConfigError(f"via-points must be {field.dim} finite coordinates each, got {np.asarray(points).tolist()}")
    if not 0 < width <= 0.5:
        raise ConfigError(f"the via-point width must be in (0, 0.5] of the phase, got {width}")
    given: list[float | None] = [None] * len(v) if phases is None else list(phases)
    if len(given) != len(v):
        raise ConfigError(f"{len(v)} via-points but {len(given)} phases")
    return v, given


def _phases(given: list[float | None], v: np.ndarray, path: np.ndarray, path_s: np.ndarray) -> np.ndarray:
    """Each point's phase: given, or the phase path_s (P,) of its nearest point of path (P, d); checked."""
    s = np.array([float(path_s[np.argmin(np.linalg.norm(path - p, axis=1))]) if g is None else float(g)
                  for p, g in zip(v, given)])
    if not ((s >= PHASE_RANGE[0]) & (s <= PHASE_RANGE[1])).all():
        raise ConfigError(f"a via-point's phase must lie in [{PHASE_RANGE[0]:g}, {PHASE_RANGE[1]:g}] (the ends "
                          f"are the start and the goal), got {np.round(s, 3).tolist()}")
    if len(s) > 1 and np.min(np.diff(np.sort(s))) < MIN_PHASE_GAP:
        raise ConfigError(f"two via-points lie closer than {MIN_PHASE_GAP:g} in phase: {np.round(s, 3).tolist()}")
    return s


def _through_moving_goal(field: Any, points: Any, phases: Sequence[float | None] | None, width: float,
                         start: np.ndarray | None, duration: float | None) -> MovingGoalField:
    """An autonomous field through the points by the moving goal delta(t) of the module docstring."""
    v, given = _checked(field, points, phases, width)
    if start is None or duration is None or not (np.isfinite(duration) and duration > 0):
        raise ConfigError("via-points on an autonomous field need its start and the motion's duration")
    x0 = np.asarray(start, dtype=np.float64).reshape(-1)
    if x0.shape != (field.dim,) or not np.isfinite(x0).all():
        raise ConfigError(f"the start must be {field.dim} finite coordinates, got {x0.tolist()}")
    T = float(duration)
    grid = np.linspace(0.0, 1.0, PATH_SAMPLES)
    path = field.trajectory(x0, grid * T)[0]   # requires an autonomous field: MovingGoalField checks it
    s = _phases(given, v, path, grid)
    phi_v, _ = _basis(s, s, width)
    at = np.array([np.interp(sj, grid, path[:, i]) for sj in s for i in range(field.dim)]).reshape(len(s), -1)
    c = np.linalg.solve(phi_v, v - at)   # (m, d)

    def shift(t: float) -> tuple[np.ndarray, np.ndarray]:
        u = t / T
        if u <= 0.0 or u >= 1.0:
            return np.zeros(field.dim), np.zeros(field.dim)
        b, db = _basis(np.array([u]), s, width)
        return b[0] @ c, (db[0] / T) @ c
    samples = np.array([field.goal + shift(float(u) * T)[0] for u in np.linspace(0.0, 1.0, 41)])
    return MovingGoalField(field, shift, samples)



def parse_via(text: str, dim: int) -> tuple[np.ndarray, float | None]:
    """``X,Y[,Z][@S]``: a via-point of ``dim`` coordinates and its phase S (None: the nearest), or a
    ``ConfigError`` of one line."""
    coords, _, phase = text.partition("@")
    try:
        point = np.array([float(c) for c in coords.split(",")], dtype=np.float64)
        s = float(phase) if phase else None
    except ValueError:
        raise ConfigError(f"--via {text!r}: expected X,Y[,Z] in task units, optionally @PHASE") from None
    if point.shape != (dim,) or not np.isfinite(point).all():
        raise ConfigError(f"--via {text!r}: expected {dim} finite task coordinates for {dim}-D demos")
    if s is not None and not PHASE_RANGE[0] <= s <= PHASE_RANGE[1]:
        raise ConfigError(f"--via {text!r}: the phase must lie in [{PHASE_RANGE[0]:g}, {PHASE_RANGE[1]:g}]")
    return point, s
