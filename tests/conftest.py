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


@pytest.fixture(scope="module")
def model_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A fresh model cache (``LFD_CACHE_DIR``) for the module's jobs, the old setting restored after."""
    old = os.environ.get("LFD_CACHE_DIR")
    os.environ["LFD_CACHE_DIR"] = str(tmp_path_factory.mktemp("models"))
    yield os.environ["LFD_CACHE_DIR"]
    if old is None:
        os.environ.pop("LFD_CACHE_DIR", None)
    else:
        os.environ["LFD_CACHE_DIR"] = old


@pytest.fixture
def make_linear_field() -> Callable[..., VelocityField]:
    """The ``linear_field`` builder, for tests that need fields of their own."""
    return linear_field


@pytest.fixture
def spiral_field_2d() -> VelocityField:
    """f(x) = A (x - g), A = [[-1, 3], [-3, -1]], g = (0.5, -0.25): a stable focus, |x - g| ~ e^{-t}."""
    return linear_field(np.array([[-1.0, 3.0], [-3.0, -1.0]]), np.array([0.5, -0.25]), scale=2.0)


# The test files that take longest, longest first: pytest-xdist (``--dist loadfile``, pyproject.toml)
# hands files to the workers in collection order, so these start first and the short files fill
# in after them, instead of one long file running alone at the end.
LONGEST_FIRST = ("test_examples", "test_ray_cluster", "test_workers", "test_certify", "test_bench", "test_contraction",
                 "test_arm_clearance", "test_stable_node", "test_pose", "test_reliability", "test_obstacles",
                 "test_sim_obstacles", "test_relative", "test_signals", "test_pages")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Order the files as ``LONGEST_FIRST``, then the rest as collected (tests keep their order)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(rank)))
