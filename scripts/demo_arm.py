#!/usr/bin/env python
"""Run learned velocity fields on a simulated arm in closed loop, perturb them, score and film them.

With no flags: trains (or takes from .cache/models) a NODE and a contraction field on the spiral
demos, runs both on the Panda unperturbed, from a start 2 cm off the demo's and with a 20 N push,
and writes one MP4 per run, its time series (.npz) and figures (.png), and metrics.json into a fresh
folder out/demo_arm_YYYYmmdd-HHMMSS/ (--side-by-side and --grid add comparison videos; see --help).
Scenarios: none, offset, push, goal (goal moved 2 cm), noise (joint-velocity noise); see
``sim.experiment.scenario``. Errors in the input (unknown
robot or frame, missing model, bad demos, unreachable placement) print one line and exit 2; a
diverging simulation exits 2 before anything is written. Output paths are checked before any
training or simulation; a run that fails or is interrupted (Ctrl-C or SIGTERM: exit 130) while
writing removes what it wrote, so no incomplete output folder is left behind.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

EXIT_USAGE, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 2, 130, 141


_PENDING: list[int] = []  # signals that arrived during the start-up imports


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _defer_interrupt(signum: int, frame: Any) -> None:
    """During the start-up imports: remember the signal (an interrupt inside an import can surface
    as another error); a second one ends the process at once."""
    if _PENDING:
        print("demo_arm: interrupted", file=sys.stderr)
        os._exit(EXIT_INTERRUPTED)
    _PENDING.append(signum)


def _interrupts_now() -> None:
    """From here on SIGINT and SIGTERM raise KeyboardInterrupt (cleanup runs, exit 130); one that
    came during the imports is raised now."""
    import signal

    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _raise_interrupt)
    except ValueError:  # not the main thread (imported by a test runner's worker): leave them
        return
    if _PENDING:
        _PENDING.clear()
        raise KeyboardInterrupt


if __name__ == "__main__":  # SIGINT and SIGTERM wait until the start-up imports are done
    import signal

    signal.signal(signal.SIGINT, _defer_interrupt)
    signal.signal(signal.SIGTERM, _defer_interrupt)

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

try:
    import numpy as np  # noqa: E402

    import sim  # noqa: E402  (sets MUJOCO_GL before mujoco is imported)
    from robots.loader import ACTUATIONS  # noqa: E402
    from sim.camera import CameraSpec  # noqa: E402
    from sim.experiment import scenario  # noqa: E402
except KeyboardInterrupt:  # Ctrl-C during the start-up imports: no traceback
    print("demo_arm: interrupted", file=sys.stderr)
    sys.exit(EXIT_INTERRUPTED)

LEARNER_CHOICES = ("node", "contraction", "tracking", "both")
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
    p.add_argument("--seed", type=seed, default=0, help="training and perturbation seed, 0 to 2^63 - 1 "
                   "(default 0)")
    p.add_argument("--out", help="output folder (default: a fresh out/demo_arm_YYYYmmdd-HHMMSS)")
    p.add_argument("--video", help="video path (one run), or a base name: PATH_<learner>_<scenario>.mp4")
    p.add_argument("--no-video", action="store_true", help="skip rendering")
    v = p.add_argument_group("videos and plots")
    v.add_argument("--camera", type=camera, default=None, metavar="NAME|AZ,EL,DIST",
                   help="auto (default: looks at the path from its plane's normal, tilted away from the "
                        "arm, the path across half the frame), a camera of the model (e.g. workspace), or "
                        "azimuth,elevation,distance (deg, deg, m) around the path's centre")
    v.add_argument("--size", type=frame_size, default=None, metavar="WxH",
                   help="video size in pixels, even numbers (default 640x480; 1280x480 with "
                        "--side-by-side, 960x720 with --grid); panels share it")
    v.add_argument("--fps", type=frame_rate, default=30.0, help="video frames per simulated second (default 30)")
    v.add_argument("--side-by-side", nargs="?", const="push", default=None, type=one_scenario, metavar="SCENARIO",
                   help="also one video of node, contraction and tracking under the same scenario (default "
                        "push), one labelled panel each: side_by_side_SCENARIO.mp4")
    v.add_argument("--grid", type=grid_count, default=None, metavar="N",
                   help="also one video of N pushes (2-9), seeds --seed .. --seed+N-1, of the first learner "
                        "in a grid: grid_push_LEARNER.mp4")
    v.add_argument("--table", action="store_true", help="put the robot on a table")
    v.add_argument("--no-plots", action="store_true", help="skip the figures (time series are still saved)")
    p.add_argument("--json", help="metrics file (default OUT/metrics.json)")
    p.add_argument("--ik", choices=("dls", "pink"), default="dls", help="differential IK back-end (default dls)")
    p.add_argument("--actuation", choices=ACTUATIONS, default="torque",
                   help="computed torque (default) or position servos; see scripts/bench_loop.py")
    p.add_argument("--plane", choices=("auto", "horizontal", "vertical"), default="auto",
                   help="task plane of a 2-D field on a spatial arm (auto: horizontal)")
    p.add_argument("--size-m", type=float, help="path size in metres (default 15%% of the reach)")
    g = p.add_argument_group("placement of the demos on the robot (default: centred on the tool at the "
                             "home posture, --size-m across)")
    g.add_argument("--placement", choices=("auto", "recorded"), default="auto",
                   help="recorded: run 3-D demos exactly where they were recorded, positions in metres "
                        "in the robot's base frame (the model's world frame); auto (default): see above")
    g.add_argument("--origin", type=vector3, metavar="X,Y,Z",
                   help="world position (m) of the centre of the demos' bounding box (auto placement)")
    g.add_argument("--scale", type=float, metavar="M_PER_UNIT",
                   help="metres per demo unit (auto placement; overrides --size-m)")
    g = p.add_argument_group("the push scenario (default: 20 N for 0.2 s at t = 1 s, seeded direction)")
    g.add_argument("--push-force", type=float, default=20.0, metavar="N", help="force in newtons")
    g.add_argument("--push-start", type=float, default=1.0, metavar="S", help="start time in seconds")
    g.add_argument("--push-duration", type=float, default=0.2, metavar="S", help="duration in seconds")
    g.add_argument("--push-direction", type=vector3, metavar="X,Y,Z",
                   help="world direction (normalised; default: drawn from --seed)")
    p.add_argument("--obstacle", action="append", default=[], metavar="SHAPE:NUMBERS",
                   help="an obstacle in task units (repeatable): sphere:x,y[,z],r, box:x,y[,z],hx,hy[,hz] or "
                        "capsule:x1,y1[,z1],x2,y2[,z2],r, optionally ';margin=M' and ';velocity=VX,VY[,VZ]' "
                        "(it moves, units/s). The fields avoid it (lfd.avoid), the scene holds it as a "
                        "MuJoCo geom (moving with it), the controller adds a 10 ms phase lead "
                        "(sim.controller.Gains.lead_s), and each run reports its robot-obstacle contacts "
                        "and smallest clearance")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--goal-shift", metavar="T:DX,DY[,DZ]",
                   help="move the goal by DX (task units) at time T (s) of every run, blended in over "
                        "0.5 s (lfd.goal.shift_goal); the fields re-centre on it during the run")
    g.add_argument("--goal-path", metavar="FILE",
                   help="the goal follows this trajectory during every run: CSV rows t,x,y[,z] (task "
                        "units) or NPZ with t (T,) and x (T, d) (lfd.goal.follow_goal_path)")
    p.add_argument("--control-hz", type=float, default=500.0, help="control rate in Hz (default 500)")
    p.add_argument("--iters", type=int, help="training iterations (default: the learner's)")
    p.add_argument("--quiet", action="store_true", help="print only the results table and errors "
                   "(progress bars appear only on a terminal anyway)")
    return p


def camera(text: str) -> Any:
    """argparse type of --camera: a ``sim.camera.CameraSpec`` (a name is checked after loading the robot)."""
    from sim.camera import CameraSpec

    try:
        return CameraSpec.parse(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def frame_size(text: str) -> tuple[int, int]:
    """argparse type of --size: 'WxH', even integers, 32..3840 by 32..2160."""
    parts = text.lower().split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 640x480, got '{text[:40]}'") from None
    if not (32 <= w <= 3840 and 32 <= h <= 2160):
        raise argparse.ArgumentTypeError(f"video size must be 32..3840 x 32..2160 pixels, got {w}x{h}")
    if w % 2 or h % 2:
        raise argparse.ArgumentTypeError(f"video width and height must be even (H.264), got {w}x{h}")
    return w, h


def frame_rate(text: str) -> float:
    """argparse type of --fps: a number in [1, 240]."""
    import math

    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and 1.0 <= v <= 240.0):
        raise argparse.ArgumentTypeError(f"--fps must be a number from 1 to 240, got '{text[:40]}'")
    return v


def one_scenario(text: str) -> str:
    """argparse type: one scenario name."""
    if text not in sim.SCENARIOS:
        raise argparse.ArgumentTypeError(f"unknown scenario '{text[:40]}'; use one of {', '.join(sim.SCENARIOS)}")
    return text


def grid_count(text: str) -> int:
    """argparse type of --grid: an integer from 2 to 9."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 2 <= n <= 9:
        raise argparse.ArgumentTypeError(f"--grid must be an integer from 2 to 9, got '{text[:40]}'")
    return n


def vector3(text: str) -> tuple[float, float, float]:
    """argparse type: 'x,y,z' -> three finite floats."""
    import math

    try:
        v = tuple(float(s) for s in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got '{text[:40]}'")
    return v  # type: ignore[return-value]


def perturbations(args: argparse.Namespace, name: str) -> tuple[Any, ...]:
    """The perturbations of scenario ``name``, the push taking its --push-* flags."""
    return push_of(args, args.seed) if name == "push" else scenario(name, args.seed)


def check_push(args: argparse.Namespace) -> None:
    import math

    import lfd

    if not (math.isfinite(args.push_force) and 0 <= args.push_force <= 1000):
        raise lfd.ConfigError(f"--push-force must be between 0 and 1000 N, got {args.push_force:g}")
    if not (math.isfinite(args.push_start) and args.push_start >= 0):
        raise lfd.ConfigError(f"--push-start must be a time >= 0 s, got {args.push_start:g}")
    if not (math.isfinite(args.push_duration) and 0 < args.push_duration <= 60):
        raise lfd.ConfigError(f"--push-duration must be in (0, 60] s, got {args.push_duration:g}")
    if args.push_direction is not None and not any(args.push_direction):
        raise lfd.ConfigError("--push-direction must not be zero")


def placement(args: argparse.Namespace, robot: Any, demos: Any) -> Any:
    """The placement the flags ask for, or None for the Experiment's default."""
    import numpy as np

    import lfd

    if args.placement == "recorded":
        if args.origin is not None or args.scale is not None or args.size_m is not None:
            raise lfd.ConfigError("--placement recorded takes no --origin, --scale or --size-m")
        if demos.dim != 3:
            raise lfd.ConfigError(f"--placement recorded needs 3-D demos, {demos.name} are {demos.dim}-D")
        return sim.Placement(np.zeros(3), np.eye(3), 1.0, 3)
    if args.origin is None and args.scale is None:
        return None
    if args.scale is not None and not (np.isfinite(args.scale) and args.scale > 0):
        raise lfd.ConfigError(f"--scale must be a positive number, got {args.scale:g}")
    auto = sim.Placement.auto(robot, demos.x, plane=args.plane, size_m=args.size_m)
    lo, hi = demos.bounds()
    center = (lo + hi) / 2
    scale = auto.scale if args.scale is None else float(args.scale)
    target = auto.to_world(center) if args.origin is None else np.asarray(args.origin, dtype=np.float64)
    return sim.Placement(target - scale * auto.axes @ center, auto.rotation, scale, auto.dim)


def seed(text: str) -> int:
    """argparse type of --seed: an integer in [0, 2^63 - 1] (lfd's rule, see lfd.commands.seed)."""
    from lfd.commands import seed as lfd_seed

    return lfd_seed(text)


class Outputs:
    """The files and folders one run writes: checked before the work, removed again if the run
    fails or is interrupted before it completes (no incomplete output folder)."""

    def __init__(self) -> None:
        self.files: list[Path] = []
        self.dirs: list[Path] = []

    def check(self, path: Path, what: str, inputs: dict[str, str | None]) -> None:
        from lfd.commands import check_output

        check_output(str(path), what, inputs)

    def make_dir(self, path: Path) -> None:
        """mkdir -p, remembering each folder it created."""
        missing = []
        p = path
        while not p.exists():
            missing.append(p)
            p = p.parent
        path.mkdir(parents=True, exist_ok=True)
        self.dirs.extend(reversed(missing))

    def rollback(self) -> None:
        for f in self.files:
            try:
                f.unlink()
            except OSError:
                pass
        for d in reversed(self.dirs):
            try:
                d.rmdir()
            except OSError:  # not empty: something else is in it
                pass


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


SIDE_BY_SIDE_LEARNERS = ("node", "contraction", "tracking")


@dataclasses.dataclass
class Plan:
    """Every file one run writes, decided (and checked) before any work."""

    videos: dict[tuple[str, str], Path]
    series: dict[tuple[str, str], Path]
    plots: dict[tuple[str, str], Path]
    extra_plots: dict[str, Path]
    side_by_side: Path | None
    grid: Path | None


def plan_outputs(args: argparse.Namespace, out: Path, json_path: Path, learners: list[str],
                 outputs: Outputs, inputs: dict[str, str | None]) -> Plan:
    import lfd

    single = len(learners) * len(args.perturb) == 1
    beside = json_path.parent
    plan = Plan({}, {}, {}, {}, None, None)
    for learner in learners:
        for name in args.perturb:
            if not args.no_video:
                plan.videos[learner, name] = video_path(args, out, learner, name, single)
            plan.series[learner, name] = beside / f"{learner}_{name}.npz"
            if not args.no_plots:
                plan.plots[learner, name] = beside / f"{learner}_{name}.png"
    if not args.no_plots:
        plan.extra_plots["paths"] = beside / "paths.png"
        for learner in learners:
            plan.extra_plots[f"loss_{learner}"] = beside / f"loss_{learner}.png"
    if args.side_by_side and not args.no_video:
        plan.side_by_side = out / f"side_by_side_{args.side_by_side}.mp4"
    if args.grid and not args.no_video:
        plan.grid = out / f"grid_push_{learners[0]}.mp4"
    every = [*plan.videos.values(), *plan.series.values(), *plan.plots.values(), *plan.extra_plots.values(),
             *(p for p in (plan.side_by_side, plan.grid) if p is not None)]
    for path in every:
        if same_path(path, json_path):
            raise lfd.ConfigError(f"{path}: an output and --json would be the same file")
        outputs.check(path, "output", inputs)
    return plan


def run(args: argparse.Namespace) -> int:
    import lfd
    from lfd.cache import cached_field
    from lfd.obstacles import MIN_GOAL_GAMMA, parse_obstacle
    from robots import load_robot
    from sim.controller import Gains
    from sim.obstacles import obstacle_contacts

    progress = not args.quiet and sys.stderr.isatty()  # bars only on a terminal
    verbose = not args.quiet
    if args.model and args.learner == "both":
        raise lfd.ConfigError("--model holds one learner; leave out --learner or name that learner")
    if args.control_hz <= 0 or (args.size_m is not None and args.size_m <= 0):
        raise lfd.ConfigError("--control-hz and --size-m must be positive")
    check_push(args)
    outputs = Outputs()
    out = Path(args.out) if args.out else fresh_dir(
        Path("out") / f"demo_arm_{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}")
    json_path = Path(args.json) if args.json else out / "metrics.json"
    if out.exists() and not out.is_dir():
        raise lfd.ConfigError(f"{out}: --out exists and is not a folder")
    inputs = {"model file": args.model, "demo file": args.demos}
    outputs.check(json_path, "--json", inputs)
    n_runs = (1 if args.model or args.learner not in (None, "both") else 2) * len(args.perturb)
    planned = [args.learner or "node"] if n_runs == len(args.perturb) else ["node", "contraction"]
    plan = plan_outputs(args, out, json_path, planned, outputs, inputs)
    demos = lfd.load_demos(args.demos)
    obstacles = [parse_obstacle(text, demos.dim) for text in args.obstacle]
    goal_motion = parse_goal_motion(args, demos.dim)
    for o in obstacles:
        if float(o.gamma(demos.goal)) < MIN_GOAL_GAMMA:
            raise lfd.ConfigError(f"the demos' goal lies inside or too close to the {o.describe()}")
    robot = load_robot(args.robot, args.ee_frame, actuation=args.actuation, table=args.table)
    if args.camera is not None:
        try:
            args.camera.check(robot.mj_model)
        except ValueError as e:
            raise lfd.ConfigError(str(e)) from None
    # the placement (reachability) and the push are checked before any training
    exp = sim.Experiment(robot, demos, placement=placement(args, robot, demos), plane=args.plane,
                         size_m=args.size_m, control_hz=args.control_hz, ik=args.ik, fps=args.fps)
    if obstacles:  # the same placement, on a scene that also holds the obstacles (moving ones move)
        exp = sim.Experiment(robot, demos, placement=exp.placement, control_hz=args.control_hz, ik=args.ik,
                             fps=args.fps, obstacles=obstacles, gains=Gains(lead_s=OBSTACLE_LEAD_S))
        robot = exp.robot
    if goal_motion is not None:
        check_goal_motion(goal_motion, exp, demos, obstacles)
    pushes = "push" in args.perturb or args.side_by_side == "push" or args.grid
    if pushes and args.push_start + args.push_duration > exp.duration_s:
        raise lfd.ConfigError(f"the push ends at {args.push_start + args.push_duration:g} s, after the run "
                              f"({exp.duration_s:g} s)")
    fields: dict[str, lfd.VelocityField] = {}
    models: dict[str, dict[str, Any]] = {}

    def train(name: str) -> None:
        options = {} if args.iters is None else _iters_option(name, args.iters)
        t0 = time.perf_counter()
        field, path, trained = cached_field(name, demos, args.seed, options, progress=progress, verbose=verbose)
        fields[name] = field
        models[name] = {"path": str(path), "trained_now": trained, "options": options,
                        "train_time_s": field.history.get("train_time_s"),
                        "load_or_train_s": time.perf_counter() - t0}
        if verbose:
            print(f"{name}: {'trained' if trained else 'cached'} model {path}", file=sys.stderr)

    if args.model:
        field = lfd.load(args.model)
        if args.learner and args.learner != field.learner:
            raise lfd.ConfigError(f"{args.model} holds a '{field.learner}' model, not '{args.learner}'")
        fields[field.learner] = field
        models[field.learner] = {"path": args.model, "trained_now": False}
    else:
        for name in ("node", "contraction") if args.learner in (None, "both") else (args.learner,):
            train(name)
    main_learners = list(fields)
    if args.side_by_side:
        for name in SIDE_BY_SIDE_LEARNERS:
            if name not in fields:
                train(name)
    for name, field in fields.items():
        if field.dim != demos.dim:
            raise lfd.ConfigError(f"the {name} model is {field.dim}-D but the demos {demos.name} are {demos.dim}-D")
    for name, field in fields.items():
        if (obstacles or goal_motion is not None) and hasattr(field, "rollout_with_phase"):
            flag = "--obstacle" if obstacles else "--goal-shift/--goal-path"
            raise lfd.ConfigError(f"{flag} does not apply to the {name} learner yet (its phase state)")
        if goal_motion is not None:
            field = fields[name] = moving(field, goal_motion)
        if obstacles:
            fields[name] = lfd.avoid(field, obstacles)
    if main_learners != planned:  # --model named its own learner: the planned names follow it
        plan = plan_outputs(args, out, json_path, main_learners, Outputs(), inputs)

    results: list[sim.RunResult] = []
    t_sim = time.perf_counter()
    for learner in main_learners:
        for name in args.perturb:
            if verbose:
                print(f"running {learner} / {name}", file=sys.stderr)
            results.append(exp.run(fields[learner], name, perturbations(args, name), seed=args.seed,
                                   progress=progress))
    side: list[sim.RunResult] = []
    if args.side_by_side:
        for learner in SIDE_BY_SIDE_LEARNERS:
            done = [r for r in results if r.learner == learner and r.scenario == args.side_by_side]
            if verbose and not done:
                print(f"running {learner} / {args.side_by_side} (side by side)", file=sys.stderr)
            side.append(done[0] if done else exp.run(fields[learner], args.side_by_side,
                                                     perturbations(args, args.side_by_side), seed=args.seed,
                                                     progress=progress))
    grid: list[sim.RunResult] = []
    for i in range(args.grid or 0):
        if verbose:
            print(f"running {main_learners[0]} / push, seed {args.seed + i} (grid)", file=sys.stderr)
        grid.append(exp.run(fields[main_learners[0]], "push", push_of(args, args.seed + i),
                            seed=args.seed + i, progress=progress))
    t_sim = time.perf_counter() - t_sim
    if obstacles:
        for r in {id(r): r for r in results + side + grid}.values():
            report = obstacle_contacts(robot, r.rollout.q, r.rollout.t, r.rollout.mocap_pos)
            r.metrics.update(obstacle_contacts=report.contacts, obstacle_steps_in_contact=report.steps_in_contact,
                             obstacle_min_clearance_m=report.min_clearance_m)

    try:
        _write_outputs(args, exp, results, side, grid, fields, models, plan, json_path, outputs, t_sim,
                       progress, verbose)
    except BaseException:
        outputs.rollback()
        raise
    print_table(results + [r for r in side if r not in results])
    n_videos = len(plan.videos) + (plan.side_by_side is not None) + (plan.grid is not None)
    print(f"wrote {json_path}" + ("" if args.no_video else f" and {n_videos} video(s) into {out}"))
    return 0


#: the controller's phase lead with --obstacle (``sim.controller.Gains.lead_s``; the Panda's measured lag)
OBSTACLE_LEAD_S = 0.01


def parse_goal_motion(args: argparse.Namespace, dim: int) -> tuple[str, Any] | None:
    """The goal's motion of --goal-shift (``("shift", (t, dx))``) or --goal-path (``("path", (times,
    goals))``), read and checked (``lfd.ConfigError``), or None."""
    import lfd
    from lfd import goal as moving_goal

    if args.goal_shift:
        return "shift", moving_goal.parse_goal_shift(args.goal_shift, dim)
    if args.goal_path:
        times, goals = moving_goal.load_goal_path(args.goal_path)
        if goals.ndim != 2 or goals.shape[1] != dim:
            raise lfd.ConfigError(f"--goal-path {args.goal_path}: {goals.shape[-1]}-D goals for {dim}-D demos")
        return "path", (times, goals)
    return None


def check_goal_motion(motion: tuple[str, Any], exp: Any, demos: Any, obstacles: list[Any]) -> None:
    """Every goal the run will visit must be reachable and clear of the obstacles (as the demos'
    goal is), and a shift must come before the run ends; checked before any training."""
    import lfd
    from lfd.obstacles import MIN_GOAL_GAMMA
    from sim.errors import PlacementError

    kind, spec = motion
    if kind == "shift":
        t, dx = spec
        if t >= exp.duration_s:
            raise lfd.ConfigError(f"--goal-shift at t = {t:g} s comes after the run ends ({exp.duration_s:g} s)")
        goals = np.stack([demos.goal, demos.goal + dx])
    else:
        goals = spec[1]
    flag = "--goal-shift" if kind == "shift" else "--goal-path"
    for o in obstacles:
        if float(np.min(o.gamma(goals))) < MIN_GOAL_GAMMA:
            raise lfd.ConfigError(f"{flag}: the moving goal comes inside or too close to the {o.describe()}")
    try:
        exp.placement.check_reachable(exp.robot, goals, rotation=exp.rotation_ref)
    except PlacementError as e:
        raise lfd.ConfigError(f"{flag}: the moving goal leaves the arm's reach ({e})") from None


def moving(field: Any, motion: tuple[str, Any]) -> Any:
    """``field`` re-centred on the moving goal (``lfd.goal.shift_goal`` / ``follow_goal_path``)."""
    from lfd import goal as moving_goal

    kind, spec = motion
    return moving_goal.shift_goal(field, *spec) if kind == "shift" else moving_goal.follow_goal_path(field, *spec)


def describe_goal_motion(args: argparse.Namespace) -> dict[str, Any] | None:
    """--goal-shift / --goal-path for metrics.json."""
    from lfd.goal import BLEND_S

    if args.goal_shift:
        return {"shift": args.goal_shift, "blend_s": BLEND_S}
    if args.goal_path:
        return {"path": str(args.goal_path), "blend_s": BLEND_S}
    return None


def push_of(args: argparse.Namespace, seed_: int) -> tuple[Any, ...]:
    """The push of the --push-* flags with direction drawn from ``seed_`` (unless --push-direction)."""
    return (sim.Push(force_n=args.push_force, duration_s=args.push_duration, start_s=args.push_start,
                     direction=args.push_direction, seed=seed_),)


def same_path(a: Path, b: Path) -> bool:
    from lfd.io import same_file

    return same_file(a, b)


def _write_outputs(args: argparse.Namespace, exp: Any, results: list[Any], side: list[Any], grid: list[Any],
                   fields: dict[str, Any], models: dict[str, Any], plan: Plan, json_path: Path,
                   outputs: Outputs, t_sim: float, progress: bool, verbose: bool) -> None:
    """Videos, time series, figures, then metrics.json (atomically, last); every file and folder
    noted in outputs (removed again if anything fails)."""
    from lfd.io import write_json
    from sim import timeseries

    camera_ = args.camera or CameraSpec()
    size = args.size or (640, 480)

    def new_file(path: Path) -> Path:
        outputs.make_dir(path.parent)
        if not path.exists():
            outputs.files.append(path)
        return path

    runs: list[dict[str, Any]] = []
    t_video = t_files = 0.0
    for r in results:
        key = (r.learner, r.scenario)
        entry = run_entry(r)
        t0 = time.perf_counter()
        ts = timeseries.arrays(r, exp.placement, exp.robot)
        timeseries.save(new_file(plan.series[key]), ts)
        entry["timeseries"] = str(plan.series[key])
        if key in plan.plots:
            _save_figure(new_file(plan.plots[key]), _run_figure(ts, r))
            entry["plot"] = str(plan.plots[key])
        t_files += time.perf_counter() - t0
        if key in plan.videos:
            path = plan.videos[key]
            if verbose:
                print(f"rendering {path}", file=sys.stderr)
            entry["video"] = str(path)
            t0 = time.perf_counter()
            entry["video_frames"] = exp.render(r, new_file(path), size[0], size[1], args.fps, progress, camera_)
            t_video += time.perf_counter() - t0
        runs.append(entry)
    report: dict[str, Any] = {}
    if side and plan.side_by_side is not None:
        if verbose:
            print(f"rendering {plan.side_by_side}", file=sys.stderr)
        w, h = args.size or (1280, 480)
        t0 = time.perf_counter()
        frames = exp.render(side, new_file(plan.side_by_side), w, h, args.fps, progress, camera_,
                            titles=[f"{r.learner} / {r.scenario}" for r in side])
        report["side_by_side"] = {"video": str(plan.side_by_side), "video_frames": frames,
                                  "render_s": time.perf_counter() - t0,
                                  "runs": [run_entry(r) for r in side]}
        t_video += report["side_by_side"]["render_s"]
    if grid and plan.grid is not None:
        if verbose:
            print(f"rendering {plan.grid}", file=sys.stderr)
        w, h = args.size or (960, 720)
        t0 = time.perf_counter()
        seeds = [args.seed + i for i in range(len(grid))]
        frames = exp.render(grid, new_file(plan.grid), w, h, args.fps, progress, camera_,
                            titles=[f"{r.learner} / push, seed {s}" for r, s in zip(grid, seeds)])
        report["grid"] = {"video": str(plan.grid), "video_frames": frames, "seeds": seeds,
                          "runs": [{"seed": s, **run_entry(r)} for r, s in zip(grid, seeds)]}
        t_video += time.perf_counter() - t0
    t0 = time.perf_counter()
    if "paths" in plan.extra_plots:
        from sim.plots import paths_figure

        goal = np.asarray(next(iter(fields.values())).goal)
        label_runs = [(f"{r.learner} / {r.scenario}", exp.placement.to_task(r.rollout.ee)) for r in results]
        _save_figure(new_file(plan.extra_plots["paths"]),
                     paths_figure(exp.demos.x, label_runs, goal, f"tool paths over the demos {exp.demos.name}"))
        for learner in {r.learner for r in results}:
            path = plan.extra_plots.get(f"loss_{learner}")
            if path is not None and fields[learner].history.get("loss"):
                from matplotlib.figure import Figure

                from lfd.plotting import draw_loss

                fig = Figure(figsize=(7, 4.5), layout="constrained")
                draw_loss(fig.add_subplot(), fields[learner].history, fields[learner].config)
                _save_figure(new_file(path), fig)
    t_files += time.perf_counter() - t0
    report = {
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "command": sys.argv,
        "settings": {**exp.describe(), "seed": args.seed, "goal_motion": describe_goal_motion(args), "video": {
            "size": list(size), "fps": args.fps, "camera": args.camera.name if args.camera else "auto"}},
        "models": models,
        "runs": runs,
        **report,
        "timing_s": {"simulation": t_sim, "video": t_video, "series_and_plots": t_files},
    }
    outputs.make_dir(json_path.parent)
    write_json(json_path, report)


def run_entry(r: sim.RunResult) -> dict[str, Any]:
    """A run's entry in metrics.json: learner, scenario, the perturbations it ran with (taken from
    the result, ``RunResult.perturbations``, each ``describe()``) and its metrics."""
    return {"learner": r.learner, "scenario": r.scenario,
            "perturbations": [p.describe() for p in r.perturbations], "metrics": r.metrics}


def _run_figure(ts: dict[str, Any], r: Any) -> Any:
    from sim.plots import run_figure

    return run_figure(ts, r.rollout.hold_window_s)


def _save_figure(path: Path, fig: Any) -> None:
    """Save a matplotlib Figure as PNG atomically."""
    import io

    from lfd.io import atomic_write

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    atomic_write(path, lambda f: f.write(buf.getvalue()))


def _iters_option(learner: str, iters: int) -> dict[str, int]:
    """{'iters': n} or {'iterations': n}, as the learner's Config names it."""
    from lfd import get_learner

    names = {f.name for f in dataclasses.fields(get_learner(learner).Config)}
    key = next((k for k in ("iters", "iterations") if k in names), None)
    if key is None:
        return {}
    return {key: iters}


def print_table(results: Sequence[sim.RunResult]) -> None:
    head = (f"{'learner':12s} {'scenario':9s} {'track mm':>9s} {'imit mm':>8s} {'dtw mm':>7s} {'goal mm':>8s} "
            f"{'maxdev mm':>9s} {'recov s':>8s} {'limits':>6s} {'step us':>8s} {'RTF':>5s}")
    contacts = any("obstacle_contacts" in r.metrics for r in results)
    print(head + (f" {'contacts':>8s}" if contacts else ""))
    for r in results:
        m = r.metrics
        push = "max_deviation_m" in m
        print(f"{r.learner:12s} {r.scenario:9s} {fmt(m['tracking_rmse_m'], 1e3):>9s} "
              f"{fmt(m['imitation_rmse_m'], 1e3):>8s} {fmt(m['imitation_dtw_m'], 1e3):>7s} "
              f"{fmt(m['final_goal_error_m'], 1e3):>8s} "
              f"{fmt(m['max_deviation_m'], 1e3) if push else '-':>9s} "
              f"{fmt(m['recovery_time_s']) if push else '-':>8s} {m['joint_limit_violations']:>6d} "
              f"{m['control_step_us']:>8.1f} {m['realtime_factor']:>5.1f}"
              + (f" {m.get('obstacle_contacts', '-'):>8}" if contacts else ""))


def main(argv: Sequence[str] | None = None) -> int:
    from lfd.cli import run_guarded

    return run_guarded(_main, argv, "demo_arm")


def _main(argv: Sequence[str] | None) -> int:
    import warnings

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    import torch

    import lfd
    import lfd.demos  # noqa: F401  (preloaded while interrupts wait: scipy, torchdiffeq)
    import lfd.learners  # noqa: F401
    from robots import RobotError

    if __name__ == "__main__" or _PENDING:
        _interrupts_now()
    torch.set_num_threads(1)  # small networks: a second intra-op thread only adds contention
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            return run(args)
        except BrokenPipeError:
            raise
        except (lfd.LfdError, RobotError, sim.SimError) as e:
            print(f"demo_arm: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
            return EXIT_USAGE
        except OSError as e:
            print(f"demo_arm: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
            return EXIT_USAGE


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:
    text = str(message).strip()
    print(f"demo_arm: warning: {text.splitlines()[0] if text else category.__name__}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
