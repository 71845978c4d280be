"""Hand-built velocity fields with known behaviour, for the tests (no training).

The tests import these builders by name (``from known_fields import sink_field``); ``conftest.py``
wraps some of them as fixtures.
"""

from __future__ import annotations

import numpy as np
import torch

import lfd
from lfd.field import VelocityField
from lfd.normalization import Normalization


def linear_field(A: np.ndarray, goal: np.ndarray, scale: float = 1.0,
                 history: dict | None = None) -> VelocityField:
    """The field f(x) = A (x - goal): a torch Linear module, no bias, on normalised coordinates
    (with a scalar scale, f_n(x_n) = A x_n gives the same A in user units)."""
    d = len(goal)
    module = torch.nn.Linear(d, d, bias=False)
    with torch.no_grad():
        module.weight.copy_(torch.as_tensor(np.asarray(A, dtype=np.float64)))
    norm = Normalization(goal=np.asarray(goal, dtype=np.float64), scale=scale)
    return VelocityField(module, norm, "linear", {}, history or {"loss": [1.0, 0.1, 0.01]})


class LinearSink(torch.nn.Module):
    """f_n(x) = A x with A = [[-a, -w], [w, -a]] (-a on z in 3-D): a contracting spiral, no training."""

    def __init__(self, dim: int, a: float = 1.5, w: float = 2.0) -> None:
        super().__init__()
        m = -a * np.eye(dim)
        m[0, 1], m[1, 0] = -w, w
        self.A = torch.nn.Parameter(torch.tensor(m))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x @ self.A.T


def sink_field(demos: lfd.DemoSet, learner: str = "node", a: float = 1.5) -> VelocityField:
    """A ``LinearSink`` field on ``demos``' normalisation, named ``learner`` (for the sim, env and video tests)."""
    return VelocityField(LinearSink(demos.dim, a), Normalization.from_points(demos.x, demos.goal), learner, {})
