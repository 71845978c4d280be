"""Learner registry: each learner chosen by name, like torchdiffeq's solvers."""

from __future__ import annotations

import dataclasses
import importlib
import time
from typing import Any

import torch

from lfd.demos import DemoSet
from lfd.errors import ConfigError, ModelError
from lfd.field import VelocityField
from lfd.learners.base import Learner
from lfd.modelfile import load_payload
from lfd.normalization import Normalization

_REGISTRY: dict[str, str] = {
    "node": "lfd.learners.node:NodeLearner",
    "contraction": "lfd.learners.contraction:ContractionLearner",
}
LEARNERS: tuple[str, ...] = tuple(_REGISTRY)


def get_learner(name: str) -> type[Learner]:
    """The learner class registered under ``name``."""
    if name not in _REGISTRY:
        raise ConfigError(f"unknown learner '{name}'; known: {', '.join(LEARNERS)}")
    mod, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(mod), cls)


def normalize_demos(demos: DemoSet, norm: Normalization) -> DemoSet:
    """The same demos in normalised coordinates x_n = (x - goal) / s."""
    return DemoSet(demos.t, norm.to_norm(demos.x), name=demos.name)


def train(learner: str, demos: DemoSet, seed: int = 0, progress: bool = True,
          **options: Any) -> VelocityField:
    """Fit a learner to demos and return its field. The same seed gives the same model."""
    cls = get_learner(learner)
    config = cls.make_config(**options)
    norm = Normalization.from_points(demos.x, demos.goal)
    torch.manual_seed(seed)
    module = cls.build(demos.dim, config)
    t0 = time.perf_counter()
    history = cls.fit(module, normalize_demos(demos, norm), config, progress)
    lo, hi = demos.bounds()
    history = {"train_time_s": time.perf_counter() - t0, "seed": seed,
               "demo_box": [lo.tolist(), hi.tolist()], **history}
    return cls.field_class(module, norm, learner, dataclasses.asdict(config), history)


def load(path: str) -> VelocityField:
    """Read a model file (never executes code) and rebuild its field."""
    payload = load_payload(path)
    try:
        cls = get_learner(str(payload["learner"]))
    except ConfigError as e:
        raise ModelError(f"{path}: {e}") from None
    try:
        config = cls.make_config(**payload["config"])
        module = cls.build(int(payload["dim"]), config).double()
        module.load_state_dict(payload["state_dict"])
    except (ConfigError, RuntimeError, KeyError, TypeError) as e:
        raise ModelError(f"{path}: model does not match its learner '{cls.name}' ({str(e).splitlines()[0]})") from None
    return cls.field_class(module, Normalization.from_dict(payload["normalization"]), cls.name,
                           dataclasses.asdict(config), payload.get("history") or {})
