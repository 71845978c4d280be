"""lfd: learn a task-space velocity field from demonstrations (NODE or contracting field).

The public names below are imported on first use (PEP 562), so that ``import lfd.cli`` and
``lfd --help`` do not pay for torch, scipy and matplotlib.
"""

from __future__ import annotations

import os

# Cross-process reproducibility. MKL picks alignment-dependent code paths: numpy buffers are only
# 16-byte aligned and their alignment varies between processes, which can change a contraction fit in
# its last digits through the lstsq of its initial A. The learners therefore copy
# numpy input into torch's 64-byte-aligned memory (torch.tensor, not from_numpy), and MKL's
# conditional numerical reproducibility is asked for here, before torch loads MKL.
os.environ.setdefault("MKL_CBWR", "COMPATIBLE")

from lfd.errors import ConfigError, DemoError, LfdError, ModelError
from lfd.lazy import lazy_getattr

# public name -> the module that defines it
_LAZY: dict[str, str] = {
    "DemoSet": "lfd.demos", "lasa": "lfd.demos", "load_demos": "lfd.demos", "spiral": "lfd.demos",
    "spiral3d": "lfd.demos",
    "VelocityField": "lfd.field",
    "LEARNERS": "lfd.learners", "get_learner": "lfd.learners", "load": "lfd.learners", "train": "lfd.learners",
    "Normalization": "lfd.normalization",
    "Obstacle": "lfd.obstacles", "avoid": "lfd.obstacles",
}

_SUBMODULES = ("demos", "field", "learners", "normalization", "metrics", "evaluation", "integrate", "io",
               "threads", "modelfile", "certify",
               "plotting", "commands", "cli", "bench", "obstacles", "goal")

TYPE_CHECKING = False  # not typing's: ``import lfd`` stays cheap for the programs' first lines
if TYPE_CHECKING:
    from lfd.demos import DemoSet, lasa, load_demos, spiral, spiral3d
    from lfd.field import VelocityField
    from lfd.learners import LEARNERS, get_learner, load, train
    from lfd.normalization import Normalization
    from lfd.obstacles import Obstacle, avoid


# ``import lfd; lfd.learners`` worked when this file imported the submodules eagerly
__getattr__ = lazy_getattr("lfd", _LAZY, _SUBMODULES)


__all__ = [
    "ConfigError", "DemoError", "DemoSet", "LEARNERS", "LfdError", "ModelError", "Normalization", "Obstacle",
    "VelocityField", "avoid", "get_learner", "lasa", "load", "load_demos", "spiral", "spiral3d", "train",
]
