"""Generated demos: the paper's planar spiral, Eq. (11), and a conical spiral in 3-D, with noise."""

from __future__ import annotations

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.errors import DemoError


def _ease_out(s: np.ndarray) -> np.ndarray:
    """s -> 1 - (1 - s)^2: progress whose speed falls to zero at the goal."""
    return 1.0 - (1.0 - s) ** 2


def spiral(n_demos: int = 5, n_samples: int = 200, turns: float = 2.0, radius: float = 1.0,
           duration: float = 5.0, start_spread: float = 0.1, noise: float = 0.01,
           goal: tuple[float, ...] = (0.0, 0.0), seed: int = 0) -> DemoSet:
    """Planar spiral demos converging to ``goal``: the paper's spiral, Eq. (11), with noise, Eq. (1).

    x = r cos th, y = r sin th with s = 1 - (1 - t/duration)^2,
    r = r0 (1 - s), th = th0 + 2 pi turns s; r0 = radius (1 + start_spread u1), th0 = start_spread u2 pi
    with u ~ U(-1, 1), plus N(0, (noise radius)^2) on every sample except the last.
    Returns a DemoSet with x of shape (n_demos, n_samples, 2).
    """
    return _spiral(n_demos, n_samples, turns, radius, duration, start_spread, noise, goal, seed, 0.0,
                   "spiral")


def spiral3d(n_demos: int = 5, n_samples: int = 200, turns: float = 2.0, radius: float = 1.0,
             height: float = 1.0, duration: float = 5.0, start_spread: float = 0.1, noise: float = 0.01,
             goal: tuple[float, ...] = (0.0, 0.0, 0.0), seed: int = 0) -> DemoSet:
    """Conical spiral descending to ``goal``: the planar spiral plus z = height (1 - s).

    Returns a DemoSet with x of shape (n_demos, n_samples, 3).
    """
    return _spiral(n_demos, n_samples, turns, radius, duration, start_spread, noise, goal, seed, height,
                   "spiral3d")


def _spiral(n_demos: int, n_samples: int, turns: float, radius: float, duration: float,
            start_spread: float, noise: float, goal: tuple[float, ...], seed: int, height: float,
            name: str) -> DemoSet:
    d = 3 if name == "spiral3d" else 2
    if len(goal) != d:
        raise DemoError(f"{name}: goal must have {d} coordinates, got {len(goal)}")
    if n_demos < 1 or radius <= 0 or duration <= 0:
        raise DemoError(f"{name}: n_demos, radius and duration must be positive")
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, n_samples)
    s = _ease_out(t / duration)
    xs = np.empty((n_demos, n_samples, d))
    for i in range(n_demos):
        u1, u2 = rng.uniform(-1, 1, 2)
        r0, th0 = radius * (1 + start_spread * u1), start_spread * u2 * np.pi
        r, th = r0 * (1 - s), th0 + 2 * np.pi * turns * s
        xs[i, :, 0], xs[i, :, 1] = r * np.cos(th), r * np.sin(th)
        if d == 3:
            xs[i, :, 2] = height * (1 - s) * r0 / radius
        xs[i, :-1] += rng.normal(0.0, noise * radius, (n_samples - 1, d))
    return DemoSet(np.broadcast_to(t, (n_demos, n_samples)).copy(), xs + np.asarray(goal), name=name)
