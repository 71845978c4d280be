"""robots: arm models in MuJoCo and Pinocchio from one source file, tool kinematics and differential IK.

The actuations a robot can be loaded with are ``robots.loader.ACTUATIONS``.
"""

from robots.errors import RobotError
from robots.ik import IK_BACKENDS, DifferentialIK, solve_position_ik
from robots.kinematics import Kinematics
from robots.loader import BUILTIN_ROBOTS, load_robot
from robots.model import RobotModel

__all__ = [
    "BUILTIN_ROBOTS", "DifferentialIK", "IK_BACKENDS", "Kinematics", "RobotError", "RobotModel", "load_robot",
    "solve_position_ik",
]
