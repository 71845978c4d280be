"""Seeded start points near the demos' starts and outside every obstacle (``starts_outside``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from lfd.obstacles.avoidance import AvoidingField

__all__ = ["starts_outside"]


def starts_outside(field: AvoidingField, demos: Any, n: int, seed: int = 0, spread: float = 0.15,
                   clearance: float = 1.05) -> np.ndarray:
    """Seeded starts near the demos' starts and outside every obstacle of ``field``.

    Parameters
    ----------
    field : AvoidingField
        Its ``gamma`` (> 1 outside every obstacle) decides what is outside.
    demos : DemoSet
        x of shape (N, T, d); a start is a demo start plus uniform noise of +-spread x the demos'
        bounding box's side per coordinate.
    n, seed, spread : int, int, float
        How many starts, the numpy seed, the noise's half-width as a fraction of the box's sides.
    clearance : float
        Keep only starts with gamma > clearance.

    Returns
    -------
    array, shape (n, d)
    """
    rng = np.random.default_rng(seed)
    sides = np.ptp(demos.x.reshape(-1, demos.dim), axis=0)       # (d,): the bounding box's sides
    out: list[np.ndarray] = []
    while len(out) < n:
        x = demos.x[rng.integers(len(demos.x)), 0] + rng.uniform(-spread, spread, demos.dim) * sides
        if field.gamma(x) > clearance:
            out.append(x)
    return np.array(out)
