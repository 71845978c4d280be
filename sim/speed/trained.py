"""The learned fields that the arm's speed measurements (``ik``, ``loop``) run: options to choose them
and the call that trains them (or takes them from ``lfd.cache``'s model cache, or a model file).
"""

from __future__ import annotations

import argparse
from typing import Any

import lfd
from lfd.cache import cached_field
from lfd.errors import ConfigError
from robots.loader import ACTUATIONS
from sim.run.parsing import names

__all__ = ["QUICK_TRAINING", "add_field_arguments", "demos_of", "field_of"]

#: ``--quick``: a learner's options for a field trained in a moment (not cached)
QUICK_TRAINING: dict[str, dict[str, Any]] = {"node": {"iterations": 2}, "contraction": {"iterations": 2}}
#: ``--quick``: the demos' duration (s), whatever ``--demos`` says: a short spiral, short runs
QUICK_DURATION_S = 1.0


def add_field_arguments(ap: argparse.ArgumentParser, learners: str) -> None:
    """``--learner`` (default ``learners``), ``--model``, ``--demos`` and ``--actuation``."""
    ap.add_argument("--learner", default=learners,
                    help="learner(s) of the field, comma-separated (trained and cached if needed)")
    ap.add_argument("--model", help="a model file instead of training")
    ap.add_argument("--demos", default="spiral")
    ap.add_argument("--actuation", default="torque", choices=ACTUATIONS)


def demos_of(args: argparse.Namespace) -> lfd.DemoSet:
    """The demos of ``--demos``; ``--quick``: a spiral of ``QUICK_DURATION_S``."""
    return lfd.spiral(duration=QUICK_DURATION_S) if args.quick else lfd.load_demos(args.demos)


def field_of(args: argparse.Namespace) -> tuple[lfd.DemoSet, list[Any]]:
    """(demos, fields) of the options of ``add_field_arguments``: the model file, else each learner's
    field on the demos with its defaults from the model cache (``--quick``: a short spiral, 2 iterations,
    not cached)."""
    demos = demos_of(args)
    if not args.model and not names(args.learner):
        raise ConfigError("--learner: none given")
    if args.model:
        return demos, [lfd.load(args.model)]
    if args.quick:
        return demos, [lfd.train(name, demos, seed=0, progress=False, **QUICK_TRAINING.get(name, {}))
                       for name in names(args.learner)]
    return demos, [cached_field(name, demos)[0] for name in names(args.learner)]
