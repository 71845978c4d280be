"""Shared fixtures: small hand-built velocity fields with known behaviour."""

from __future__ import annotations

import os

os.environ.setdefault("MKL_CBWR", "COMPATIBLE")  # before torch loads MKL, as ``import lfd`` does

from collections.abc import Callable, Iterator

import numpy as np
import pytest
import torch

import lfd
from lfd.field import VelocityField
from lfd.normalization import Normalization
from lfd.threads import torch_threads


@pytest.fixture(scope="module")
def one_thread() -> Iterator[None]:
    """Small-batch torch on a shared 2-core machine: a second intra-op thread measured 10-80x
    slower rollouts under load (threads wait on each other). Modules that train or roll out
    use it with ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def spiral() -> lfd.DemoSet:
    """The default spiral demos, shared by a module's tests."""
    return lfd.spiral()


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


@pytest.fixture
def make_linear_field() -> Callable[..., VelocityField]:
    """The ``linear_field`` builder, for tests that need fields of their own."""
    return linear_field


@pytest.fixture
def spiral_field_2d() -> VelocityField:
    """f(x) = A (x - g), A = [[-1, 3], [-3, -1]], g = (0.5, -0.25): a stable focus, |x - g| ~ e^{-t}."""
    return linear_field(np.array([[-1.0, 3.0], [-3.0, -1.0]]), np.array([0.5, -0.25]), scale=2.0)


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
