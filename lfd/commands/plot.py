"""``lfd plot``: draw a model's field, demos, rollouts and loss curve into an image file."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

FORMATS = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("plot", help="plot a model's field, rollouts and loss",
                              description=__doc__.splitlines()[0])
    p.add_argument("model", help="model file written by 'lfd train'")
    p.add_argument("--demos", required=True, metavar="SPEC",
                   help="spiral, spiral3d, lasa:NAME or a .csv/.npz file")
    p.add_argument("--out", required=True, metavar="PATH", help=f"image file ({', '.join(FORMATS)})")
    p.add_argument("--perturbed", type=int, default=8, metavar="N",
                   help="rollouts from N perturbed starts (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the perturbed starts (default 0)")
    p.add_argument("--dpi", type=int, default=120, help="resolution (default 120)")
    return p


def run(args: argparse.Namespace) -> int:
    from lfd.commands import model_and_demos
    from lfd.errors import ConfigError
    from lfd.modelfile import atomic_write
    from lfd.plotting import field_figure

    out = Path(args.out)
    if out.suffix.lower() not in FORMATS:
        raise ConfigError(f"{args.out}: unknown image type '{out.suffix}' (use {', '.join(FORMATS)})")
    if args.perturbed < 0 or args.dpi < 1:
        raise ConfigError("--perturbed must be >= 0 and --dpi >= 1")
    field, demos = model_and_demos(args.model, args.demos)
    fig = field_figure(field, demos, n_perturbed=args.perturbed, seed=args.seed)
    fmt = out.suffix.lower().lstrip(".")
    atomic_write(out, lambda f: fig.savefig(f, format=fmt, dpi=args.dpi))
    print(f"wrote {args.out}")
    return 0
