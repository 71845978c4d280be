"""Each demo relative to its own end: a set whose demos end apart, moved so that every demo ends at one goal.

The preprocessing of stable-DS learners (SEDS learns each demo relative to its end point), Eqs. (R1)-(R2)
of docs/equations.md: demo i, ending at x_i(T_i) with orientation R_i(T_i), becomes

    Eq. (R1): x_i'(t) = x_i(t) - x_i(T_i) + g,
    Eq. (R2): R_i'(t) = R_g R_i(T_i)^T R_i(t)   (left multiplication: a turn of the whole demo in world axes),

so it ends at the goal (g, R_g) and keeps its motion as seen from its own end: the translation
x_i(t) - x_i(T_i) and the turn R_i(T_i)^T R_i(t) in its final tool frame. The latter is what a pose
field learns (the chart coordinate l log(R_g^T R_i') of Eq. (P1)), so a field run toward demo i's
own end (``VelocityField.toward``: the chart moved to R_i(T_i)) has demo i's own chart points.
Every learner learns its demos so (``lfd.learners.train``), and so does the DMP baseline.
"""

from __future__ import annotations

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.rotations import continuous, geodesic_angle, matrix_quaternions, quaternion_matrices


def relative_to_ends(demos: DemoSet, goal: np.ndarray | None = None, goal_q: np.ndarray | None = None) -> DemoSet:
    """The demos moved to end at one goal, Eqs. (R1)-(R2) (module docstring).

    Parameters
    ----------
    demos : DemoSet
        N demos, positions x (N, T, d) and, for poses, quaternions q (N, T, 4) (w, x, y, z).
    goal : array, shape (d,), optional
        g, where every demo ends; default the demos' mean end point ``demos.goal``.
    goal_q : array, shape (4,), optional
        R_g as a unit quaternion (w, x, y, z), the final orientation of every demo; default the
        Karcher mean of the final orientations ``demos.goal_q`` (poses only).

    Returns
    -------
    DemoSet
        The same times, name, frame and notes; positions (N, T, d) and orientations (N, T, 4),
        each demo's sign-continuous. Its ``goal`` is g and its ``goal_q`` R_g, to round-off.
    """
    g = demos.goal if goal is None else np.asarray(goal, dtype=np.float64)
    x = demos.x - demos.ends[:, None, :] + g                                        # Eq. (R1)
    q = None
    if demos.q is not None and demos.goal_q is not None:
        rg = quaternion_matrices(demos.goal_q if goal_q is None else np.asarray(goal_q, dtype=np.float64))
        turn = np.einsum("ij,nkj->nik", rg, quaternion_matrices(demos.q[:, -1]))   # R_g R_i(T_i)^T, (N, 3, 3)
        rot = np.einsum("nij,ntjk->ntik", turn, quaternion_matrices(demos.q))     # Eq. (R2), (N, T, 3, 3)
        q = np.stack([continuous(qi) for qi in matrix_quaternions(rot)])
    return DemoSet(demos.t, x, name=demos.name, q=q, frame=demos.frame, end_tolerance=demos.end_tolerance,
                   notes=demos.notes)


def end_spread(demos: DemoSet) -> tuple[float, float]:
    """How far the demos end apart: the largest distance of an end point from their mean, as a
    fraction of the extent, and the largest angle of a final orientation from their mean, degrees
    (0 for positions). Shapes: ends (N, d), end orientations (N, 4)."""
    pos = float(np.max(np.linalg.norm(demos.ends - demos.goal, axis=1))) / max(demos.extent, 1e-300)
    if demos.goal_q is None or demos.end_q is None:
        return pos, 0.0
    angles = geodesic_angle(quaternion_matrices(demos.goal_q), quaternion_matrices(demos.end_q))
    return pos, float(np.degrees(np.max(angles)))
