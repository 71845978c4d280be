"""Error types of the robots package. The CLI turns each into a one-line message and exit code 2."""

from __future__ import annotations


class RobotError(Exception):
    """A robot spec, file, frame, option or target is invalid (unknown robot, missing file, unknown frame, ...)."""
