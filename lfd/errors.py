"""Error types of the learning package. The CLI turns each into a one-line message and exit code 2."""

from __future__ import annotations


class LfdError(Exception):
    """Base class of every error that is the user's input, not a bug."""


class DemoError(LfdError):
    """A demonstration file or spec is missing, malformed or inconsistent."""


class ModelError(LfdError):
    """A model file is missing, corrupt, of an unknown format or learner."""


class ConfigError(LfdError):
    """A learner or command option has an invalid value."""


class TrainingError(LfdError):
    """Training failed on the user's data or options, e.g. it never reached a finite loss."""


class OutputError(LfdError):
    """An output path cannot be written, or would overwrite an input."""
