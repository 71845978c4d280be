"""``lfd train``: fit a learner to demos and write the model file.

Only the options the user gives reach the learner, so each learner keeps its own defaults. Each
flag names a learner option (a field of the learner's Config); where learners spell one idea
differently the flag goes to the name the chosen learner has (``--iters`` -> ``iters`` or
``iterations``). Values are converted to the type of the option's default (``--hidden 32`` is the
int 32 for a learner whose default width is an int, the tuple (32,) for one whose default is a
tuple of widths). ``--option KEY=VALUE`` reaches any other option. An option the learner does not
have, or a bad value, is a ConfigError (exit 2).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from lfd.errors import ConfigError

# flag destination -> the learner option names it may stand for, first match wins
FLAG_OPTIONS: dict[str, tuple[str, ...]] = {
    "iters": ("iters", "iterations"),
    "hidden": ("hidden",),
    "activation": ("activation",),
    "lr": ("lr",),
    "solver": ("solver", "method"),
    "adjoint": ("adjoint",),
    "rate": ("rate",),
}
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


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("train", help="fit a learner to demos and save the model",
                              description=__doc__.split("\n\n")[0].splitlines()[0])
    p.add_argument("--learner", default="node", help="learner name: node or contraction (default node)")
    p.add_argument("--demos", required=True, metavar="SPEC",
                   help="spiral, spiral3d, lasa:NAME or a .csv/.npz file")
    p.add_argument("--out", required=True, metavar="PATH", help="model file to write (e.g. model.pt)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    g = p.add_argument_group("learner options (left out: the learner's default)")
    g.add_argument("--iters", type=int, help="training iterations")
    g.add_argument("--hidden", type=hidden_sizes, metavar="W1,W2,...", help="hidden layer widths")
    g.add_argument("--activation", help="activation function name")
    g.add_argument("--lr", type=float, help="learning rate")
    g.add_argument("--solver", help="ODE solver name (torchdiffeq)")
    g.add_argument("--adjoint", action=argparse.BooleanOptionalAction, default=None,
                   help="adjoint-method gradients")
    g.add_argument("--rate", type=float, help="contraction rate, 1/s (contraction learner)")
    g.add_argument("--option", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="any other learner option, e.g. --option batch=256 (repeatable)")
    return p


def learner_options(learner: str, args: argparse.Namespace) -> dict[str, Any]:
    """The options the user gave, named and typed as the learner's Config declares them."""
    from lfd.learners import get_learner

    defaults = _config_defaults(get_learner(learner).Config)
    options: dict[str, Any] = {}
    for flag, names in FLAG_OPTIONS.items():
        value = getattr(args, flag)
        if value is not None:
            name = next((n for n in names if n in defaults), names[0])
            options[name] = _coerce(learner, f"--{flag}", value, defaults.get(name))
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
    from lfd.demos import load_demos
    from lfd.learners import train

    options = learner_options(args.learner, args)
    demos = load_demos(args.demos)
    field = train(args.learner, demos, seed=args.seed, progress=not args.quiet, **options)
    field.save(args.out)
    loss = field.history.get("loss") or []
    loss_text = f"final loss {loss[-1]:.4g}" if loss else "no loss recorded"
    if field.history.get("interrupted"):
        loss_text += " (interrupted: best model so far kept)"
    if field.history.get("stopped_nonfinite"):
        loss_text += " (stopped on a non-finite loss: best model so far kept)"
    print(f"trained {field.learner} on {demos.name} ({demos.n_demos} demos x {demos.n_samples} "
          f"samples, {demos.dim}-D): {loss_text}, {field.history.get('train_time_s', 0.0):.1f} s, "
          f"saved {args.out}")
    return 0
