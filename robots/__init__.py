"""robots: arm models in MuJoCo and Pinocchio from one source file, tool kinematics and differential IK.

The actuations a robot can be loaded with are ``robots.loader.ACTUATIONS``.
"""

from robots.nogl import rendering_off

with rendering_off():   # MuJoCo picks its GL back-end at import; a robot renders nothing
    import mujoco  # noqa: F401

from robots.errors import RobotError  # noqa: E402
from robots.ik import IK_BACKENDS, DifferentialIK, solve_pose_ik  # noqa: E402
from robots.kinematics import Kinematics  # noqa: E402
from robots.loader import BUILTIN_ROBOTS, load_robot  # noqa: E402
from robots.model import RobotModel  # noqa: E402

__all__ = [
    "BUILTIN_ROBOTS", "DifferentialIK", "IK_BACKENDS", "Kinematics", "RobotError", "RobotModel", "load_robot",
    "solve_pose_ik",
]
