"""Robustness sweep of the arm: robots x learners x seeded perturbations, on a local process pool
or on Ray, one JSON record per run (atomic, resumable), then a summary with a robustness heatmap
and a basin-of-attraction plot (``sim.studies.sweep_figures``). Run by ``scripts/sweep_arm.py``.

Runs (each a ``sim.Experiment`` run of a learned field, ``sim.scene.perturbations``): ``push``, a force
of each magnitude (N) for ``--push-duration`` s at ``--push-start`` s on the tool's body, along each
of ``--directions`` directions evenly spaced in the task plane (``direction``), ``--seeds`` times,
each seed adding a small seeded jitter to the direction; ``offset``, the run starts ``--offsets`` m
away from the demo's start, along each direction; ``goal``, the goal moves ``--goal-shifts`` m.

Each run is written as ``OUT/runs/<name>.json`` (``lfd.io.write_json``) with a ``key`` hash of
everything that determines it; a later sweep skips a run whose record exists with that key, so an
interrupted sweep resumes. The fields are trained (or read from ``lfd.cache``) here, before any
worker starts. Then ``OUT/heatmap.png``, ``OUT/basin.png``, the results page ``OUT/index.html``
(``sim.studies.sweep_page``) and last ``OUT/summary.json`` (``summarize``).
A run succeeds when it ends within ``--goal-tol`` m of its (shifted) goal without leaving the joint
limits; a diverged simulation is a failed run, recorded with its error.

A run whose worker process dies is tried again (``lfd.bench.executor.run_parallel``); its record's
``attempts`` counts the tries and ``node`` says where the last one ran; ``summary.json``'s
``run.nodes`` counts the runs per node. ``attempts``, ``node`` and the timings (``run_s``,
``run_cpu_s``, ``control_step_us``, ``realtime_factor``) may differ between two sweeps of the same
runs. A run given up is recorded as failed with ``lost: true`` (a later sweep tries it again).
Ctrl-C or SIGTERM stops the workers and ends with ``sweep_arm: interrupted``, exit code 130.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

import lfd
import sim
from lfd.bench.executor import check_executor, run_parallel
from lfd.bench.protocol import stable_hash
from lfd.cache import cache_dir, cached_field
from lfd.commands.bench import parse_options
from lfd.errors import ConfigError, LfdError
from lfd.interrupts import install_signal_handlers, restore_signal_handlers
from lfd.io import write_json
from lfd.learners import LEARNERS, get_learner
from lfd.pages import versions, write_page
from robots import RobotError, load_robot
from sim.errors import SimError, SimulationError
from sim.media.job_page import DISTRIBUTIONS
from sim.run.parsing import OneLineParser, fail, floats, names
from sim.studies.sweep_figures import basin, heatmap
from sim.studies.sweep_page import sweep_page

__all__ = ["KINDS", "RunSpec", "direction", "grid", "lost_record", "main", "read_record", "run_one", "summarize",
           "sweep"]

PROG = "sweep_arm"
# what ``sim.Experiment`` and ``sim.Push`` load on first use, imported before main with interrupts deferred
# (lfd.interrupts.run_script): an interrupt inside an import can surface as another error
PRELOAD = ("sim.run.experiment", "sim.scene.perturbations")
KINDS: tuple[str, ...] = ("push", "offset", "goal")
PUSH_JITTER_RAD = 0.05             # seeded jitter of a push direction per seed (radians)
RECORD_VERSION = 1


@dataclass(frozen=True)
class RunSpec:
    """One run. angle_rad : direction in the task plane; magnitude : N (push) or m (offset, goal)."""

    robot: str
    learner: str
    demos: str
    kind: str
    angle_rad: float
    magnitude: float
    seed: int
    push_start_s: float
    push_duration_s: float
    goal_tol_m: float
    model_dir: str
    options: str = "{}"        # the learner's training options, canonical JSON

    def key(self) -> str:
        """A hash of everything that determines the run (the model folder left out)."""
        d = asdict(self)
        d.pop("model_dir")
        return stable_hash({"v": RECORD_VERSION, **d})

    @property
    def name(self) -> str:
        """The record's file name without ``.json``."""
        deg = int(round(math.degrees(self.angle_rad))) % 360
        return (f"{self.robot}__{self.learner}__{self.kind}__a{deg:03d}__m{self.magnitude:g}__s{self.seed}"
                .replace(".", "p"))

    def record(self) -> dict[str, Any]:
        """The fields every record of this run starts with: key, name and the spec, its model folder left out."""
        out: dict[str, Any] = {"key": self.key(), "name": self.name, **asdict(self)}
        out.pop("model_dir")
        return out


# ---------------------------------------------------------------- one run (in a worker)
_CACHE: dict[tuple[str, str, str, str], Any] = {}


def _experiment(spec: RunSpec) -> tuple[Any, Any]:
    """(Experiment, field) for the spec, built once per process."""
    key = (spec.robot, spec.learner, spec.demos, spec.model_dir)
    if key not in _CACHE:
        demos = lfd.load_demos(spec.demos)
        field = cached_field(spec.learner, demos, options=json.loads(spec.options), directory=spec.model_dir,
                             verbose=False)[0]
        exp = sim.Experiment(load_robot(spec.robot, actuation="torque"), demos)
        _CACHE[key] = (exp, field)
    return _CACHE[key]


def direction(exp: Any, angle: float) -> tuple[float, float, float]:
    """World unit vector, shape (3,), of the task-plane angle ``angle`` (rad): the placement's axes
    times (cos a, sin a); a 3-D task uses the plane of its first two axes."""
    u = exp.placement.axes[:, :2] @ np.array([math.cos(angle), math.sin(angle)])
    u = u / np.linalg.norm(u)
    return (float(u[0]), float(u[1]), float(u[2]))


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Run and score one spec; returns its record (JSON-able). Never raises for a failed run."""
    torch.set_num_threads(1)
    t0, c0 = time.perf_counter(), time.process_time()
    exp, field = _experiment(spec)
    angle = spec.angle_rad
    if spec.kind == "push":
        angle += PUSH_JITTER_RAD * float(np.random.default_rng(spec.seed).uniform(-1.0, 1.0)) if spec.seed else 0.0
        perts: tuple = (sim.Push(force_n=spec.magnitude, duration_s=spec.push_duration_s,
                                 start_s=spec.push_start_s, direction=direction(exp, angle)),)
    elif spec.kind == "offset":
        perts = (sim.StartOffset(distance_m=spec.magnitude, direction=direction(exp, angle)),)
    else:
        perts = (sim.GoalShift(distance_m=spec.magnitude, direction=direction(exp, angle)),)
    record = {**spec.record(), "angle_applied_rad": angle}
    try:
        res = exp.run(field, spec.kind, perturbations=perts)
        ro, m = res.trace, res.metrics
        final = float(m["final_goal_error_m"])
        ok = final <= spec.goal_tol_m and ro.joint_limit_violations == 0
        record.update(success=bool(ok), error=None, metrics=m,
                      start_task=ro.start_task.tolist(), goal_task=ro.goal_task.tolist(),
                      end_task=exp.placement.to_task(ro.ee[-1]).tolist(),
                      start_world=ro.ee[0].tolist(), control_step_us=ro.control_step_us)
    except (SimError, SimulationError) as e:
        record.update(success=False, error=str(e).splitlines()[0], metrics=None)
    record["run_s"] = time.perf_counter() - t0
    record["run_cpu_s"] = time.process_time() - c0
    return record


# ---------------------------------------------------------------- the sweep (driver)
def grid(args: argparse.Namespace, model_dir: str) -> list[RunSpec]:
    """Every run of the sweep, in a stable order."""
    angles = [2 * math.pi * i / args.directions for i in range(args.directions)]
    mags = {"push": args.forces, "offset": args.offsets, "goal": args.goal_shifts}
    out = []
    for robot in args.robots:
        for learner in args.learners:
            for kind in args.kinds:
                for mag in mags[kind]:
                    for a in angles:
                        for seed in range(args.seeds):
                            out.append(RunSpec(robot, learner, args.demos, kind, a, float(mag), seed,
                                               args.push_start, args.push_duration, args.goal_tol, model_dir,
                                               json.dumps(args.options[learner], sort_keys=True)))
    return out[:args.limit] if args.limit else out


def read_record(path: Path, key: str) -> dict[str, Any] | None:
    """The record at ``path`` if it parses, carries ``key`` and is not a lost run's, else None."""
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("key") == key and not rec.get("lost") else None


def lost_record(spec: RunSpec, failure: Any) -> dict[str, Any]:
    """The record of a run given up after its worker process died on each try
    (``lfd.bench.executor.Failure``): failed, with the reason; ``lost`` makes a later sweep retry it."""
    return {**spec.record(), "success": False, "error": f"given up after {failure.attempts} tries: {failure.reason}",
            "metrics": None, "attempts": failure.attempts, "lost": True}


def sweep(specs: list[RunSpec], out: Path, workers: int, executor: str, address: str | None,
          fresh: bool = False, progress: bool = True) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Run every spec without a matching record in ``out/runs`` (all with ``fresh``); returns the
    records in spec order and run info (computed, cached, wall_s, runs_per_s, nodes: runs computed
    per node, by Ray node id or host name)."""
    runs = out / "runs"     # made by the first record written (``write_json``): an early Ctrl-C leaves nothing
    records: list[dict[str, Any] | None] = []
    todo: list[int] = []
    for i, s in enumerate(specs):
        rec = None if fresh else read_record(runs / f"{s.name}.json", s.key())
        records.append(rec)
        if rec is None:
            todo.append(i)
    bar = tqdm(total=len(specs), initial=len(specs) - len(todo), desc="sweep", unit="run", disable=not progress)

    stamps: list[float] = []
    nodes: dict[str, int] = {}

    def finished(j: int, rec: dict[str, Any], attempts: int, node: dict[str, str]) -> None:
        i = todo[j]
        rec = {**rec, "attempts": attempts, "node": node}
        where = node.get("ray_node_id") or node["host"]
        nodes[where] = nodes.get(where, 0) + 1
        write_json(runs / f"{specs[i].name}.json", rec)
        records[i] = rec
        stamps.append(time.perf_counter())
        bar.update()

    def lost(j: int, failure: Any) -> None:
        i = todo[j]
        records[i] = lost_record(specs[i], failure)
        write_json(runs / f"{specs[i].name}.json", records[i])
        bar.update()

    t0 = time.perf_counter()
    try:
        run_parallel(run_one, [specs[i] for i in todo], min(workers, max(len(todo), 1)), executor, address,
                     finished, on_failed=lost)
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    n, h = len(stamps), len(stamps) // 2
    # steady rate: the second half of the runs, after worker start-up (imports, model loading)
    steady = (n - h) / (stamps[-1] - stamps[h - 1]) if h >= 1 and stamps[-1] > stamps[h - 1] else None
    info = {"computed": len(todo), "cached": len(specs) - len(todo), "wall_s": wall,
            "runs_per_s": len(todo) / wall if todo and wall > 0 else None, "steady_runs_per_s": steady,
            "workers": workers, "executor": executor, "nodes": dict(sorted(nodes.items()))}
    return [r for r in records if r is not None], info


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per robot/learner/kind: runs, success rate, recovery-time and deviation statistics."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        groups.setdefault(f"{r['robot']}/{r['learner']}/{r['kind']}", []).append(r)
    out = {}
    for k, rs in sorted(groups.items()):
        rec = [r["metrics"].get("recovery_time_s") for r in rs if r.get("metrics")]
        rec_ok = [v for v in rec if v is not None]
        dev = [r["metrics"]["max_deviation_m"] for r in rs if r.get("metrics") and "max_deviation_m" in r["metrics"]]
        out[k] = {"runs": len(rs), "success_rate": float(np.mean([r["success"] for r in rs])),
                  "errors": sum(r.get("error") is not None for r in rs),
                  "final_goal_error_m_median": _median([r["metrics"]["final_goal_error_m"] for r in rs
                                                        if r.get("metrics")]),
                  "recovered_rate": (len(rec_ok) / len(rec)) if rec and rs[0]["kind"] == "push" else None,
                  "recovery_time_s_median": _median(rec_ok), "max_deviation_m_median": _median(dev)}
    return out


def _median(v: list[float]) -> float | None:
    return float(np.median(v)) if v else None


# ---------------------------------------------------------------- the command line
def parse(argv: list[str] | None) -> argparse.Namespace:
    """The sweep's options (``--help``)."""
    ap = OneLineParser(prog=PROG, description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--out", required=True,
                    help="output directory (runs/, summary.json, heatmap.png, basin.png, index.html)")
    ap.add_argument("--robots", default="panda", help="comma-separated robot names (default panda)")
    ap.add_argument("--learners", default="node,contraction", help="comma-separated learners")
    ap.add_argument("--demos", default="spiral", help="demo spec (default spiral)")
    ap.add_argument("--kinds", default="push,offset,goal", help=f"comma-separated, of {','.join(KINDS)}")
    ap.add_argument("--directions", type=int, default=8, help="directions in the task plane (default 8)")
    ap.add_argument("--forces", default="10,20,40,80", help="push magnitudes, N")
    ap.add_argument("--offsets", default="0.02,0.05,0.1", help="start offsets, m")
    ap.add_argument("--goal-shifts", default="0.02,0.05", help="goal shifts, m")
    ap.add_argument("--seeds", type=int, default=1, help="seeds per grid point (default 1)")
    ap.add_argument("--push-start", type=float, default=1.0, help="push start, s (default 1)")
    ap.add_argument("--push-duration", type=float, default=0.2, help="push duration, s (default 0.2)")
    ap.add_argument("--goal-tol", type=float, default=0.005, help="success: final goal error below this, m")
    ap.add_argument("--limit", type=int, default=0, help="run only the first N grid points (0: all)")
    ap.add_argument("--option", action="append", default=[], metavar="LEARNER.KEY=VALUE",
                    help="a training option of a learner, e.g. node.iterations=200 (VALUE is JSON, else a string)")
    ap.add_argument("--executor", default="local", choices=("local", "ray"))
    ap.add_argument("--address", help="with --executor ray: join the Ray cluster at HOST:PORT (default: $RAY_ADDRESS)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="parallel runs (default: CPU count)")
    ap.add_argument("--fresh", action="store_true", help="recompute every run")
    ap.add_argument("--throughput", type=int, metavar="N", default=0,
                    help="measure runs/s with 1 and with N workers (fresh, in OUT/tp1 and OUT/tpN) and exit")
    return ap.parse_args(argv)


def check(args: argparse.Namespace) -> None:
    """Validate the options (``ConfigError`` with one line)."""
    args.robots, args.learners, args.kinds = names(args.robots), names(args.learners), names(args.kinds)
    bad = [k for k in args.kinds if k not in KINDS]
    if bad or not args.kinds:
        raise ConfigError(f"--kinds: unknown {', '.join(bad) or '(none)'}; known: {', '.join(KINDS)}")
    bad = [k for k in args.learners if k not in LEARNERS]
    if bad or not args.learners:
        raise ConfigError(f"--learners: unknown {', '.join(bad) or '(none)'}; known: {', '.join(LEARNERS)}")
    if not args.robots:
        raise ConfigError("--robots: none given")
    for name, lo, hi in (("directions", 1, 360), ("seeds", 1, 1000), ("workers", 1, 4096), ("limit", 0, 10**7),
                         ("throughput", 0, 4096)):
        v = getattr(args, name)
        if not lo <= v <= hi:
            raise ConfigError(f"--{name} {v}: expected {lo}..{hi}")
    args.forces = floats(args.forces, "forces")
    args.offsets = floats(args.offsets, "offsets")
    args.goal_shifts = floats(args.goal_shifts, "goal-shifts")
    for name in ("push_start", "push_duration", "goal_tol"):
        v = getattr(args, name)
        if not (math.isfinite(v) and 0 <= v <= 100) or (name == "push_duration" and v <= 0):
            raise ConfigError(f"--{name.replace('_', '-')} {v}: expected a finite value in (0, 100]")
    args.address = check_executor(args.executor, args.address)
    args.options = parse_options(args.option, args.learners)
    for learner in args.learners:
        get_learner(learner).make_config(**args.options.setdefault(learner, {}))   # unknown keys: ConfigError


def prepare_models(args: argparse.Namespace) -> str:
    """Train (or find) every field now, so workers only read them; returns the model directory."""
    model_dir = str(Path(cache_dir()).resolve())
    demos = lfd.load_demos(args.demos)
    for robot in args.robots:
        load_robot(robot, actuation="torque")            # a bad name fails here, not in every run
    for learner in args.learners:
        cached_field(learner, demos, options=args.options[learner], directory=model_dir)
    return model_dir


def throughput(args: argparse.Namespace, specs: list[RunSpec], out: Path, progress: bool) -> None:
    """Runs per second with 1 and with ``args.throughput`` workers, fresh, in OUT/tp1 and OUT/tpN;
    printed and written to OUT/throughput_<executor>.json."""
    rates, steady, cpu = {}, {}, {}
    for w in sorted({1, args.throughput}):
        d = out / f"tp{w}"
        shutil.rmtree(d, ignore_errors=True)
        recs, info = sweep(specs, d, w, args.executor, args.address, fresh=True, progress=progress)
        rates[w], steady[w] = info["runs_per_s"], info["steady_runs_per_s"]
        cpu[w] = float(np.median([r["run_cpu_s"] for r in recs]))
        print(f"{args.executor}, {w} worker(s): {len(specs)} runs in {info['wall_s']:.1f} s, "
              f"{rates[w]:.2f} runs/s overall, {steady[w] or float('nan'):.2f} runs/s steady "
              f"(load {os.getloadavg()[0]:.1f}), median CPU time per run {cpu[w]:.3f} s")
    top = max(rates)
    sp = steady[top] / steady[1] if steady[top] and steady[1] else None
    print(f"throughput {top} vs 1 worker: {rates[top] / rates[1]:.2f}x overall, "
          f"{sp or float('nan'):.2f}x steady (target >= 1.8x); on {top} free cores, from the CPU "
          f"time per run: {top * cpu[1] / cpu[top]:.2f}x")
    write_json(out / f"throughput_{args.executor}.json",
               {"executor": args.executor, "runs": len(specs), "runs_per_s": rates,
                "steady_runs_per_s": steady, "speedup": rates[top] / rates[1], "steady_speedup": sp,
                "cpu_s_per_run": cpu, "cpu_bound_speedup": top * cpu[1] / cpu[top], "load": os.getloadavg()})


def main(argv: list[str] | None = None) -> int:
    """The sweep (module docstring); returns the exit code: 0 done, 2 bad input, 130 interrupted
    (Ctrl-C or SIGTERM: the workers are stopped, every finished record is kept)."""
    previous = install_signal_handlers()   # SIGTERM is Ctrl-C: KeyboardInterrupt, exit 130
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    finally:
        restore_signal_handlers(previous)


def _main(argv: list[str] | None) -> int:
    args = parse(argv)
    try:
        check(args)
        model_dir = prepare_models(args)
        specs = grid(args, model_dir)
        out = Path(args.out)
        progress = sys.stderr.isatty()
        if args.throughput:
            throughput(args, specs, out, progress)
            return 0
        records, info = sweep(specs, out, args.workers, args.executor, args.address, args.fresh, progress)
        figures = [p for p in (heatmap(records, out / "heatmap.png"), basin(records, out / "basin.png")) if p]
        summary = {"runs": len(records), "run": {**info, "load": os.getloadavg()}, "summary": summarize(records),
                   "command": [PROG, *(sys.argv[1:] if argv is None else argv)],
                   "versions": versions(DISTRIBUTIONS), "page": str(out / "index.html")}
        write_page(out / "index.html", sweep_page(out, summary, records, figures,
                                                  [out / "runs" / f"{r['name']}.json" for r in records]))
        write_json(out / "summary.json", summary)   # last: a sweep with its summary is complete
        ok = sum(r["success"] for r in records)
        rate = f", {info['runs_per_s']:.2f} runs/s" if info["runs_per_s"] else ""
        where = f" on {len(info['nodes'])} node(s)" if args.executor == "ray" and info["nodes"] else ""
        print(f"{info['computed']} run(s) computed, {info['cached']} from {out / 'runs'}, in {info['wall_s']:.1f} s"
              f"{rate}{where}; {ok}/{len(records)} succeeded")
        print(f"wrote {out / 'summary.json'}" + "".join(f", {p}" for p in figures) + f", {out / 'index.html'}")
        return 0
    except (LfdError, SimError, RobotError, OSError) as e:
        return fail(PROG, str(e) or type(e).__name__)
