"""What a learner is: a config, a torch module on normalised coordinates, and a fit routine."""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import torch

from lfd.demos import DemoSet
from lfd.errors import ConfigError
from lfd.field import VelocityField


class Learner(ABC):
    """A way to learn a velocity field. Subclasses give, as class keywords, ``name``, ``config`` (a
    dataclass whose ``__post_init__`` raises ConfigError on bad values; ``Config``) and, optionally,
    ``field`` (``field_class``): ``class NodeLearner(Learner, name="node", config=NodeConfig, field=NodeField)``."""

    name: ClassVar[str]
    Config: ClassVar[type]
    field_class: ClassVar[type[VelocityField]] = VelocityField

    def __init_subclass__(cls, name: str | None = None, config: type | None = None,
                          field: type[VelocityField] | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if name is not None:
            cls.name = name
        if config is not None:
            cls.Config = config
        if field is not None:
            cls.field_class = field

    @classmethod
    def make_config(cls, **options: Any) -> Any:
        """Config from keyword options; unknown names and bad values raise ConfigError."""
        known = {f.name for f in dataclasses.fields(cls.Config)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ConfigError(f"{cls.name}: unknown option(s) {', '.join(unknown)}; "
                              f"known: {', '.join(sorted(known))}")
        try:
            return cls.Config(**options)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"{cls.name}: {e}") from None

    @classmethod
    def parameter_count(cls, dim: int, config: Any) -> int | None:
        """The number of parameters ``build(dim, config)`` would allocate, or None if unknown.

        Learners override this with arithmetic on the config. This fallback builds the module on
        torch's meta device (nothing is allocated, but its first use imports many modules and is
        slow); it returns None for a build that cannot run there (one that needs real data).
        """
        try:
            with torch.device("meta"):
                module = cls.build(dim, config)
            return int(sum(p.numel() for p in module.parameters()))
        except Exception:  # noqa: BLE001  a build that needs real data: no up-front size check
            return None

    @classmethod
    @abstractmethod
    def build(cls, dim: int, config: Any) -> torch.nn.Module:
        """A fresh module mapping x_n (B, d) -> dx_n/dt (B, d). Call after seeding torch."""

    @classmethod
    @abstractmethod
    def fit(cls, module: torch.nn.Module, demos: DemoSet, config: Any, progress: bool) -> dict[str, Any]:
        """Train ``module`` in place on normalised ``demos``; return the history dict
        (at least ``loss``: list of floats). Ctrl-C stops training and keeps the best module."""
