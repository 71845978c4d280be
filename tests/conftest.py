"""Shared fixtures: small hand-built velocity fields with known behaviour."""

from __future__ import annotations

import os

os.environ.setdefault("MKL_CBWR", "COMPATIBLE")  # before torch loads MKL, as ``import lfd`` does

from collections.abc import Callable, Iterator

import numpy as np
import pytest
from known_fields import linear_field

import lfd
from lfd.field import VelocityField
from lfd.threads import torch_threads


@pytest.fixture(scope="module")
def one_thread() -> Iterator[None]:
    """Small-batch torch on a shared 2-core machine: a second intra-op thread makes rollouts many
    times slower under load (threads wait on each other). Modules that train or roll out
    use it with ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def spiral() -> lfd.DemoSet:
    """The default spiral demos, shared by a module's tests."""
    return lfd.spiral()


@pytest.fixture
def make_linear_field() -> Callable[..., VelocityField]:
    """The ``linear_field`` builder, for tests that need fields of their own."""
    return linear_field


@pytest.fixture
def spiral_field_2d() -> VelocityField:
    """f(x) = A (x - g), A = [[-1, 3], [-3, -1]], g = (0.5, -0.25): a stable focus, |x - g| ~ e^{-t}."""
    return linear_field(np.array([[-1.0, 3.0], [-3.0, -1.0]]), np.array([0.5, -0.25]), scale=2.0)


# Modules whose module-scoped fixtures train models, run benchmarks or start a cluster (and the
# examples, which share one model cache in order): their tests stay on one xdist worker
# (``--dist loadgroup``, pyproject.toml), so that each such fixture is built once; the tests of every
# other module are spread over the workers one by one.
SHARED_FIXTURES = frozenset({
    "test_arm_regression", "test_bench", "test_bench_robottasks", "test_certify", "test_contraction", "test_examples",
    "test_node", "test_ray_cluster", "test_sim_obstacles", "test_sweep",
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Put the tests of ``SHARED_FIXTURES`` modules into one xdist group per module."""
    for item in items:
        module = item.path.stem
        if module in SHARED_FIXTURES:
            item.add_marker(pytest.mark.xdist_group(module))
