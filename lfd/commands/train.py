"""``lfd train``: fit a learner to demos and write the model file.

Only the options the user gives reach the learner, so each learner keeps its own defaults. Each
flag names a learner option (a field of the learner's Config) of the same name (``--iterations``
-> ``iterations``, ``--max-condition`` -> ``max_condition``). Values are converted to the type of
the option's default (``--hidden 32`` is the int 32 for a learner whose default width is an int,
the tuple (32,) for one whose default is a tuple of widths). ``--option KEY=VALUE`` reaches any
other option. An option the learner does not have, or a bad value, is a ConfigError (exit 2).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from typing import Any

from lfd.errors import ConfigError

# the flags of the "learner options" group: each one's destination is the learner option it sets
FLAG_OPTIONS: tuple[str, ...] = ("iterations", "hidden", "activation", "lr", "solver", "adjoint", "rate",
                                 "max_condition")
_TRUE, _FALSE = {"1", "true", "yes", "on"}, {"0", "false", "no", "off"}


def hidden_sizes(text: str) -> tuple[int, ...]:
    """'64,64' -> (64, 64): comma-separated positive layer widths."""
    try:
        sizes = tuple(int(s) for s in text.split(","))
    except ValueError:
        sizes = ()
    if not sizes or any(s < 1 for s in sizes):
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers like 64,64, "
                                         f"got '{text}'")
    return sizes


def key_value(text: str) -> tuple[str, str]:
    """'lr=0.01' -> ('lr', '0.01')."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got '{text}'")
    return key.strip(), value.strip()


@functools.cache
def _registry() -> dict[str, str]:
    """The learner registry (name -> ``module:Class``), read from lfd/learners/__init__.py without
    importing torch."""
    from lfd.commands import source_constant

    return dict(source_constant("lfd.learners", "_REGISTRY"))


def learner_names() -> tuple[str, ...]:
    """The registered learners, read from lfd/learners/__init__.py without importing torch."""
    return tuple(_registry())


def preload(args: argparse.Namespace) -> tuple[str, ...]:
    """The modules ``run`` imports (``lfd.cli`` imports them first, with interrupts deferred): the
    demos, the field, the registry and the chosen learner's module, which imports what the learner
    needs (torchdiffeq, numba, ...) and nothing for the others."""
    entry = _registry().get(args.learner)
    learner = () if entry is None else (entry.split(":")[0],)   # an unknown name: ``run`` says so
    return ("torch", "numpy", "lfd.demos", "lfd.field", "lfd.learners", *learner)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    from lfd.commands import DEMOS_HELP, add_clean, seed, source_constant

    names = learner_names()
    share = source_constant("lfd.demos.recording", "LOUD_SHARE")
    p = subparsers.add_parser("train", help="fit a learner to demos and save the model",
                              description=__doc__.split("\n\n")[0].splitlines()[0])
    p.add_argument("--learner", default="node", metavar="{" + ",".join(names) + "}",
                   help=f"learner: {', '.join(names)} (default node)")
    p.add_argument("--demos", required=True, metavar="SPEC", help=DEMOS_HELP)
    add_clean(p)
    p.add_argument("--out", required=True, metavar="PATH", help="model file to write (e.g. model.pt)")
    p.add_argument("--seed", type=seed, default=0, help="random seed, 0 to 2^63 - 1 (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (there is none unless stderr is a "
                   f"terminal), and of the clean-up's notes only those of a step that removed, filled or moved "
                   f"more than {100 * share:g}%% of a demo's duration")
    g = p.add_argument_group("learner options (left out: the learner's default; a learner "
                             "without the option refuses it)")
    g.add_argument("--iterations", type=int, help="training iterations (node: Adam steps, contraction: "
                   "L-BFGS loss evaluations)")
    g.add_argument("--hidden", type=hidden_sizes, metavar="W1,W2,...",
                   help="hidden layer widths (node: a list; contraction: one width)")
    g.add_argument("--activation", help="activation function name (node)")
    g.add_argument("--lr", type=float, help="learning rate (node)")
    g.add_argument("--solver", help="ODE solver name, torchdiffeq (node)")
    g.add_argument("--adjoint", action=argparse.BooleanOptionalAction, default=None,
                   help="adjoint-method gradients (node)")
    g.add_argument("--rate", type=float, help="contraction rate, 1/s (contraction)")
    g.add_argument("--max-condition", type=float, metavar="KAPPA",
                   help="bound on b/a of the contraction metric, so the overshoot sqrt(b/a) <= sqrt(KAPPA); "
                        "inf for none (contraction; default 100)")
    g.add_argument("--option", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="any other learner option, e.g. --option batch=256 (repeatable)")
    return p


def learner_options(learner: str, args: argparse.Namespace) -> dict[str, Any]:
    """The options the user gave, named and typed as the learner's Config declares them."""
    from lfd.learners import get_learner

    defaults = _config_defaults(get_learner(learner).Config)
    options: dict[str, Any] = {}
    for name in FLAG_OPTIONS:
        value = getattr(args, name)
        if value is not None:
            options[name] = _coerce(learner, f"--{name}", value, defaults.get(name))
    for key, text in args.option:
        options[key] = _coerce(learner, key, text, defaults.get(key))
    return options


def _config_defaults(config_cls: type) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config_cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
        else:
            out[f.name] = None
    return out


def _coerce(learner: str, what: str, value: Any, default: Any) -> Any:
    """value (a string from --option, or an already typed flag value) -> the type of default."""
    try:
        if isinstance(default, bool):
            if isinstance(value, bool):
                return value
            if str(value).lower() in _TRUE | _FALSE:
                return str(value).lower() in _TRUE
            raise ValueError("expected true or false")
        if isinstance(default, int):
            if isinstance(value, tuple):
                if len(value) != 1:
                    raise ValueError(f"{learner} takes a single width, e.g. {default}")
                return value[0]
            return int(value)
        if isinstance(default, float):
            return float(value)
        if isinstance(default, (tuple, list)):
            seq = value if isinstance(value, tuple) else hidden_sizes(str(value))
            return type(default)(seq)
        return value
    except (ValueError, TypeError, argparse.ArgumentTypeError) as e:
        raise ConfigError(f"{learner}: bad value {value!r} for {what} ({e})") from None


def run(args: argparse.Namespace) -> int:
    import sys
    import warnings

    from lfd.commands import check_output, demo_clean, say_notes
    from lfd.demos import demo_warnings, load_demos
    from lfd.learners import train

    options = learner_options(args.learner, args)
    check_output(args.out, "--out", {"demo file": args.demos})
    demos = load_demos(args.demos, clean=demo_clean(args))
    say_notes(demos, quiet=args.quiet)
    for text in demo_warnings(demos):  # shown by lfd.cli as one line "lfd: warning: ..."
        warnings.warn(text, UserWarning, stacklevel=1)
    progress = not args.quiet and sys.stderr.isatty()  # a bar only on a terminal
    field = train(args.learner, demos, seed=args.seed, progress=progress, **options)
    if field.history.get("interrupted"):  # the learner stopped on Ctrl-C: never save a partial model
        raise KeyboardInterrupt
    field.save(args.out)
    loss = field.history.get("loss") or []
    loss_text = f"final loss {loss[-1]:.4g}" if loss else "no loss recorded"
    if field.history.get("stopped_nonfinite"):
        loss_text += " (stopped on a non-finite loss: best model so far kept)"
    kind = "poses" if demos.has_orientation else f"{demos.dim}-D"
    print(f"trained {field.learner} on {demos.name} ({demos.n_demos} demos x {demos.n_samples} "
          f"samples, {kind}): {loss_text}, {field.history.get('train_time_s', 0.0):.1f} s, "
          f"saved {args.out}")
    return 0
