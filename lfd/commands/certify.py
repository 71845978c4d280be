"""``lfd certify``: check the contraction condition of a model on a dense grid (see ``lfd.certify``).

The box is --box, else the --demos box grown by 50%, else the training demos' box stored in the
model, grown by 50%. A contraction model is checked in its learned metric with its own rate; any
other model (a NODE) in the identity metric with --rate or 0.05/s. The box is also searched for
equilibria and closed orbits besides the goal (``lfd.equilibria``; rollouts of 10x the --demos'
duration): a spurious attractor, a closed orbit or a start that escapes makes it "not certified".
With --goal the model is checked as run toward that goal (the default box moves with it).
Prints the verdict, the equilibria and orbits and, with --json, writes the certificate atomically.
Exit code 0: certified; 1: not certified; 2: bad input.
"""

from __future__ import annotations

import argparse
from typing import Any

EXIT_NOT_CERTIFIED = 1
MAX_SAMPLES = 10_000_000  # grid points: ~1 GB of float64 work arrays in 3-D; beyond, refuse up front


def parse_box(text: str) -> tuple[Any, Any]:
    """'xmin,xmax,ymin,ymax(,zmin,zmax)' -> (lo, hi), each an array of shape (d,)."""
    import numpy as np

    try:
        v = [float(s) for s in text.split(",")]
    except ValueError:
        v = []
    if len(v) not in (4, 6):
        raise argparse.ArgumentTypeError(f"expected xmin,xmax,ymin,ymax or xmin,xmax,ymin,ymax,zmin,zmax, "
                                         f"got '{text}'")
    return np.asarray(v[0::2]), np.asarray(v[1::2])


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    from lfd.commands import MODEL_HELP, add_clean, add_goal, source_constant

    # read from lfd/certify.py without importing it (it imports torch; ``lfd --help`` stays fast)
    DEFAULT_SAMPLES, DEFAULT_TOLERANCE, IDENTITY_RATE = (  # noqa: N806
        source_constant("lfd.certify", n) for n in ("DEFAULT_SAMPLES", "DEFAULT_TOLERANCE", "IDENTITY_RATE"))
    p = subparsers.add_parser("certify", help="check a model's contraction condition on a grid",
                              description=__doc__.splitlines()[0])
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--box", type=parse_box, metavar="XMIN,XMAX,YMIN,YMAX[,ZMIN,ZMAX]",
                   help="box to check, user units; write --box=-1,1,-1,1 when it starts with a minus "
                        "(default: the demos' box grown by 50%%)")
    p.add_argument("--demos", metavar="SPEC",
                   help="take the box (grown by 50%%) and the duration of the search from these demos")
    add_clean(p)
    p.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, metavar="N",
                   help=f"at least N grid points, at most {MAX_SAMPLES} (default {DEFAULT_SAMPLES})")
    p.add_argument("--rate", type=float, metavar="LAMBDA",
                   help=f"rate to check, 1/s (default: the model's; {IDENTITY_RATE} for a model without a metric)")
    p.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE, metavar="TOL",
                   help="relative round-off slack: certified if worst <= -2 rate + TOL max(1, 2 rate) "
                        f"(default {DEFAULT_TOLERANCE:g})")
    p.add_argument("--no-equilibria", action="store_true",
                   help="skip the search for spurious attractors, closed orbits and escaping starts")
    add_goal(p)
    p.add_argument("--json", metavar="PATH", help="write the certificate to this JSON file")
    return p


def run(args: argparse.Namespace) -> int:
    from lfd.commands import check_output
    from lfd.errors import ConfigError

    if not 1 <= args.samples <= MAX_SAMPLES:
        raise ConfigError(f"--samples must be between 1 and {MAX_SAMPLES}, got {args.samples}")
    if args.json:
        check_output(args.json, "--json", {"model file": args.model, "demo file": args.demos})
    import numpy as np

    from lfd.certify import BOX_GROWTH, certify
    from lfd.io import write_json
    from lfd.learners import load

    duration = None
    lo: Any = None
    hi: Any = None
    if args.demos is not None:
        from lfd.commands import demo_clean, model_and_demos

        field, demos = model_and_demos(args.model, args.demos, allow_nonfinite=True, clean=demo_clean(args))
        lo, hi = demos.bounds(BOX_GROWTH)
        duration = float((demos.t[:, -1] - demos.t[:, 0]).mean())
    else:
        field = load(args.model, allow_nonfinite=True)
    if args.goal is not None:   # the model run toward the goal; a box from --demos moves with it
        moved = field.toward(np.asarray(args.goal, dtype=np.float64))
        if lo is not None:
            lo, hi = lo + (moved.goal - field.goal), hi + (moved.goal - field.goal)
        field = moved
    if args.box is not None:
        lo, hi = args.box
    cert = certify(field, lo, hi, samples=args.samples, rate=args.rate, tolerance=args.tolerance,
                   equilibria=not args.no_equilibria, duration=duration)
    print(cert.summary())
    if args.json:
        report = {"model": str(args.model), **cert.to_dict()}
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0 if cert.certified else EXIT_NOT_CERTIFIED
