#!/usr/bin/env python
"""Run learned velocity fields on a simulated arm in closed loop, perturb them, score and film them.

With no flags: trains (or takes from .cache/models) a NODE and a contraction field on the spiral
demos, runs both on the Panda unperturbed, from a start 2 cm off the demo's and with a 20 N push,
and writes one MP4 per run and metrics.json into a fresh folder out/demo_arm_YYYYmmdd-HHMMSS/.
Scenarios: none, offset, push, goal (goal moved 2 cm), noise (joint-velocity noise); see
``sim.experiment.scenario``. Errors in the input (unknown
robot or frame, missing model, bad demos, unreachable placement) print one line and exit 2; a
diverging simulation exits 2 before anything is written.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, NoReturn, Sequence

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import sim  # noqa: E402  (sets MUJOCO_GL before mujoco is imported)

EXIT_USAGE, EXIT_INTERRUPTED = 2, 130
LEARNER_CHOICES = ("node", "contraction", "both")
DEFAULT_SCENARIOS = ("none", "offset", "push")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"demo_arm: error: {message} (see --help)\n")


def scenarios(text: str) -> tuple[str, ...]:
    """'all' -> every scenario; 'none,push' -> ('none', 'push')."""
    names = sim.SCENARIOS if text == "all" else tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [n for n in names if n not in sim.SCENARIOS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"unknown perturbation '{','.join(bad) or text}'; "
                                         f"use {', '.join(sim.SCENARIOS)}, all, or a comma list")
    return tuple(dict.fromkeys(names))


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="demo_arm.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="panda", help="planar, panda (default), or a .urdf/.xml file")
    p.add_argument("--ee-frame", help="tool frame name (needed for a robot file)")
    p.add_argument("--learner", choices=LEARNER_CHOICES, help="learner(s) to run (default: both, "
                   "or the learner of --model)")
    p.add_argument("--model", help="a trained model file instead of training")
    p.add_argument("--demos", default="spiral", help="spiral (default), spiral3d, lasa:NAME or a .csv/.npz file")
    p.add_argument("--perturb", type=scenarios, default=DEFAULT_SCENARIOS, metavar="|".join(sim.SCENARIOS) + "|all",
                   help="perturbation scenario(s): one name, a comma list, or all (default: none,offset,push)")
    p.add_argument("--seed", type=int, default=0, help="training and perturbation seed (default 0)")
    p.add_argument("--out", help="output folder (default: a fresh out/demo_arm_YYYYmmdd-HHMMSS)")
    p.add_argument("--video", help="video path (one run), or a base name: PATH_<learner>_<scenario>.mp4")
    p.add_argument("--no-video", action="store_true", help="skip rendering")
    p.add_argument("--json", help="metrics file (default OUT/metrics.json)")
    p.add_argument("--ik", choices=("dls", "pink"), default="dls", help="differential IK back-end (default dls)")
    p.add_argument("--actuation", choices=sim.ACTUATIONS, default="torque",
                   help="computed torque (default) or position servos; see scripts/bench_loop.py")
    p.add_argument("--plane", choices=("auto", "horizontal", "vertical"), default="auto",
                   help="task plane of a 2-D field on a spatial arm (auto: horizontal)")
    p.add_argument("--size-m", type=float, help="path size in metres (default 15%% of the reach)")
    p.add_argument("--control-hz", type=float, default=500.0, help="control rate in Hz (default 500)")
    p.add_argument("--iters", type=int, help="training iterations (default: the learner's)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def fresh_dir(base: Path) -> Path:
    """base, or base-1, base-2, ... : the first that does not exist yet."""
    path, k = base, 0
    while path.exists():
        k += 1
        path = Path(f"{base}-{k}")
    return path


def video_path(args: argparse.Namespace, out: Path, learner: str, name: str, single: bool) -> Path:
    if args.video is None:
        return out / f"{learner}_{name}.mp4"
    v = Path(args.video)
    if single:
        return v
    return v.with_name(f"{v.stem}_{learner}_{name}{v.suffix or '.mp4'}")


def fmt(value: Any, scale: float = 1.0, digits: int = 2) -> str:
    if value is None:
        return "never"
    return f"{value * scale:.{digits}f}"


def run(args: argparse.Namespace) -> int:
    import lfd
    from lfd.modelfile import atomic_write
    from robots import load_robot
    from sim.modelcache import cached_field

    progress = not args.quiet
    if args.model and args.learner == "both":
        raise lfd.ConfigError("--model holds one learner; leave out --learner or name that learner")
    if args.control_hz <= 0 or (args.size_m is not None and args.size_m <= 0):
        raise lfd.ConfigError("--control-hz and --size-m must be positive")
    demos = lfd.load_demos(args.demos)
    robot = load_robot(args.robot, args.ee_frame, actuation=args.actuation)
    fields: dict[str, lfd.VelocityField] = {}
    models: dict[str, dict[str, Any]] = {}
    if args.model:
        field = lfd.load(args.model)
        if args.learner and args.learner != field.learner:
            raise lfd.ConfigError(f"{args.model} holds a '{field.learner}' model, not '{args.learner}'")
        fields[field.learner] = field
        models[field.learner] = {"path": args.model, "trained_now": False}
    else:
        learners = ("node", "contraction") if args.learner in (None, "both") else (args.learner,)
        for name in learners:
            options = {} if args.iters is None else _iters_option(name, args.iters)
            t0 = time.perf_counter()
            field, path, trained = cached_field(name, demos, args.seed, options, progress=progress)
            fields[name] = field
            models[name] = {"path": str(path), "trained_now": trained, "options": options,
                            "train_time_s": field.history.get("train_time_s"),
                            "load_or_train_s": time.perf_counter() - t0}
            print(f"{name}: {'trained' if trained else 'cached'} model {path}", file=sys.stderr)
    for name, field in fields.items():
        if field.dim != demos.dim:
            raise lfd.ConfigError(f"the {name} model is {field.dim}-D but the demos {demos.name} are {demos.dim}-D")

    exp = sim.Experiment(robot, demos, plane=args.plane, size_m=args.size_m, control_hz=args.control_hz,
                         ik=args.ik, actuation=args.actuation)
    results: list[sim.RunResult] = []
    jobs = [(learner, name) for learner in fields for name in args.perturb]
    t_sim = time.perf_counter()
    for learner, name in jobs:
        if progress:
            print(f"running {learner} / {name}", file=sys.stderr)
        results.append(exp.run(fields[learner], name, seed=args.seed, progress=progress))
    t_sim = time.perf_counter() - t_sim

    out = Path(args.out) if args.out else fresh_dir(
        Path("out") / f"demo_arm_{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    runs: list[dict[str, Any]] = []
    t_video = time.perf_counter()
    for r in results:
        entry: dict[str, Any] = {"learner": r.learner, "scenario": r.scenario,
                                 "perturbations": [p.describe() for p in sim.scenario(r.scenario, args.seed)],
                                 "metrics": r.metrics}
        if not args.no_video:
            path = video_path(args, out, r.learner, r.scenario, single=len(results) == 1)
            if progress:
                print(f"rendering {path}", file=sys.stderr)
            entry["video"] = str(path)
            entry["video_frames"] = exp.render(r, path, progress=progress)
        runs.append(entry)
    t_video = time.perf_counter() - t_video
    report = {
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "command": sys.argv,
        "settings": {**exp.describe(), "seed": args.seed},
        "models": models,
        "runs": runs,
        "timing_s": {"simulation": t_sim, "video": t_video},
    }
    json_path = Path(args.json) if args.json else out / "metrics.json"
    atomic_write(json_path, lambda f: f.write(json.dumps(report, indent=2, default=_json_default).encode()))
    print_table(results)
    print(f"wrote {json_path}" + ("" if args.no_video else f" and {len(results)} video(s) into {out}"))
    return 0


def _iters_option(learner: str, iters: int) -> dict[str, int]:
    """{'iters': n} or {'iterations': n}, as the learner's Config names it."""
    from lfd import get_learner

    names = {f.name for f in dataclasses.fields(get_learner(learner).Config)}
    key = next((k for k in ("iters", "iterations") if k in names), None)
    if key is None:
        return {}
    return {key: iters}


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


def print_table(results: Sequence[sim.RunResult]) -> None:
    head = (f"{'learner':12s} {'scenario':9s} {'track mm':>9s} {'imit mm':>8s} {'dtw mm':>7s} {'goal mm':>8s} "
            f"{'maxdev mm':>9s} {'recov s':>8s} {'limits':>6s} {'step us':>8s} {'RTF':>5s}")
    print(head)
    for r in results:
        m = r.metrics
        push = "max_deviation_m" in m
        print(f"{r.learner:12s} {r.scenario:9s} {fmt(m['tracking_rmse_m'], 1e3):>9s} "
              f"{fmt(m['imitation_rmse_m'], 1e3):>8s} {fmt(m['imitation_dtw_m'], 1e3):>7s} "
              f"{fmt(m['final_goal_error_m'], 1e3):>8s} "
              f"{fmt(m['max_deviation_m'], 1e3) if push else '-':>9s} "
              f"{fmt(m['recovery_time_s']) if push else '-':>8s} {m['joint_limit_violations']:>6d} "
              f"{m['control_step_us']:>8.1f} {m['realtime_factor']:>5.1f}")


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    import torch

    import lfd
    from robots import RobotError

    torch.set_num_threads(1)  # small networks: a second intra-op thread only adds contention
    try:
        return run(args)
    except (lfd.LfdError, RobotError, sim.SimError) as e:
        print(f"demo_arm: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as e:
        print(f"demo_arm: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("demo_arm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
