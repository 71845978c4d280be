"""Pinning torch to a number of intra-op threads for a block of work, then restoring it.

The learners, the certificate and the command line run small tensors (batches of a few hundred
points, d x d matrices): one thread is as fast as several, immune to oversubscription on a
shared machine (where two threads can be many times slower under load), and gives the same floats
on every run.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["torch_threads"]


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
