"""Pinning torch, and the native thread pools under numpy and scipy, to a number of threads for a
block of work, then restoring them.

The learners, the certificate and the command line run small tensors (batches of a few hundred
points, d x d matrices): one thread is as fast as several, immune to oversubscription on a
shared machine (where two threads can be many times slower under load), and gives the same floats
on every run.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["limit_native_threads", "native_threads", "torch_threads"]


@contextmanager
def torch_threads(n: int = 1) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(n)``; the previous count is restored on exit,
    exceptions (KeyboardInterrupt included) too.

    Parameters
    ----------
    n : int
        Intra-op threads inside the block, >= 1.
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextmanager
def native_threads(n: int = 1) -> Iterator[None]:
    """Run the block with torch's intra-op threads and every native thread pool loaded in the
    process (numpy's and scipy's BLAS, OpenMP; ``threadpoolctl``) limited to ``n``; restored on exit.

    The bench and sweep workers run their cells under ``native_threads(1)``, wherever they run (in
    this process, a local pool worker or a Ray task): a BLAS call's floats can depend on its thread
    count, and the same count everywhere gives the same records, bit for bit.

    Parameters
    ----------
    n : int
        Threads of each pool inside the block, >= 1.
    """
    from threadpoolctl import threadpool_limits

    _load_native_pools()
    with torch_threads(n), threadpool_limits(limits=n):
        yield


def _load_native_pools() -> None:
    """Load numpy's and scipy's BLAS (scipy ships its own) so that ``threadpoolctl`` sees them."""
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401


def limit_native_threads(n: int = 1) -> None:
    """For the rest of this process (a worker's set-up): torch's intra-op threads and every native
    thread pool (BLAS, OpenMP) limited to ``n``, those loaded later too (through the environment
    variables they read when they load; torch is not imported here, so a worker that never needs
    it does not pay for it).

    Parameters
    ----------
    n : int
        Threads of each pool, >= 1.
    """
    import os
    import sys

    from threadpoolctl import threadpool_limits

    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = str(n)
    if "torch" in sys.modules:   # else torch takes its intra-op count from OMP_NUM_THREADS when it loads
        sys.modules["torch"].set_num_threads(n)
    _load_native_pools()
    threadpool_limits(limits=n)
