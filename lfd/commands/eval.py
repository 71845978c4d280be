"""``lfd eval``: roll a model out from each demo's start and score it against the demos.

Prints a table (one row per demo, then the mean) and, with --json, writes the numbers
atomically: {"model", "learner", "demos", "goal", "dim", "n_demos", "dtw_step", "metrics",
"per_demo": [{metric: value}], "mean": {metric: value}}; a non-finite value is written as null.
With --goal the model runs toward that goal (``goal`` in the JSON; null: the demos' mean end).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from lfd.pose import PoseChart

MAX_EVAL_SAMPLES = 50_000  # samples per demo: a rollout of more steps takes minutes
LONG_EVAL_SAMPLES = 10_000  # beyond this, say on stderr that the rollout takes a while
UNITS = ("units: the demos' length unit U (cosine_error: none, in [0, 2]); dtw is a sum over samples, "
         "U; swept_area U^2; velocity_rmse U/s")


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    from lfd.commands import add_goal, add_model_and_demos

    p = subparsers.add_parser("eval", help="score a model's rollouts against demos",
                              description=__doc__.splitlines()[0])
    add_model_and_demos(p)
    add_goal(p)
    p.add_argument("--json", metavar="PATH", help="write the metrics to this JSON file")
    p.add_argument("--dtw-step", type=int, default=1, metavar="K",
                   help="DTW on every K-th sample (the LASA protocol uses 4; default 1)")
    return p


def run(args: argparse.Namespace) -> int:
    from lfd.commands import check_output, demo_clean, model_and_demos
    from lfd.errors import ConfigError, DemoError
    from lfd.evaluation import evaluate
    from lfd.field import StateSpace
    from lfd.io import write_json
    from lfd.metrics import dtw_step_for

    if args.dtw_step < 1:
        raise ConfigError(f"--dtw-step must be >= 1, got {args.dtw_step}")
    if args.json:
        check_output(args.json, "--json", {"model file": args.model, "demo file": args.demos})
    field, demos = model_and_demos(args.model, args.demos, goal=args.goal, clean=demo_clean(args))
    if demos.n_samples > MAX_EVAL_SAMPLES:
        raise DemoError(f"{demos.name}: {demos.n_samples} samples per demo, lfd eval rolls out at most "
                        f"{MAX_EVAL_SAMPLES}; resample the demos")
    if demos.n_samples > LONG_EVAL_SAMPLES:
        print(f"lfd: note: rolling out {demos.n_demos} demo(s) of {demos.n_samples} samples; this takes "
              "a while", file=sys.stderr)
    dtw_step = dtw_step_for(demos.n_samples, demos.n_samples, args.dtw_step)
    if dtw_step != args.dtw_step:
        print(f"lfd: note: DTW and Frechet on every {dtw_step}-th sample (the full "
              f"{demos.n_samples} x {demos.n_samples} matrix is too large)", file=sys.stderr)
    result = evaluate(field, demos, dtw_step=dtw_step)
    names = list(result["mean"])
    print(format_table(names, result["per_demo"], result["mean"]))
    print(UNITS)
    if field.space is StateSpace.POSE:
        print(f"a pose model: scored on chart points (lfd.pose), U = metres, a turn of one radian counting as "
              f"{cast('PoseChart', field.chart).length:g} m")
    if args.json:
        report = {"model": str(args.model), "learner": field.learner, "demos": demos.name,
                  "goal": None if args.goal is None else list(args.goal),
                  "dim": demos.dim, "n_demos": demos.n_demos, "dtw_step": dtw_step,
                  "metrics": names, "per_demo": result["per_demo"],
                  "mean": result["mean"]}
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0


def format_table(names: list[str], rows: list[dict[str, float]], mean: dict[str, float]) -> str:
    """A fixed-width table: a header, one line per demo, one line for the mean."""
    widths = [max(10, len(n)) + 2 for n in names]

    def line(label: str, row: dict[str, float]) -> str:
        return label.ljust(6) + "".join(f"{row[n]:{w}.4g}" for n, w in zip(names, widths))

    head = "demo".ljust(6) + "".join(n.rjust(w) for n, w in zip(names, widths))
    return "\n".join([head, *(line(str(i), r) for i, r in enumerate(rows)), line("mean", mean)])
