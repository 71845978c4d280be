"""Plausibility checks of a demo set: signs that the demos are probably not what the user meant,
returned as warning lines (the ``lfd`` command prints them), never refused."""

from __future__ import annotations

import numpy as np

from lfd.demos.demoset import DemoSet


def demo_warnings(demos: DemoSet) -> list[str]:
    """Signs that demos are probably not what the user meant, one line each (the CLI prints them).

    - times that look like milliseconds: a median time step of at least 1 s over more than 100 s;
    - a 2-D demo that crosses itself (away from the goal): an autonomous field x -> dx/dt has one
      velocity per point, so it cannot reproduce a crossing.
    """
    out = []
    steps = np.median(np.diff(demos.t, axis=1))
    duration = float(np.max(demos.t[:, -1] - demos.t[:, 0]))
    if steps >= 1.0 and duration > 100.0:
        out.append(f"{demos.name}: demos last {duration:g} s with a median time step of {steps:g} s; "
                   "if the times are milliseconds, divide them by 1000")
    if demos.dim == 2:
        crossing = [i for i, x in enumerate(demos.x) if _crosses_itself(x, demos.goal)]
        if crossing:
            out.append(f"{demos.name}: demo {crossing[0]} crosses itself; a velocity field cannot "
                       "reproduce a crossing (it has one velocity per point)")
    return out


def _crosses_itself(x: np.ndarray, goal: np.ndarray, max_points: int = 300,
                    goal_fraction: float = 0.1) -> bool:
    """Whether the polyline x, shape (T, 2), has two segments at least a tenth of the demo apart
    that properly cross, outside the disc of ``goal_fraction`` times the demo's extent around
    ``goal`` (where noise makes small loops). Subsampled to at most ``max_points`` points."""
    k = max(1, -(-len(x) // max_points))
    p = np.concatenate([x[::k], x[-1:]]) if (len(x) - 1) % k else x[::k]
    a, b = p[:-1], p[1:]                                               # segments, (S, 2) each
    extent = float(np.max(p.max(0) - p.min(0)))
    far = np.maximum(np.linalg.norm(a - goal, axis=1), np.linalg.norm(b - goal, axis=1)) > goal_fraction * extent

    def orient(o: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        return np.sign((q[..., 0] - o[..., 0]) * (r[..., 1] - o[..., 1])
                       - (q[..., 1] - o[..., 1]) * (r[..., 0] - o[..., 0]))

    A, B, C, D = a[:, None], b[:, None], a[None, :], b[None, :]        # (S, 1, 2) and (1, S, 2)
    with np.errstate(all="ignore"):
        cross = ((orient(A, B, C) * orient(A, B, D) < 0) & (orient(C, D, A) * orient(C, D, B) < 0))
    # pairs at least a tenth of the demo apart: noise makes tiny loops between nearby samples
    i, j = np.triu_indices(len(a), k=max(2, len(a) // 10))
    return bool(np.any(cross[i, j] & far[i] & far[j]))
