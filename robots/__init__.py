"""robots: arm models in MuJoCo and Pinocchio from one source file, tool kinematics and differential IK.

The actuations a robot can be loaded with are ``robots.loader.ACTUATIONS``.
"""

import os as _os


def _import_mujoco_without_gl() -> None:
    """Import MuJoCo with rendering off (``MUJOCO_GL=disable`` for that import only): MuJoCo picks
    its GL back-end at import, and a bad or missing one must not stop a robot from loading
    (``sim.gl`` chooses and checks the back-end where videos are rendered)."""
    saved = _os.environ.get("MUJOCO_GL")
    _os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco  # noqa: F401
    finally:
        if saved is None:
            _os.environ.pop("MUJOCO_GL", None)
        else:
            _os.environ["MUJOCO_GL"] = saved


_import_mujoco_without_gl()

from robots.errors import RobotError  # noqa: E402
from robots.ik import IK_BACKENDS, DifferentialIK, solve_position_ik  # noqa: E402
from robots.kinematics import Kinematics  # noqa: E402
from robots.loader import BUILTIN_ROBOTS, load_robot  # noqa: E402
from robots.model import RobotModel  # noqa: E402

__all__ = [
    "BUILTIN_ROBOTS", "DifferentialIK", "IK_BACKENDS", "Kinematics", "RobotError", "RobotModel", "load_robot",
    "solve_position_ik",
]
