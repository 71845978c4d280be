"""The arm job's command line (``lfd-demo-arm``): flags ->
``sim.run.job.ArmJob`` -> ``sim.run.pipeline.run_job`` -> a results table.

Errors in the input print one line ``demo_arm: error: ...`` and exit 2 before any training or
simulation; Ctrl-C or SIGTERM exits 130 and leaves no output of the job behind.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NoReturn

from lfd.interrupts import run_main
from lfd.interrupts import say as _say

if TYPE_CHECKING:
    from sim.run.job import ArmJob

__all__ = ["build_parser", "job_from_args", "main"]

EXIT_USAGE = 2
PROG = "demo_arm"
DEFAULT_SCENARIOS = ("none", "offset", "push")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{PROG}: error: {message} (see --help)\n")


def _type(check: Any) -> Any:
    """An argparse type from a function that raises ValueError with the message to show."""
    def parse(text: str) -> Any:
        try:
            return check(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    parse.__name__ = check.__name__
    return parse


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


@_type
def scenarios(text: str) -> tuple[str, ...]:
    """'all' -> every scenario; 'none,push' -> ('none', 'push')."""
    from sim.run.experiment import SCENARIOS

    names = SCENARIOS if text == "all" else tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [n for n in names if n not in SCENARIOS]
    if bad or not names:
        raise ValueError(f"unknown perturbation '{','.join(bad) or text}'; use {', '.join(SCENARIOS)}, all, "
                         "or a comma list")
    return tuple(dict.fromkeys(names))


@_type
def one_scenario(text: str) -> str:
    from sim.run.experiment import SCENARIOS

    if text not in SCENARIOS:
        raise ValueError(f"unknown scenario '{text[:40]}'; use one of {', '.join(SCENARIOS)}")
    return text


@_type
def camera(text: str) -> Any:
    from sim.media.camera import CameraSpec

    return CameraSpec.parse(text)   # a camera name is checked once the robot is loaded


@_type
def frame_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"expected WIDTHxHEIGHT in pixels, e.g. 640x480, got '{text[:40]}'") from None
    if not (32 <= w <= 3840 and 32 <= h <= 2160):
        raise ValueError(f"video size must be 32..3840 x 32..2160 pixels, got {w}x{h}")
    if w % 2 or h % 2:
        raise ValueError(f"video width and height must be even (H.264), got {w}x{h}")
    return w, h


@_type
def frame_rate(text: str) -> float:
    v = _number(text)
    if not (math.isfinite(v) and 1.0 <= v <= 240.0):
        raise ValueError(f"--fps must be a number from 1 to 240, got '{text[:40]}'")
    return v


@_type
def grid_count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 2 <= n <= 9:
        raise ValueError(f"--grid must be an integer from 2 to 9, got '{text[:40]}'")
    return n


@_type
def vector3(text: str) -> tuple[float, float, float]:
    v = tuple(_number(s) for s in text.split(","))
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        raise ValueError(f"expected three numbers X,Y,Z, got '{text[:40]}'")
    return v[0], v[1], v[2]


def goal_vector(text: str) -> tuple[float, ...]:
    """A goal: 2 or 3 task coordinates, or a pose x,y,z,qw,qx,qy,qz (finite numbers)."""
    v = tuple(_number(s) for s in text.split(","))
    if len(v) not in (2, 3, 7) or not all(math.isfinite(c) for c in v):
        raise argparse.ArgumentTypeError(f"expected X,Y[,Z] or X,Y,Z,QW,QX,QY,QZ, got '{text[:60]}'")
    return v


def build_parser() -> argparse.ArgumentParser:
    """The flags of the arm job (every one an ``ArmJob`` field)."""
    from lfd import commands as lfd_commands  # the seed rule every command shares
    from robots.loader import ACTUATIONS
    from sim.run.experiment import SCENARIOS

    p = _Parser(prog="demo_arm.py", description="Run learned velocity fields on a simulated arm in closed "
                "loop, perturb them, score and film them.")
    p.add_argument("--robot", default="panda", help="planar, panda (default), or a .urdf/.xml file")
    p.add_argument("--ee-frame", help="tool frame name (needed for a robot file)")
    p.add_argument("--learner", metavar="NAME,...|both", help="learner(s) to run, comma-separated: node, "
                   "stable_node, contraction, tracking, or the DMP baseline dmp; both: node,contraction (default: "
                   "the job's default learners, or the learner of --model)")
    p.add_argument("--model", help="a trained model file instead of training")
    p.add_argument("--demos",
                   help="spiral (default), spiral3d, lasa:NAME, robottasks:TASK (poses), bag:PATH:/topic, "
                        "or a .csv/.npz file (with --task: the task's RoboTasks9 demos by default)")
    lfd_commands.add_clean(p)
    p.add_argument("--perturb", type=scenarios, default=DEFAULT_SCENARIOS, metavar="|".join(SCENARIOS) + "|all",
                   help="perturbation scenario(s): one name, a comma list, or all (default: none,offset,push)")
    p.add_argument("--seed", type=lfd_commands.seed, default=0,
                   help="training and perturbation seed, 0 to 2^63 - 1 (default 0)")
    p.add_argument("--out", help="output folder (default: a fresh out/demo_arm_YYYYmmdd-HHMMSS)")
    p.add_argument("--overwrite", action="store_true", help="replace a previous run's --out folder")
    p.add_argument("--video", help="video path (one run), or a base name: PATH_<learner>_<scenario>.mp4")
    p.add_argument("--no-video", action="store_true", help="skip rendering")
    v = p.add_argument_group("videos and plots")
    v.add_argument("--camera", type=camera, default=None, metavar="NAME|AZ,EL,DIST",
                   help="auto (default: the path seen from its plane's normal, tilted away from the arm), a "
                        "camera of the model (e.g. workspace), or azimuth,elevation,distance (deg, deg, m)")
    v.add_argument("--size", type=frame_size, default=None, metavar="WxH",
                   help="video size in pixels, even (default 640x480; 1280x480 side by side, 960x720 grid)")
    v.add_argument("--fps", type=frame_rate, default=30.0, help="video frames per simulated second (default 30)")
    v.add_argument("--side-by-side", nargs="?", const="push", default=None, type=one_scenario, metavar="SCENARIO",
                   help="also one video of node, contraction and tracking under one scenario (default push)")
    v.add_argument("--grid", type=grid_count, default=None, metavar="N",
                   help="also one video of N pushes (2-9), seeds --seed .. --seed+N-1, of the first learner")
    v.add_argument("--table", action="store_true", help="put the robot on a table")
    v.add_argument("--no-plots", action="store_true", help="skip the figures (time series are still saved)")
    p.add_argument("--json", help="metrics file (default OUT/metrics.json)")
    p.add_argument("--ik", choices=("dls", "pink"), default="dls", help="differential IK back-end (default dls)")
    p.add_argument("--actuation", choices=ACTUATIONS, default="torque",
                   help="computed torque (default) or position servos")
    p.add_argument("--plane", choices=("auto", "horizontal", "vertical"), default="auto",
                   help="task plane of a 2-D field on a spatial arm (auto: horizontal)")
    p.add_argument("--size-m", type=float, help="path size in metres (default 15%% of the reach)")
    g = p.add_argument_group("placement of the demos on the robot (default: centred on the tool at the "
                             "home posture, --size-m across)")
    g.add_argument("--placement", choices=("auto", "recorded"), default="auto",
                   help="recorded: 3-D demos where they were recorded, metres in the robot's base frame "
                        "(demos of poses always run where recorded)")
    g.add_argument("--origin", type=vector3, metavar="X,Y,Z", help="world position (m) of the demos' box centre")
    g.add_argument("--scale", type=float, metavar="M_PER_UNIT", help="metres per demo unit (overrides --size-m)")
    g.add_argument("--shift", type=vector3, metavar="DX,DY,DZ",
                   help="demos of poses (which run where recorded): translate them by this, m")
    g = p.add_argument_group("the push scenario (default: 20 N for 0.2 s at t = 1 s, seeded direction)")
    g.add_argument("--push-force", type=float, default=20.0, metavar="N", help="force in newtons")
    g.add_argument("--push-start", type=float, default=1.0, metavar="S", help="start time in seconds")
    g.add_argument("--push-duration", type=float, default=0.2, metavar="S", help="duration in seconds")
    g.add_argument("--push-direction", type=vector3, metavar="X,Y,Z", help="world direction (default: from --seed)")
    p.add_argument("--obstacle", action="append", default=[], metavar="SHAPE:NUMBERS",
                   help="an obstacle in task units (repeatable): sphere:x,y[,z],r, box:x,y[,z],hx,hy[,hz] or "
                        "capsule:x1,y1[,z1],x2,y2[,z2],r, optionally ';margin=M' and ';velocity=VX,VY[,VZ]'; "
                        "the field keeps the tool point the hand's size plus M clear of it")
    p.add_argument("--no-arm-clearance", action="store_true",
                   help="keep only the tool point clear of obstacles and table (no collision dampers in the IK "
                        "for the rest of the arm, no hand margin)")
    p.add_argument("--goal", type=goal_vector, metavar="X,Y[,Z[,QW,QX,QY,QZ]]",
                   help="run every field toward this goal instead of the demos' mean end, in the demos' frame "
                        "(task units; a pose: metres and a unit quaternion, or the position alone)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--goal-shift", metavar="T:DX,DY[,DZ]", help="move the goal by DX (task units) at T s")
    g.add_argument("--goal-path", metavar="FILE", help="the goal follows this trajectory: CSV t,x,y[,z] or NPZ t, x")
    p.add_argument("--via", action="append", default=[], metavar="X,Y[,Z][@S]",
                   help="a point the tracking learner's motion passes through (repeatable), task units, "
                        "near phase S in [0.05, 0.95] if given (default: the nearest point of its path)")
    p.add_argument("--speed", type=float, default=1.0, metavar="S",
                   help="run every learned motion S times faster (below 1: slower), 0.05 to 20 (default 1)")
    p.add_argument("--control-hz", type=float, default=500.0, help="control rate in Hz (default 500)")
    p.add_argument("--limiter", action="store_true",
                   help="stream joint velocities as a real arm takes them: the robot's controller "
                        "(robots.controller) with an online jerk-limited limiter within its published limits; "
                        "use with --control-hz 1000 for the Franka's rate")
    p.add_argument("--held-out", type=int, metavar="K",
                   help="train on every demo but demo K and run from its start (a held-out run)")
    p.add_argument("--task", help="a task with objects: pour (a cup of balls in the hand, a bowl on the table; "
                                  "each run scored by whether 10 of 12 balls land in the bowl), place (a bottle "
                                  "in the hand, let go on a shelf; scored by whether it stands on its spot) or lid "
                                  "(a box's lid swung open by its handle; scored by whether it opens past 60 deg)")
    p.add_argument("--target", type=goal_vector, metavar="X,Y[,Z]",
                   help="where the task's object stands (the bowl's centre on the table; the bottle's spot, Z the "
                        "shelf's top), m, robot base frame; the goal follows it")
    p.add_argument("--limits", metavar="FILE",
                   help="the arm's limits as JSON (robots.limits.load_limits: q_min, q_max, dq_max, ddq_max, "
                        "dddq_max, ...; default: the robot's published ones, or its model's)")
    p.add_argument("--iters", type=int, help="training iterations (default: the learner's)")
    p.add_argument("--quiet", action="store_true", help="print only the results table and errors")
    return p


def job_from_args(args: argparse.Namespace, command: Sequence[str] = ()) -> ArmJob:
    """The ``ArmJob`` of parsed flags."""
    from lfd import commands as lfd_commands
    from sim.run.job import ArmJob, PushSpec

    learners = None if args.learner is None else (
        ("node", "contraction") if args.learner == "both"
        else tuple(s.strip() for s in args.learner.split(",") if s.strip()))
    return ArmJob(
        robot=args.robot, ee_frame=args.ee_frame, learners=learners, model=args.model, demos=args.demos,
        clean=lfd_commands.demo_clean(args),
        scenarios=args.perturb, seed=args.seed, out=args.out, overwrite=args.overwrite, json=args.json,
        video=args.video, videos=not args.no_video, plots=not args.no_plots, camera=args.camera, size=args.size,
        fps=args.fps, side_by_side=args.side_by_side, grid=args.grid, table=args.table, ik=args.ik,
        actuation=args.actuation, plane=args.plane, size_m=args.size_m, placement=args.placement,
        origin=args.origin, scale=args.scale, shift=args.shift,
        push=PushSpec(args.push_force, args.push_start, args.push_duration, args.push_direction),
        obstacles=tuple(args.obstacle), goal=args.goal, goal_shift=args.goal_shift, goal_path=args.goal_path,
        arm_clearance=not args.no_arm_clearance, speed=args.speed, via=tuple(args.via), control_hz=args.control_hz,
        limiter=args.limiter, limits=args.limits, task=args.task, target=args.target,
        held_out=args.held_out, iters=args.iters,
        quiet=args.quiet, command=tuple(command))


def _fmt(value: Any, scale: float = 1.0, digits: int = 2) -> str:
    return "never" if value is None else f"{value * scale:.{digits}f}"


def print_table(results: Sequence[Any]) -> None:
    """One line of scores per run on stdout."""
    contacts = any("obstacle_contacts" in r.metrics for r in results)
    w = max([12, *(len(r.learner) for r in results)])   # the learner column fits the longest name
    print(f"{'learner':{w}s} {'scenario':9s} {'track mm':>9s} {'imit mm':>8s} {'dtw mm':>7s} {'goal mm':>8s} "
          f"{'maxdev mm':>9s} {'recov s':>8s} {'limits':>6s} {'step us':>8s} {'RTF':>5s}"
          + (f" {'contacts':>8s}" if contacts else ""))
    for r in results:
        m = r.metrics
        push = "max_deviation_m" in m
        print(f"{r.learner:{w}s} {r.scenario:9s} {_fmt(m['tracking_rmse_m'], 1e3):>9s} "
              f"{_fmt(m['imitation_rmse_m'], 1e3):>8s} {_fmt(m['imitation_dtw_m'], 1e3):>7s} "
              f"{_fmt(m['final_goal_error_m'], 1e3):>8s} "
              f"{_fmt(m['max_deviation_m'], 1e3) if push else '-':>9s} "
              f"{_fmt(m['recovery_time_s']) if push else '-':>8s} {m['joint_limit_violations']:>6d} "
              f"{m['control_step_us']:>8.1f} {m['realtime_factor']:>5.1f}"
              + (f" {m.get('obstacle_contacts', '-'):>8}" if contacts else ""))


def _load() -> Any:
    """The job's modules (imported with interrupts deferred); returns the program."""
    import lfd.learners  # noqa: F401
    import sim.run.pipeline  # noqa: F401

    return _run


def _run(argv: Sequence[str] | None) -> int:
    import warnings

    import lfd
    from lfd.threads import torch_threads
    from robots import RobotError
    from sim.errors import SimError
    from sim.run.pipeline import run_job

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    with torch_threads(1), warnings.catch_warnings():   # small networks: one intra-op thread
        warnings.showwarning = _show_warning
        try:
            report = run_job(job_from_args(args, sys.argv if argv is None else ["demo_arm.py", *argv]))
        except BrokenPipeError:
            raise
        except (lfd.LfdError, RobotError, SimError) as e:
            _say(f"{PROG}: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
            return EXIT_USAGE
        except OSError as e:
            _say(f"{PROG}: error: {e.filename or ''}: {e.strerror or e}")
            return EXIT_USAGE
    print_table(report.results + [r for r in report.side_by_side if r not in report.results])
    print(f"wrote {report.json_path}" + ("" if args.no_video else f" and {report.n_videos} video(s) into {report.out}"))
    return 0


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:
    text = str(message).strip()
    _say(f"{PROG}: warning: {text.splitlines()[0] if text else category.__name__}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the arm job of the command line ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    SIGINT and SIGTERM end it with ``demo_arm: interrupted`` and exit code 130 (``lfd.interrupts``)."""
    return run_main(PROG, _load, argv)
