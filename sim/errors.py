"""Error types of the simulation package. The CLI turns each into a one-line message and exit code 2."""

from __future__ import annotations


class SimError(Exception):
    """Base class of every simulation error that is the user's input or an unusable run, not a bug."""


class PlacementError(SimError):
    """The task-space path cannot be placed in the robot's reachable workspace."""


class SimulationError(SimError):
    """The simulation diverged (NaN state or a MuJoCo instability warning); nothing was written."""


class RenderError(SimError):
    """No OpenGL context could be opened for offscreen rendering, or the video could not be written."""
