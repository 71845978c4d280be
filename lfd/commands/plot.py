"""``lfd plot``: draw a model's field, demos, rollouts and loss curve into an image file, with the field's
spurious attractors and closed orbits (``lfd.equilibria``, in the demos' box grown by half) marked, and a
pose model's orientations over time."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

FORMATS = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
MAX_DPI = 1000  # the figure is about 12 x 5 inches: 1000 dpi is already 60 megapixels


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    from lfd.commands import add_goal, add_model_and_demos, seed

    p = subparsers.add_parser("plot", help="plot a model's field, rollouts and loss",
                              description=__doc__.splitlines()[0])
    add_model_and_demos(p)
    add_goal(p)
    p.add_argument("--out", required=True, metavar="PATH", help=f"image file ({', '.join(FORMATS)})")
    p.add_argument("--perturbed", type=int, default=8, metavar="N",
                   help="rollouts from N perturbed starts (default 8)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the perturbed starts (default 0)")
    p.add_argument("--dpi", type=int, default=120, help=f"resolution, 1 to {MAX_DPI} (default 120)")
    p.add_argument("--no-equilibria", action="store_true",
                   help="do not search for (nor mark) spurious attractors and closed orbits")
    p.add_argument("--obstacle", action="append", default=[], metavar="SPEC",
                   help="avoid an obstacle (repeatable, task units): sphere:x,y[,z],r | "
                        "box:x,y[,z],hx,hy[,hz] | capsule:x1,y1[,z1],x2,y2[,z2],r [;margin=M]")
    goal = p.add_mutually_exclusive_group()
    goal.add_argument("--goal-shift", metavar="T:DX,DY[,DZ]", help="move the goal by DX at time T [s]")
    goal.add_argument("--goal-path", metavar="FILE", help="goal trajectory: CSV t,x,y[,z] or NPZ t, x")
    return p


def run(args: argparse.Namespace) -> int:
    from lfd.commands import check_output, demo_clean, model_and_demos
    from lfd.errors import ConfigError
    from lfd.interrupts import say
    from lfd.io import atomic_write

    out = Path(args.out)
    if out.suffix.lower() not in FORMATS:
        raise ConfigError(f"{args.out}: unknown image type '{out.suffix}' (use {', '.join(FORMATS)})")
    if not 0 <= args.perturbed <= 1000 or not 1 <= args.dpi <= MAX_DPI:
        raise ConfigError(f"--perturbed must be between 0 and 1000 and --dpi between 1 and {MAX_DPI}")
    check_output(args.out, "--out", {"model file": args.model, "demo file": args.demos})
    from lfd import goal as moving_goal
    from lfd.obstacles import avoid, parse_obstacle

    obstacles = [parse_obstacle(text) for text in args.obstacle]
    shift = moving_goal.parse_goal_shift(args.goal_shift) if args.goal_shift else None
    path = moving_goal.load_goal_path(args.goal_path) if args.goal_path else None
    from lfd.equilibria import find_equilibria
    from lfd.plotting import draw_obstacles, field_figure

    field: Any   # a VelocityField, then maybe wrapped (moving goal, obstacles) with the same interface
    field, demos = model_and_demos(args.model, args.demos, goal=args.goal, clean=demo_clean(args))
    found = None
    if not args.no_equilibria:      # the learned field's own, before any obstacle or moving goal
        lo, hi = demos.bounds(grow=0.5)
        found = find_equilibria(field, lo, hi, float((demos.t[:, -1] - demos.t[:, 0]).mean()))
    if shift is not None:
        t0, dx = shift
        field = moving_goal.shift_goal(field, t0, cast(Sequence[float], dx))   # shift_goal takes arrays too
    if path is not None:
        field = moving_goal.follow_goal_path(field, *path)
    if obstacles:
        field = avoid(field, obstacles)
    fig = field_figure(field, demos, n_perturbed=args.perturbed, seed=args.seed, equilibria=found)
    draw_obstacles(fig.axes[0], obstacles)
    fmt = out.suffix.lower().lstrip(".")
    atomic_write(out, lambda f: fig.savefig(f, format=fmt, dpi=args.dpi))
    if found is not None and not found.clean:
        say(f"lfd: note: in the demos' box grown by half: {'; '.join(found.failures())} (attractors and "
            f"orbits marked; `lfd certify` lists them)")
    print(f"wrote {args.out}")
    return 0
