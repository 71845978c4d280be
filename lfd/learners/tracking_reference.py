"""The tracking learner's reference, learned in closed form from the demos: Eqs. (T1), (T1b), (T1c), (T2).

Each demo i is a least-squares cubic B-spline x_i(s) in its normalised time s = (t - t_i0) / T_i.
The reference r(s) is their mean (Eq. (T1)); with ``align="path"`` the demos are first matched at
equal fractions of their path length and the match is timed by the demos' mean time fraction
(Eq. (T1c), then smoothed by a spline like the demos'), so that a feature of the motion is averaged
with itself even where the demos reach it at different times; ``align="time"`` averages at equal
time fractions. The start conditioning of
Eq. (T2) takes each demo's deviation from r at the matched points; Eq. (T1b) blends the reference
onto the goal. Derivations: docs/equations.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_lsq_spline

from lfd.demos import DemoSet

ALIGNMENTS = ("time", "path")
END_BLEND = 0.2       # Eq. (T1b): with end_at_goal, the reference blends onto the goal over this last part
PATH_FLOOR = 1e-3     # Eq. (T1c): the path fraction advances at least this fraction of the time fraction
FINE = 8              # Eq. (T1c): path fractions are inverted on a grid this many times the table's


@dataclass(frozen=True)
class ReferenceTables:
    """The tables of Eqs. (T1)-(T2) at M phases s_j = j / (M - 1), normalised units.

    ref, dref : array, shape (M, d) -- r(s_j) and r'(s_j)
    gain, dgain : array, shape (M, d, d) -- G(s_j) and G'(s_j) (zero without conditioning)
    precision : array, shape (d, d) -- P = (C(0, 0) + sigma^2 I)^-1 of Eq. (T2a) (zero without)
    splines : list of BSpline -- each demo's x_i(s)
    """

    ref: np.ndarray
    dref: np.ndarray
    gain: np.ndarray
    dgain: np.ndarray
    precision: np.ndarray
    splines: list[BSpline]


def _spline(s: np.ndarray, x: np.ndarray, knots: int) -> BSpline:
    """The least-squares cubic B-spline through samples x (T, ...) at s (T,) in [0, 1], ``knots`` uniform
    interior knots (at most a third of the samples), pinned to its first and last sample."""
    n_int = max(1, min(knots, len(s) // 3))
    inner = np.linspace(0.0, 1.0, n_int + 2)[1:-1]
    tk = np.concatenate([[0.0] * 4, inner, [1.0] * 4])
    w = np.ones(len(s))
    w[[0, -1]] = 1e3                       # pin the spline to the start and the goal
    return make_lsq_spline(s, x, tk, k=3, w=w)


def demo_splines(demos: DemoSet, knots: int) -> list[BSpline]:
    """Each demo's least-squares cubic B-spline x_i(s) in its normalised time s = (t - t_0) / T_i, with
    ``knots`` uniform interior knots (at most a third of its samples), pinned to its start and end."""
    return [_spline((t - t[0]) / (t[-1] - t[0]), x, knots) for t, x in zip(demos.t, demos.x)]


def phase_splines(demos: DemoSet, knots: int, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x_i(s_j) and dx_i/ds(s_j) of ``demo_splines`` at phases, shape (M,) in [0, 1]: each shape (N, M, d)."""
    splines = demo_splines(demos, knots)
    return np.stack([b(phases) for b in splines]), np.stack([b.derivative()(phases) for b in splines])


def matched_phases(splines: list[BSpline], phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (T1c): the time fractions s_i at which each demo is matched to the reference's phases s.

    a_i(s) = (1 - eps) L_i(s) / L_i(1) + eps s is demo i's path fraction (L_i(s) its path length
    up to s, eps = ``PATH_FLOOR``), strictly increasing; tau(u) = (1/N) sum_i a_i^-1(u) the demos'
    mean time fraction at path fraction u, and a phase s is matched at s_i = a_i^-1(tau^-1(s)).

    Returns s_i, shape (N, M), and a_i'(s_i), shape (N, M).
    """
    fine = np.linspace(0.0, 1.0, FINE * (len(phases) - 1) + 1)
    speed = [np.linalg.norm(b.derivative()(fine), axis=1) for b in splines]                       # (F,) each
    length = [np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) * 0.5 * np.diff(fine))]) for v in speed]
    total = [max(float(lg[-1]), 1e-300) for lg in length]
    arc = np.stack([(1.0 - PATH_FLOOR) * lg / tot + PATH_FLOOR * fine for lg, tot in zip(length, total)])
    tau = np.mean([np.interp(fine, a, fine) for a in arc], axis=0)                                # tau(u), (F,)
    u = np.interp(phases, tau, fine)                                                             # tau^-1(s)
    s_i = np.stack([np.interp(u, a, fine) for a in arc])                                         # (N, M)
    da = np.stack([(1.0 - PATH_FLOOR) * np.linalg.norm(b.derivative()(si), axis=1) / tot + PATH_FLOOR
                   for b, si, tot in zip(splines, s_i, total)])
    return s_i, da


def learn_reference(demos: DemoSet, knots: int, table: int, condition_start: bool, start_noise: float,
                    end_at_goal: bool, align: str) -> ReferenceTables:
    """The reference tables of Eqs. (T1), (T1c), (T2) and, with ``end_at_goal``, (T1b).

    demos : normalised demos, x of shape (N, T, d); table : M; start_noise : sigma of Eq. (T2),
    normalised units; align : ``time`` or ``path`` (Eq. (T1c)).

    With matched phases s_i (``matched_phases``; s_i = s for ``time``, a_i' = 1) and
    w_i = 1 / a_i'(s_i), the reference and its slope are

        r(s) = (1/N) sum_i x_i(s_i),   r'(s) = sum_i w_i x_i'(s_i) / sum_i w_i,

    and Eq. (T2) takes the deviations x_i(s_i) - r(s) and their slopes w_i x_i'(s_i) N / sum_j w_j - r'(s);
    for ``path`` the tables of r and G are then smoothed by a least-squares cubic spline in s with
    ``knots`` interior knots, and r', G' are its slopes (docs/equations.md).
    """
    n, d = demos.n_demos, demos.dim
    phases = np.linspace(0.0, 1.0, table)
    splines = demo_splines(demos, knots)
    if align == "path":
        s_i, da = matched_phases(splines, phases)
    else:
        s_i, da = np.broadcast_to(phases, (n, table)), np.ones((n, table))
    xs = np.stack([b(si) for b, si in zip(splines, s_i)])                                   # (N, M, d)
    w = 1.0 / da                                                                              # (N, M)
    dxs = np.stack([b.derivative()(si) for b, si in zip(splines, s_i)]) * (w / w.mean(0))[..., None]
    ref, dref = xs.mean(0), dxs.mean(0)
    gain, dgain, prec = np.zeros((table, d, d)), np.zeros((table, d, d)), np.zeros((d, d))
    if condition_start and n > 1:
        dev, ddev = xs - ref, dxs - dref                                                      # (N, M, d)
        c00 = dev[:, 0].T @ dev[:, 0] / (n - 1)
        prec = np.linalg.inv(c00 + start_noise ** 2 * np.eye(d))
        gain = np.einsum("nmi,nj->mij", dev, dev[:, 0]) / (n - 1) @ prec
        dgain = np.einsum("nmi,nj->mij", ddev, dev[:, 0]) / (n - 1) @ prec
    if align == "path":    # the matched mean, smoothed by the demos' own spline: r' exactly its slope
        ref, dref, gain, dgain = _smoothed(phases, ref, gain, knots)
    if end_at_goal:
        ref, dref, gain, dgain = blend_to_goal(phases, ref, dref, gain, dgain)
    return ReferenceTables(ref, dref, gain, dgain, prec, splines)


def _smoothed(phases: np.ndarray, ref: np.ndarray, gain: np.ndarray, knots: int
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """r and G of Eq. (T1c), tables (M, d) and (M, d, d), as least-squares cubic B-splines in s with
    ``knots`` interior knots (pinned at both ends): their values and exact slopes at the phases (M,)."""
    m, d = ref.shape
    spl = _spline(phases, np.concatenate([ref, gain.reshape(m, d * d)], axis=1), knots)
    val, slope = spl(phases), spl.derivative()(phases)
    return val[:, :d], slope[:, :d], val[:, d:].reshape(m, d, d), slope[:, d:].reshape(m, d, d)


def blend_to_goal(phases: np.ndarray, ref: np.ndarray, dref: np.ndarray, gain: np.ndarray, dgain: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (T1b): r <- r - w(s) r(1) and G <- (1 - w(s)) G with the quintic smoothstep w, 0 before
    1 - END_BLEND and 1 at s = 1 (C2 in s), so that r(1 | x0) = 0, the goal in normalised units;
    r' and G' follow by the product rule. phases (M,), ref and dref (M, d), gain and dgain (M, d, d)."""
    u = np.clip((phases - (1.0 - END_BLEND)) / END_BLEND, 0.0, 1.0)
    w = u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
    dw = 30.0 * u * u * (1.0 - u) ** 2 / END_BLEND
    end = ref[-1].copy()
    ref = ref - w[:, None] * end
    dref = dref - dw[:, None] * end
    dgain = (1.0 - w)[:, None, None] * dgain - dw[:, None, None] * gain
    gain = (1.0 - w)[:, None, None] * gain
    return ref, dref, gain, dgain
