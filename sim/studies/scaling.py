"""Scaling curves in one report: the learners' training time, single-point time and accuracy against
the dimension, the number of demos and the samples per demo, and the control step's cost against the
number of obstacles and the robot; writes reports/scaling.md and reports/figures/scaling_*.png
(``sim.studies.scaling_report``). Run by ``scripts/scaling.py``.

Learner curves (``lfd.bench.scaling``): each learner trained with ``lfd.train(learner, demos, seed=0)``
(the DMP baseline with ``lfd.bench.dmp.fit_dmp``), its default options except where ``--iterations``
says otherwise (the default gives the NODE a tenth of its default iterations; the report states it),
on LASA shapes stacked into d = 2..32 dimensions, on 1..7 demos and on 250..4000 samples per demo.
Control-step curves (``sim.studies.scaling_control``): a contraction field on the planar arm, the Panda and a URDF arm
(the UR5 of example-robot-data) with 0..16 spheres off the path, against a bare ``mj_step``.

Every measurement is cached as one JSON file under ``--cache`` (default out/scaling, written atomically
with a key of what it depends on), so an interrupted run resumes where it stopped. ``--quick``: a smoke
test into out/scaling-quick/. Progress bars on a terminal only. Bad options: one line on stderr, exit 2.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import torch._dynamo  # noqa: F401  (torch's optimizers import it on first use: out of the timed fits)
from tqdm.auto import tqdm

import lfd
from lfd.bench.scaling import (
    CURVES,
    DIMS,
    cached_measure,
    curve_points,
    full_config,
    point_function,
    profile_fit,
    stacked_lasa,
)
from lfd.bench.spaces import fit
from lfd.cache import cached_field
from lfd.errors import LfdError
from lfd.io import atomic_write, check_writable, write_json
from lfd.threads import torch_threads
from robots import RobotError
from sim.errors import SimError
from sim.run.parsing import OneLineParser, fail, names
from sim.studies.scaling_control import OBSTACLE_COUNTS, ROBOTS, load_scaling_robot, measure_control
from sim.studies.scaling_report import (
    TARGET_EXPONENT,
    TARGET_LEARNERS,
    control_figure,
    exponents,
    findings_text,
    learner_figure,
    report,
)

__all__ = ["ALL_LEARNERS", "control_curves", "learner_curves", "learner_options", "main", "parse_iterations",
           "profile_targets"]

PROG = "scaling"
ALL_LEARNERS = ("node", "contraction", "tracking", "dmp")
CONTROL_LEARNER = "contraction"
CONTROL_FORMAT = 3
#: the quick mode's sizes, iterations and control points
QUICK: dict[str, tuple[int, ...]] = {"dim": (2, 4), "demos": (1, 7), "samples": (250, 1000)}
QUICK_ITERATIONS = {"node": 20, "contraction": 10}
QUICK_COUNTS = (0, 1, 2)
QUICK_ITERATIONS_TEXT = ",".join(f"{k}={v}" for k, v in QUICK_ITERATIONS.items())
PROFILE_ITERATIONS = 10


def parse_iterations(text: str, learners: tuple[str, ...]) -> dict[str, str]:
    """``node=/10,contraction=50`` -> {"node": "/10", "contraction": "50"}; ValueError on bad text."""
    out: dict[str, str] = {}
    for part in names(text):
        name, sep, value = part.partition("=")
        if not sep or name not in ALL_LEARNERS or name == "dmp":
            raise ValueError(f"--iterations: '{part}' is not LEARNER=N or LEARNER=/K (learners: node, contraction)")
        if name == "tracking":
            raise ValueError("--iterations: the tracking learner has no iterations")
        v = value[1:] if value.startswith("/") else value
        if not v.isdigit() or int(v) < 1 or int(v) > 10**6:
            raise ValueError(f"--iterations: '{value}' is not a positive integer or /K")
        out[name] = value
    return out


def learner_options(learners: tuple[str, ...], iterations: dict[str, str]) -> dict[str, dict[str, Any]]:
    """Each learner's options: {} (its defaults) or {"iterations": n}, n from ``iterations`` (a number, or
    /K: the learner's default, read from its config now, divided by K)."""
    out: dict[str, dict[str, Any]] = {}
    for name in learners:
        if name not in iterations:
            out[name] = {}
            continue
        value = iterations[name]
        if value.startswith("/"):
            default = int(lfd.get_learner(name).make_config().iterations)
            out[name] = {"iterations": max(1, default // int(value[1:]))}
        else:
            out[name] = {"iterations": int(value)}
    return out


def warm_up(learners: tuple[str, ...]) -> None:
    """One-off imports and compilations out of the timed fits: torch's optimizers import torch._dynamo
    on first use; one tiny fit per learner loads the rest (numba kernels included)."""
    demos = stacked_lasa(2, 2, 100)
    tiny = {"node": {"iterations": 2}, "contraction": {"iterations": 2}}
    with warnings.catch_warnings(), torch_threads(1):
        warnings.simplefilter("ignore")
        for name in learners:
            fn = point_function(name, fit(name, demos, 0, tiny.get(name, {})))
            if fn is not None:
                fn(demos.x[0, 0])


# ---------------------------------------------------------------- learner curves

def learner_curves(learners: tuple[str, ...], options: dict[str, dict[str, Any]], cache: Path,
                   sizes: dict[str, tuple[int, ...]] | None, progress: bool) -> tuple[list[dict[str, Any]], float]:
    """Measure (or read) every point of every learner's three curves; returns the records (with a
    ``curves`` list of the curves each belongs to) and the wall time spent measuring now."""
    points: dict[Any, list[str]] = {}
    for learner in learners:
        for curve in CURVES:
            for p in curve_points(learner, curve, options[learner], None if sizes is None else sizes[curve]):
                points.setdefault(p, []).append(curve)
    todo = [p for p in points if not _cached(p, cache)]
    if todo:
        warm_up(tuple(dict.fromkeys(p.learner for p in todo)))
    records = []
    spent = 0.0
    bar = tqdm(total=len(points), desc="learners", unit="point", disable=not progress)
    for p, curves in points.items():
        bar.set_postfix_str(p.stem)
        t0 = time.perf_counter()
        rec, new = cached_measure(p, cache)
        if new:
            spent += time.perf_counter() - t0
        records.append({**rec, "curves": curves})
        bar.update(1)
    bar.close()
    return records, spent


def _cached(point: Any, cache: Path) -> bool:
    path = cache / f"{point.stem}.json"
    try:
        return bool(json.loads(path.read_text()).get("key") == point.key())
    except (OSError, ValueError):
        return False


# ---------------------------------------------------------------- control-step curves

def control_key(robot: Any, counts: tuple[int, ...], repeats: int, field_file: str) -> str:
    """A hash of what one robot's control points depend on."""
    spec = {"format": CONTROL_FORMAT, "robot": dataclasses.asdict(robot), "counts": list(counts),
            "repeats": repeats, "field": field_file}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def control_curves(counts: tuple[int, ...], robots: tuple[Any, ...], repeats: int, cache: Path,
                   progress: bool) -> tuple[list[dict[str, Any]], float, dict[str, Any]]:
    """Measure (or read) the control step of every robot at every obstacle count, and each robot's plain
    loop (no obstacles, no dampers), one cached file per robot (``sim.studies.scaling_control.measure_control``);
    returns the records, the wall time spent measuring now and a description of the field and demos."""
    demos = lfd.spiral()
    field, model_file, _ = cached_field(CONTROL_LEARNER, demos, 0, {}, verbose=False)
    info = {"learner": CONTROL_LEARNER, "demos": "lfd.spiral() (5 demos, 200 samples, 5 s)",
            "model_file": model_file.name}
    records: list[dict[str, Any]] = []
    spent = 0.0
    bar = tqdm(total=len(robots), desc="control", unit="robot", disable=not progress)
    for robot_spec in robots:
        bar.set_postfix_str(robot_spec.name)
        path = cache / "control" / f"{robot_spec.name.split()[0]}.json"
        key = control_key(robot_spec, counts, repeats, model_file.name)
        rec = _read(path, key)
        if rec is None:
            t0 = time.perf_counter()
            points = measure_control(load_scaling_robot(robot_spec), demos, field, counts, repeats)
            rec = {"key": key, "robot": robot_spec.name, "points": points, "elapsed_s": time.perf_counter() - t0}
            write_json(path, rec)
            spent += rec["elapsed_s"]
        records += [{"robot": rec["robot"], **p} for p in rec["points"]]
        records[-1]["elapsed_s"] = rec["elapsed_s"]   # counted once per robot
        bar.update(1)
    bar.close()
    return records, spent, info


def _read(path: Path, key: str) -> dict[str, Any] | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if rec.get("key") == key else None


# ---------------------------------------------------------------- profiles

def profile_targets(records: list[dict[str, Any]], learners: tuple[str, ...], options: dict[str, dict[str, Any]],
                    cache: Path, dims: tuple[int, ...] | None, progress: bool) -> tuple[str, float, float]:
    """For each target learner whose training-time exponent against d exceeds ``TARGET_EXPONENT``: a
    profile of its training (``lfd.bench.scaling.profile_fit``, at most ``PROFILE_ITERATIONS`` iterations)
    at the smallest and the largest d, cached; returns the report's text, the wall time spent now and the
    wall time the profiles took when they were made."""
    dims = dims or DIMS
    lo, hi = min(dims), max(dims)
    parts, spent, took = [], 0.0, 0.0
    for learner in TARGET_LEARNERS:
        if learner not in learners:
            continue
        b = exponents(records, learner, "dim")["train_cpu_s"]
        if not b > TARGET_EXPONENT:
            continue
        opts = dict(options[learner])
        if "iterations" in full_config(learner, {}):
            default = opts.get("iterations", full_config(learner, {})["iterations"])
            opts["iterations"] = min(int(default), PROFILE_ITERATIONS)
        prof = {}
        for d in (lo, hi):
            path = cache / f"profile_{learner}_d{d}.json"
            key = hashlib.sha256(json.dumps({"v": 1, "learner": learner, "d": d, "options": opts},
                                            sort_keys=True).encode()).hexdigest()[:16]
            rec = _read(path, key)
            if rec is None:
                if progress:
                    print(f"{PROG}: profiling {learner} at d = {d}", file=sys.stderr)
                t0 = time.perf_counter()
                rec = {"key": key, **profile_fit(learner, stacked_lasa(d), opts)}
                rec["elapsed_s"] = time.perf_counter() - t0
                write_json(path, rec)
                spent += rec["elapsed_s"]
            prof[d] = rec
        parts.append(findings_text(learner, b, prof[lo], prof[hi], lo, hi, opts))
        took += sum(float(p.get("elapsed_s", 0.0)) for p in prof.values())
    return "\n\n".join(parts), spent, took


# ---------------------------------------------------------------- main

def main(argv: list[str] | None = None) -> int:
    """Measure (or read from the cache) every curve and write the report (module docstring); returns
    the exit code (2: bad options)."""
    ap = OneLineParser(prog=PROG, description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--out", help="the report (default reports/scaling.md; with --quick "
                                  "out/scaling-quick/scaling.md)")
    ap.add_argument("--figures", help="folder of the PNGs (default: figures/ beside the report)")
    ap.add_argument("--cache", help="folder of the cached measurements (default out/scaling; with --quick "
                                    "out/scaling-quick)")
    ap.add_argument("--quick", action="store_true", help="a smoke test: two sizes per curve, few iterations, "
                                                         "the planar arm with 0-2 obstacles")
    ap.add_argument("--learners", default=",".join(ALL_LEARNERS), help="comma-separated, of node, contraction, "
                                                                        "tracking, dmp")
    ap.add_argument("--iterations", default="node=/10",
                    help="LEARNER=N or LEARNER=/K (the default divided by K), comma-separated; others train "
                         "with their defaults (default: node=/10; '' trains every learner with its defaults)")
    ap.add_argument("--repeats", type=int, default=5, help="timed rounds of the control points (default 5)")
    ap.add_argument("--skip-learners", action="store_true", help="only the control-step curves")
    ap.add_argument("--skip-control", action="store_true", help="only the learner curves")
    args = ap.parse_args(argv)
    learners = tuple(names(args.learners))
    bad = [s for s in learners if s not in ALL_LEARNERS]
    if bad or not learners:
        return fail(PROG, f"--learners: unknown learner(s) {', '.join(bad) or '(none given)'}; known: "
                    f"{', '.join(ALL_LEARNERS)}")
    if not 1 <= args.repeats <= 100:
        return fail(PROG, "--repeats must be between 1 and 100")
    if args.skip_learners and args.skip_control:
        return fail(PROG, "--skip-learners and --skip-control leave nothing to do")
    try:
        iterations = parse_iterations(QUICK_ITERATIONS_TEXT if args.quick else args.iterations, learners)
    except ValueError as e:
        return fail(PROG, str(e))
    quick_dir = Path("out") / "scaling-quick"
    out = Path(args.out) if args.out else (quick_dir / "scaling.md" if args.quick else Path("reports") / "scaling.md")
    figures = Path(args.figures) if args.figures else out.parent / "figures"
    cache = Path(args.cache) if args.cache else (quick_dir if args.quick else Path("out") / "scaling")
    try:
        for p in (out, figures / "scaling_dim.png", cache / "probe.json"):
            check_writable(p)
    except (OSError, ValueError) as e:
        return fail(PROG, str(e))
    progress = sys.stderr.isatty()
    t_start = time.perf_counter()
    load_start = os.getloadavg()[0]
    try:
        options = learner_options(learners, iterations)
        learner_records: list[dict[str, Any]] = []
        control_records: list[dict[str, Any]] = []
        control_info: dict[str, Any] = {}
        measured = 0.0
        if not args.skip_learners:
            learner_records, spent = learner_curves(learners, options, cache, QUICK if args.quick else None,
                                                    progress)
            measured += spent
        if not args.skip_control:
            counts = QUICK_COUNTS if args.quick else OBSTACLE_COUNTS
            robots = ROBOTS[:1] if args.quick else ROBOTS
            control_records, spent, control_info = control_curves(counts, robots, 1 if args.quick else args.repeats,
                                                                  cache, progress)
            measured += spent
    except (LfdError, RobotError, SimError) as e:
        return fail(PROG, str(e))
    learners_done = tuple(n for n in learners if any(r["learner"] == n for r in learner_records))
    if learner_records:
        for curve in CURVES:
            learner_figure(learner_records, curve, learners_done, figures / f"scaling_{curve}.png")
    if control_records:
        control_figure(control_records, figures / "scaling_control.png")
    findings, profiles_s = "", 0.0
    if learner_records:
        findings, spent, profiles_s = profile_targets(learner_records, learners_done, options, cache,
                                                      QUICK["dim"] if args.quick else None, progress)
        measured += spent
    meta = {"command": "scripts/scaling.py" + (" --quick" if args.quick else "") + (f" --out {args.out}" if args.out
                                                                                    else ""),
            "date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()}, Python {platform.python_version()}",
            "quick": args.quick, "wall_s": time.perf_counter() - t_start, "measured_s": measured,
            "cache": os.path.relpath(cache) if cache.resolve().is_relative_to(Path.cwd()) else str(cache),
            "cache_total_s": sum(float(r.get("elapsed_s", 0.0)) for r in learner_records + control_records)
            + profiles_s,
            "load_start": load_start, "load_end": os.getloadavg()[0], "findings": findings}
    text = report(learner_records, control_records, learners_done, options, control_info, figures, out, meta)
    atomic_write(out, lambda f: f.write(text.encode()))
    print(f"wrote {out} ({meta['wall_s']:.0f} s)")
    return 0
