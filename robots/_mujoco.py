"""MuJoCo, imported with rendering off (``robots.nogl``): the robots modules that use MuJoCo import it
from here, so its GL back-end is never chosen by a robot."""

from robots.nogl import rendering_off

with rendering_off():
    import mujoco

__all__ = ["mujoco"]
