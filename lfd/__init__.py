"""lfd: learn a task-space velocity field from demonstrations (NODE or contracting field)."""

from lfd.demos import DemoSet, LASA_SHAPES, lasa, load_demos, load_file, spiral, spiral3d
from lfd.errors import ConfigError, DemoError, LfdError, ModelError
from lfd.field import VelocityField
from lfd.learners import LEARNERS, get_learner, load, train
from lfd.normalization import Normalization

__all__ = [
    "ConfigError", "DemoError", "DemoSet", "LASA_SHAPES", "LEARNERS", "LfdError", "ModelError",
    "Normalization", "VelocityField", "get_learner", "lasa", "load", "load_demos", "load_file",
    "spiral", "spiral3d", "train",
]
