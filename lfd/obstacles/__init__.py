"""Task-space obstacles and obstacle avoidance for any velocity field, by modulation that keeps convergence.

- ``shapes``: the obstacle shapes (``Obstacle``, ``Sphere``, ``Box``, ``Capsule``): Gamma, normal, motion;
- ``parse``: command-line text -> shape (``parse_obstacle``);
- ``groups``: overlapping obstacles merged into one modulation unit;
- ``modulation``: Eqs. (O1)-(O3) of docs/equations.md around the units, batched and for one point
  (``_point_kernel``: the one-point arithmetic, as Python and compiled with numba);
- ``avoidance``: the avoiding fields (``AvoidingField``, ``PhasedAvoidingField``, ``avoid``);
- ``starts``: seeded starts outside the obstacles (``starts_outside``);
- ``scenes``: seeded obstacle scenes on and near a demonstrated path (``random_scene``).
"""

from lfd.obstacles.avoidance import MIN_GOAL_GAMMA as MIN_GOAL_GAMMA
from lfd.obstacles.avoidance import AvoidingField, PhasedAvoidingField, avoid
from lfd.obstacles.parse import parse_obstacle
from lfd.obstacles.scenes import random_scene
from lfd.obstacles.shapes import Box, Capsule, Obstacle, Sphere
from lfd.obstacles.starts import starts_outside

__all__ = ["Obstacle", "Sphere", "Box", "Capsule", "AvoidingField", "PhasedAvoidingField", "avoid", "parse_obstacle",
           "random_scene", "starts_outside"]
