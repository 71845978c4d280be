"""robots: arm models in MuJoCo and Pinocchio from one source file, tool kinematics and differential IK.

The actuations a robot can be loaded with are ``robots.loader.ACTUATIONS``. The names below are
imported on first use: ``robots.controller`` and what it needs (Pinocchio kinematics, the DLS IK,
the limits and the limiter) import no MuJoCo, so a controller runs on a machine without it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from robots.errors import RobotError
    from robots.ik import IK_BACKENDS, DifferentialIK, solve_pose_ik
    from robots.kinematics import Kinematics
    from robots.loader import BUILTIN_ROBOTS, load_robot
    from robots.model import RobotModel

_WHERE = {"RobotError": "robots.errors", "IK_BACKENDS": "robots.ik", "DifferentialIK": "robots.ik",
          "solve_pose_ik": "robots.ik", "Kinematics": "robots.kinematics", "BUILTIN_ROBOTS": "robots.loader",
          "load_robot": "robots.loader", "RobotModel": "robots.model"}

__all__ = [
    "BUILTIN_ROBOTS", "DifferentialIK", "IK_BACKENDS", "Kinematics", "RobotError", "RobotModel", "load_robot",
    "solve_pose_ik",
]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'robots' has no attribute '{name}'")
