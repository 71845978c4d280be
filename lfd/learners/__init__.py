"""Learner registry: each learner chosen by name, like torchdiffeq's solvers."""

from __future__ import annotations

import dataclasses
import importlib
import math
import time
from typing import Any

import torch

from lfd.demos import DemoSet
from lfd.demos.relative import relative_to_ends
from lfd.errors import ConfigError, ModelError, TrainingError
from lfd.field import VelocityField
from lfd.learners.base import Learner
from lfd.modelfile import load_payload
from lfd.normalization import Normalization

_REGISTRY: dict[str, str] = {
    "node": "lfd.learners.node:NodeLearner",
    "contraction": "lfd.learners.contraction:ContractionLearner",
    "tracking": "lfd.learners.tracking:TrackingLearner",
    "stable_node": "lfd.learners.stable_node:StableNodeLearner",
    "contracting_node": "lfd.learners.contracting_node:ContractingNodeLearner",
}
LEARNERS: tuple[str, ...] = tuple(_REGISTRY)


def get_learner(name: str) -> type[Learner]:
    """The learner class registered under ``name``."""
    if name not in _REGISTRY:
        raise ConfigError(f"unknown learner '{name}'; known: {', '.join(LEARNERS)}")
    mod, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(mod), cls)


def learner_module(name: str) -> str:
    """The dotted name of the module that defines the learner ``name`` (its code's fingerprint starts there)."""
    if name not in _REGISTRY:
        raise ConfigError(f"unknown learner '{name}'; known: {', '.join(LEARNERS)}")
    return _REGISTRY[name].split(":")[0]


def normalize_demos(demos: DemoSet, norm: Normalization) -> DemoSet:
    """The same demos in normalised coordinates x_n = (x - goal) / s."""
    return DemoSet(demos.t, norm.to_norm(demos.x), name=demos.name, end_tolerance=demos.end_tolerance)


MAX_SEED = 9_223_372_036_854_775_807  # 2^63 - 1, a literal (``lfd.commands.seed`` reads it unimported);
# torch.manual_seed and numpy's generators take any seed in [0, 2^63)
MAX_PARAMETERS = 20_000_000  # x 8 bytes x 4 (weights, gradients, Adam's moments; float64): beyond any demo's needs


def train(learner: str, demos: DemoSet, seed: int = 0, progress: bool = False,
          **options: Any) -> VelocityField:
    """Fit a learner to demos and return its field. The same seed gives the same model.

    Every demo is first moved to end at the demos' mean end (``lfd.demos.relative``, Eqs. (R1)-(R2)
    of docs/equations.md): the field learns each demo relative to its own end, its goal is the mean
    end, and ``field.toward(goal)`` runs it toward any other.

    ``seed`` is an integer in [0, 2^63 - 1]; a model of more than MAX_PARAMETERS parameters is
    refused before anything is allocated (ConfigError). A training that never reaches a finite
    loss, or ends with non-finite weights, raises TrainingError. Ctrl-C stops the learner's fit
    early: the field is returned with ``history["interrupted"]`` True, and callers must not take
    it for a finished training (the CLI exits 130, the model cache refuses it).
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"seed must be an integer between 0 and 2^63 - 1, got {str(seed)[:40]}")
    cls = get_learner(learner)
    config = cls.make_config(**effective_options(learner, demos, options))
    n_params = cls.parameter_count(6 if demos.has_orientation else demos.dim, config)
    if n_params is not None and n_params > MAX_PARAMETERS:
        raise ConfigError(f"{learner}: the model would have {n_params:,} parameters, more than the "
                          f"limit of {MAX_PARAMETERS:,}; use smaller layers")
    demos = relative_to_ends(demos)   # each demo relative to its own end, Eqs. (R1)-(R2): the goal is an input
    chart = None
    if demos.has_orientation:   # poses: the same learner on the chart's R^6 (lfd.pose, Eq. (P1))
        from lfd.pose import PoseChart, chart_demos

        chart = PoseChart.of(demos)
        demos = chart_demos(demos, chart)
    norm = Normalization.from_points(demos.x, demos.goal)
    torch.manual_seed(seed)
    module = cls.build(demos.dim, config)
    t0, cpu0 = time.perf_counter(), time.process_time()
    history = cls.fit(module, normalize_demos(demos, norm), config, progress)
    if not history.get("interrupted"):
        _check_trained(learner, module, history)
    history = {"train_time_s": time.perf_counter() - t0, "train_cpu_s": time.process_time() - cpu0,
               "seed": seed, **history}
    return cls.field_class(module, norm, learner, dataclasses.asdict(config), history,
                           demo_box=demos.bounds(), chart=chart)


def effective_options(learner: str, demos: DemoSet, options: dict[str, Any]) -> dict[str, Any]:
    """The options ``train`` fits with: ``options``, and for poses the tracking learner's
    ``end_at_goal`` (the reference ends at the goal pose exactly, Eq. (T1b), not only to the weight
    that pins each demo's spline there) unless given."""
    if demos.has_orientation and learner == "tracking":
        return {"end_at_goal": True, **options}
    return dict(options)


def _chart(entry: dict[str, Any] | None) -> Any:
    """The PoseChart of a model file's ``pose_chart`` entry, or None."""
    if entry is None:
        return None
    from lfd.pose import PoseChart

    return PoseChart.from_dict(entry)


def _check_trained(learner: str, module: torch.nn.Module, history: dict[str, Any]) -> None:
    """TrainingError if no finite loss was ever reached or the weights are not finite."""
    losses = [v for v in history.get("loss") or [] if isinstance(v, (int, float))]
    finite = [v for v in losses if math.isfinite(v)]
    never = (losses and not finite) or (history.get("stopped_nonfinite") and not finite)
    if never or not all(bool(torch.isfinite(p).all()) for p in module.parameters()):
        raise TrainingError(f"{learner}: training never reached a finite loss (the weights diverged); "
                            "lower the learning rate or the rate, or check the demos' units")


def load(path: str, allow_nonfinite: bool = False) -> VelocityField:
    """Read a model file (never executes code) and rebuild its field.

    Every failure, a corrupt or crafted file included, is a one-line ModelError naming ``path``;
    so are NaN or inf weights unless ``allow_nonfinite`` (for ``lfd certify``, which reports them).
    """
    payload = load_payload(path, allow_nonfinite)
    try:
        cls = get_learner(str(payload["learner"]))
    except ConfigError as e:
        raise ModelError(f"{path}: {e}") from None
    try:
        config = cls.make_config(**payload["config"])
        dim = int(payload["dim"])
        n_params = cls.parameter_count(dim, config)
        if n_params is not None and n_params > MAX_PARAMETERS:
            raise ConfigError(f"{n_params} parameters, more than {MAX_PARAMETERS}")
        module = cls.build(dim, config).double()
        module.load_state_dict(payload["state_dict"])
        return cls.field_class(module, Normalization.from_dict(payload["normalization"]), cls.name,
                               dataclasses.asdict(config), payload.get("history") or {},
                               demo_box=payload.get("demo_box"), chart=_chart(payload.get("pose_chart")))
    except Exception as e:  # noqa: BLE001  whatever a crafted config does to build: a bad file
        text = str(e).strip()
        reason = text.splitlines()[0][:200] if text else type(e).__name__
        raise ModelError(f"{path}: model does not match its learner '{cls.name}' ({reason})") from None
