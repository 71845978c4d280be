"""Importing MuJoCo-based modules with rendering off.

MuJoCo (and dm_control's renderer) pick their GL back-end from ``MUJOCO_GL`` when they are
imported, and a bad or missing back-end ends the import. A robot needs no rendering, so the
imports run with ``MUJOCO_GL=disable``; ``sim.media.gl`` chooses and checks the back-end where videos are
rendered.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["rendering_off"]


@contextmanager
def rendering_off() -> Iterator[str | None]:
    """Within the block ``MUJOCO_GL`` is ``disable``; on leaving it is restored (unset if it was).

    Yields
    ------
    str or None
        The user's ``MUJOCO_GL`` from before the block.
    """
    saved = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"
    try:
        yield saved
    finally:
        if saved is None:
            os.environ.pop("MUJOCO_GL", None)
        else:
            os.environ["MUJOCO_GL"] = saved
