#!/usr/bin/env python
"""Robustness sweep of the arm: robots x learners x seeded perturbations, on a local process pool
or on Ray, one JSON record per run (atomic, resumable), then a summary with a robustness heatmap
and a basin-of-attraction plot.

Runs (each a ``sim.Experiment`` run of a learned field, ``sim.perturbations``):

* ``push``: a force of each magnitude (N) for ``--push-duration`` s at ``--push-start`` s on the
  tool's body, along each of ``--directions`` directions evenly spaced in the task plane
  (angle a: world direction axes @ (cos a, sin a); a 3-D task uses the plane of its first two
  axes), ``--seeds`` times, each seed adding a small seeded jitter to the direction (so seeds differ);
* ``offset``: the run starts ``--offsets`` m away from the demo's start, along each direction;
* ``goal``: the goal moves ``--goal-shifts`` m along each direction.

Each run is written as ``OUT/runs/<id>.json`` (``lfd.io.write_json``: strict JSON,
atomic) with a ``key`` hash of everything that determines it; a later sweep skips a run whose
record exists with the same key, so an interrupted sweep resumes. The fields are trained (or
read from ``lfd.cache``'s cache) here, before any worker starts. Then ``OUT/summary.json``
(counts, success rates, recovery statistics per robot x learner x kind, throughput),
``OUT/heatmap.png`` (push direction x magnitude -> median recovery time and success rate, one
row per robot x learner) and ``OUT/basin.png`` (start offsets in task space, coloured by success).

A run succeeds when it ends within ``--goal-tol`` m of its (shifted) goal without leaving the
joint limits; a diverged simulation is a failed run (recorded with its error).

A run whose worker process dies (kill -9, out of memory) is tried again
(``lfd.bench.executor.run_parallel``, up to ``MAX_ATTEMPTS`` tries); its record's ``attempts`` counts
the tries and its ``node`` says where the last one ran (``{"host"}``; on Ray also the node's ``ip``
and ``ray_node_id``); the summary's ``run.nodes`` counts the runs computed per node. ``attempts``,
``node`` and the timings (``run_s``, ``run_cpu_s``, ``control_step_us``, ``realtime_factor``) are
the fields that may differ between two sweeps of the same runs. A run given up is recorded as
failed with the reason and ``lost: true`` (a later sweep tries it again); every other run
finishes. Ctrl-C or SIGTERM stops the workers and ends with ``sweep_arm: interrupted`` and exit
code 130; the workers also end when this process is killed.

Examples::

    python scripts/sweep_arm.py --out out/sweep --workers 2
    python scripts/sweep_arm.py --out out/sweep --executor ray --workers 2
    python scripts/sweep_arm.py --out out/sweep --executor ray --address 10.0.0.5:6379   # README: on a cluster
    python scripts/sweep_arm.py --out /tmp/tp --throughput 2     # runs/s with 1 and 2 workers
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
if __name__ == "__main__":
    # Ctrl-C and SIGTERM handled from here on; the sweep runs as the module ``sweep_arm``, so that
    # worker processes and Ray tasks unpickle RunSpec and run_one by that importable name
    from lfd.interrupts import run_script

    run_script(__file__)

import argparse
import json
import math
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.append(HERE)          # worker processes import this module by name

# imported before main with interrupts deferred (lfd.interrupts.run_script): an interrupt inside an import
# can surface as another error (MuJoCo's reads as "ImportError: initialization failed")
PRELOAD = ("sim", "robots", "lfd.learners", "lfd.cache", "lfd.io", "lfd.bench.executor", "tqdm.auto")
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
        from lfd.bench.protocol import stable_hash

        d = asdict(self)
        d.pop("model_dir")
        return stable_hash({"v": RECORD_VERSION, **d})

    @property
    def name(self) -> str:
        deg = int(round(math.degrees(self.angle_rad))) % 360
        return (f"{self.robot}__{self.learner}__{self.kind}__a{deg:03d}__m{self.magnitude:g}__s{self.seed}"
                .replace(".", "p"))


# ---------------------------------------------------------------- one run (in a worker)
_CACHE: dict[tuple[str, str, str, str], Any] = {}


def _experiment(spec: RunSpec) -> tuple[Any, Any]:
    """(Experiment, field) for the spec, built once per process."""
    key = (spec.robot, spec.learner, spec.demos, spec.model_dir)
    if key not in _CACHE:
        import lfd
        import sim
        from lfd.cache import cached_field
        from robots import load_robot

        demos = lfd.load_demos(spec.demos)
        field = cached_field(spec.learner, demos, options=json.loads(spec.options), directory=spec.model_dir,
                             verbose=False)[0]
        exp = sim.Experiment(load_robot(spec.robot, actuation="torque"), demos)
        _CACHE[key] = (exp, field)
    return _CACHE[key]


def direction(exp: Any, angle: float) -> tuple[float, float, float]:
    """World unit vector, shape (3,), of the task-plane angle ``angle`` (rad)."""
    u = exp.placement.axes[:, :2] @ np.array([math.cos(angle), math.sin(angle)])
    u = u / np.linalg.norm(u)
    return (float(u[0]), float(u[1]), float(u[2]))


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Run and score one spec; returns its record (JSON-able). Never raises for a failed run."""
    import torch

    from sim.errors import SimError, SimulationError
    from sim.perturbations import GoalShift, Push, StartOffset

    torch.set_num_threads(1)
    t0, c0 = time.perf_counter(), time.process_time()
    exp, field = _experiment(spec)
    angle = spec.angle_rad
    if spec.kind == "push":
        angle += PUSH_JITTER_RAD * float(np.random.default_rng(spec.seed).uniform(-1.0, 1.0)) if spec.seed else 0.0
        perts: tuple = (Push(force_n=spec.magnitude, duration_s=spec.push_duration_s,
                                 start_s=spec.push_start_s, direction=direction(exp, angle)),)
    elif spec.kind == "offset":
        perts = (StartOffset(distance_m=spec.magnitude, direction=direction(exp, angle)),)
    else:
        perts = (GoalShift(distance_m=spec.magnitude, direction=direction(exp, angle)),)
    record: dict[str, Any] = {"key": spec.key(), "name": spec.name, **asdict(spec), "angle_applied_rad": angle}
    record.pop("model_dir")
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
    record: dict[str, Any] = {"key": spec.key(), "name": spec.name, **asdict(spec)}
    record.pop("model_dir")
    record.update(success=False, error=f"given up after {failure.attempts} tries: {failure.reason}",
                  metrics=None, attempts=failure.attempts, lost=True)
    return record


def sweep(specs: list[RunSpec], out: Path, workers: int, executor: str, address: str | None,
          fresh: bool = False, progress: bool = True) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Run every spec without a matching record in ``out/runs`` (all with ``fresh``); returns the
    records in spec order and run info (computed, cached, wall_s, runs_per_s, nodes: runs computed
    per node, by Ray node id or host name)."""
    from tqdm.auto import tqdm

    from lfd.bench.executor import run_parallel
    from lfd.io import write_json

    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
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
                     finished, paths=(HERE,), on_failed=lost)
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


def heatmap(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Push direction x magnitude -> median recovery time and success rate, one row per robot x learner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lfd.modelfile import atomic_write

    pushes = [r for r in records if r["kind"] == "push"]
    if not pushes:
        return None
    combos = sorted({(r["robot"], r["learner"]) for r in pushes})
    angles = sorted({round(r["angle_rad"], 9) for r in pushes})
    mags = sorted({r["magnitude"] for r in pushes})
    fig, axes = plt.subplots(len(combos), 2, figsize=(10, 3.2 * len(combos)), squeeze=False)
    for row, (robot, learner) in enumerate(combos):
        rec = np.full((len(mags), len(angles)), np.nan)
        suc = np.full((len(mags), len(angles)), np.nan)
        for i, mg in enumerate(mags):
            for j, a in enumerate(angles):
                rs = [r for r in pushes if r["robot"] == robot and r["learner"] == learner
                      and r["magnitude"] == mg and round(r["angle_rad"], 9) == a]
                if not rs:
                    continue
                suc[i, j] = np.mean([r["success"] for r in rs])
                times = [r["metrics"].get("recovery_time_s") if r.get("metrics") else None for r in rs]
                ok = [t for t in times if t is not None]
                rec[i, j] = np.median(ok) if len(ok) * 2 > len(times) else np.inf   # inf: mostly never recovered
        deg = [f"{math.degrees(a):.0f}" for a in angles]
        for col, (data, title, cmap) in enumerate(((rec, "median recovery time (s); x: never", "viridis"),
                                                   (suc, "success rate", "RdYlGn"))):
            ax = axes[row, col]
            shown = np.where(np.isinf(data), np.nan, data)
            vmin, vmax = (0.0, 1.0) if col == 1 else (None, None)
            im = ax.imshow(shown, aspect="auto", origin="lower", cmap=cmap, vmin=vmin, vmax=vmax)
            for i, j in zip(*np.nonzero(np.isinf(data))):
                ax.text(j, i, "x", ha="center", va="center", color="k")
            ax.set_xticks(range(len(angles)), deg)
            ax.set_yticks(range(len(mags)), [f"{m:g}" for m in mags])
            ax.set_xlabel("push direction in the task plane (deg)")
            ax.set_ylabel("force (N)")
            ax.set_title(f"{robot} / {learner}: {title}", fontsize=9)
            fig.colorbar(im, ax=ax)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return path


def basin(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Start points of the ``offset`` runs in task space (first two coordinates), filled where the
    run reached its goal, with the goal; one panel per robot x learner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lfd.modelfile import atomic_write

    offs = [r for r in records if r["kind"] == "offset" and r.get("start_task")]
    if not offs:
        return None
    combos = sorted({(r["robot"], r["learner"]) for r in offs})
    fig, axes = plt.subplots(1, len(combos), figsize=(4.5 * len(combos), 4.2), squeeze=False)
    for ax, (robot, learner) in zip(axes[0], combos):
        rs = [r for r in offs if r["robot"] == robot and r["learner"] == learner]
        xs = np.array([r["start_task"][:2] for r in rs])
        ok = np.array([r["success"] for r in rs])
        err = np.array([r["metrics"]["final_goal_error_m"] * 1e3 for r in rs])
        sc = ax.scatter(xs[ok, 0], xs[ok, 1], c=err[ok], cmap="viridis", s=30, label="reached goal")
        ax.scatter(xs[~ok, 0], xs[~ok, 1], marker="x", c="r", s=30, label="missed")
        g = np.array(rs[0]["goal_task"][:2])
        ax.plot(*g, "k*", ms=12, label="goal")
        for r in rs:
            ax.plot([r["start_task"][0], r["end_task"][0]], [r["start_task"][1], r["end_task"][1]],
                    color="0.8", lw=0.5, zorder=0)
        ax.set_aspect("equal")
        ax.set_title(f"{robot} / {learner}: start offsets", fontsize=9)
        ax.set_xlabel("x1 (task units)")
        ax.set_ylabel("x2 (task units)")
        ax.legend(fontsize=7, loc="best")
        fig.colorbar(sc, ax=ax, label="final goal error (mm)")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)
    return path


def _floats(text: str, name: str) -> list[float]:
    from lfd.errors import ConfigError

    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--{name} {text!r}: expected comma-separated numbers") from None
    if not vals or any(not (math.isfinite(v) and v >= 0) for v in vals) or max(vals) > 1e4:
        raise ConfigError(f"--{name} {text!r}: expected finite numbers in [0, 1e4]")
    return vals


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message: str) -> Any:
        self.exit(2, f"sweep_arm: error: {message} (see --help)\n")


def parse(argv: list[str] | None) -> argparse.Namespace:
    ap = _Parser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output directory (runs/, summary.json, heatmap.png, basin.png)")
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
    from lfd.bench.executor import check_executor
    from lfd.errors import ConfigError

    args.robots = [s.strip() for s in args.robots.split(",") if s.strip()]
    args.learners = [s.strip() for s in args.learners.split(",") if s.strip()]
    args.kinds = [s.strip() for s in args.kinds.split(",") if s.strip()]
    bad = [k for k in args.kinds if k not in KINDS]
    if bad or not args.kinds:
        raise ConfigError(f"--kinds: unknown {', '.join(bad) or '(none)'}; known: {', '.join(KINDS)}")
    from lfd.learners import LEARNERS

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
    args.forces = _floats(args.forces, "forces")
    args.offsets = _floats(args.offsets, "offsets")
    args.goal_shifts = _floats(args.goal_shifts, "goal-shifts")
    for name in ("push_start", "push_duration", "goal_tol"):
        v = getattr(args, name)
        if not (math.isfinite(v) and 0 <= v <= 100) or (name == "push_duration" and v <= 0):
            raise ConfigError(f"--{name.replace('_', '-')} {v}: expected a finite value in (0, 100]")
    args.address = check_executor(args.executor, args.address)
    from lfd.commands.bench import parse_options
    from lfd.learners import get_learner

    args.options = parse_options(args.option, args.learners)
    for learner in args.learners:
        get_learner(learner).make_config(**args.options.setdefault(learner, {}))   # unknown keys: ConfigError


def prepare_models(args: argparse.Namespace) -> str:
    """Train (or find) every field now, so workers only read them; returns the model directory."""
    import lfd
    from lfd.cache import cache_dir, cached_field
    from robots import load_robot

    model_dir = str(Path(cache_dir()).resolve())
    demos = lfd.load_demos(args.demos)
    for robot in args.robots:
        load_robot(robot, actuation="torque")            # a bad name fails here, not in every run
    for learner in args.learners:
        cached_field(learner, demos, options=args.options[learner], directory=model_dir)
    return model_dir


def main(argv: list[str] | None = None) -> int:
    """The sweep (module docstring); returns the exit code: 0 done, 2 bad input, 130 interrupted
    (Ctrl-C or SIGTERM: the workers are stopped, every finished record is kept)."""
    from lfd.interrupts import install_signal_handlers, restore_signal_handlers

    previous = install_signal_handlers()   # SIGTERM is Ctrl-C: KeyboardInterrupt, exit 130
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print("sweep_arm: interrupted", file=sys.stderr)
        return 130
    finally:
        restore_signal_handlers(previous)


def _main(argv: list[str] | None) -> int:
    args = parse(argv)
    import sim  # noqa: F401  (MUJOCO_GL before mujoco)
    from lfd.errors import LfdError
    from lfd.io import write_json
    from robots import RobotError
    from sim.errors import SimError

    try:
        check(args)
        model_dir = prepare_models(args)
        specs = grid(args, model_dir)
        out = Path(args.out)
        progress = sys.stderr.isatty()
        if args.throughput:
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
                        "cpu_s_per_run": cpu, "cpu_bound_speedup": top * cpu[1] / cpu[top],
                        "load": os.getloadavg()})
            return 0
        records, info = sweep(specs, out, args.workers, args.executor, args.address, args.fresh, progress)
        figures = [p for p in (heatmap(records, out / "heatmap.png"), basin(records, out / "basin.png")) if p]
        write_json(out / "summary.json", {"runs": len(records), "run": {**info, "load": os.getloadavg()},
                                          "summary": summarize(records)})
        ok = sum(r["success"] for r in records)
        rate = f", {info['runs_per_s']:.2f} runs/s" if info["runs_per_s"] else ""
        where = f" on {len(info['nodes'])} node(s)" if args.executor == "ray" and info["nodes"] else ""
        print(f"{info['computed']} run(s) computed, {info['cached']} from {out / 'runs'}, in {info['wall_s']:.1f} s"
              f"{rate}{where}; {ok}/{len(records)} succeeded")
        print(f"wrote {out / 'summary.json'}" + "".join(f", {p}" for p in figures))
        return 0
    except (LfdError, SimError, RobotError, OSError) as e:
        print(f"sweep_arm: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sweep_arm: interrupted", file=sys.stderr)
        return 130
