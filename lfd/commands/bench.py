"""``lfd bench lasa`` and ``lfd bench robottasks``: the benchmarks of docs/benchmark.md.

``lasa`` scores node, contraction, tracking and the DMP on the 30 LASA shapes (positions);
``robottasks`` scores them on the 9 RoboTasks9 tasks (poses: positions and orientations, the DMP
a Cartesian one). Each trains every learner on each shape or task and seed in parallel worker
processes, caches every finished cell (resumable), then writes the results JSON and the markdown
report with its figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

BENCH_LEARNERS: tuple[str, ...] = ("node", "contraction", "tracking", "dmp")
# --quick: fewer iterations, for the CI smoke test (merged under any --option given)
QUICK_OPTIONS: dict[str, dict[str, Any]] = {
    "contraction": {"iterations": 60},
    "node": {"iterations": 200},
    "tracking": {},
    "dmp": {},
}
# robottasks --quick: the same, and the Cartesian DMP's orientation integrated at the data's 60 Hz
QUICK_ROBOT_OPTIONS: dict[str, dict[str, Any]] = {
    "contraction": {"iterations": 60},
    "node": {"iterations": 200},
    "tracking": {},
    "dmp": {"int_dt": 1 / 60},
}


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("bench", help="run a benchmark and write its report",
                              description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="suite", metavar="SUITE", parser_class=type(p))
    sub.required = True
    q = sub.add_parser("lasa", help="the LASA handwriting benchmark (30 shapes)",
                       description="Train and score learners on the LASA shapes; see docs/benchmark.md.")
    _add_learner(q)
    q.add_argument("--shapes", action="append", default=[], metavar="[LEARNER:]all|NAME,...",
                   help="LASA shapes, comma-separated (default: all 30; with --quick: 3); "
                        "repeat with a LEARNER: prefix to give one learner fewer, e.g. node:Angle,Sine")
    _add_execution(q)
    q.add_argument("--train-demos", type=int, default=7, metavar="K",
                   help="train on the first K demos, test on the rest (default 7)")
    q.add_argument("--quick", action="store_true",
                   help=f"smoke test: shapes {','.join(_quick_shapes())} and fewer iterations")
    _add_outputs(q)
    r = sub.add_parser("robottasks", help="the RoboTasks9 pose benchmark (9 tasks, positions and orientations)",
                       description="Train and score learners on the RoboTasks9 poses; see docs/benchmark.md.")
    _add_learner(r)
    r.add_argument("--tasks", default="all", metavar="all|NAME,...",
                   help="RoboTasks9 tasks, comma-separated (default: all 9; with --quick: "
                        f"{','.join(_quick_tasks())})")
    _add_execution(r)
    r.add_argument("--perturbed-starts", type=int, default=8, metavar="N",
                   help="perturbed starts (5 cm, 30 degrees) around each demo start (default 8)")
    r.add_argument("--quick", action="store_true",
                   help=f"smoke test: tasks {','.join(_quick_tasks())} and fewer iterations")
    _add_outputs(r)
    return p


def _add_learner(q: argparse.ArgumentParser) -> None:
    q.add_argument("--learner", default="all", metavar="|".join([*BENCH_LEARNERS, "all"]),
                   help="learner(s) to benchmark, comma-separated (default: all)")


def _add_execution(q: argparse.ArgumentParser) -> None:
    """--seeds, --workers, --executor, --address (both suites)."""
    q.add_argument("--seeds", type=int, default=1, metavar="N", help="train with seeds 0..N-1 (default 1)")
    q.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="worker processes (default: the CPU count; 1 runs in this process); with "
                        "--executor ray: the CPUs of the local Ray instance")
    q.add_argument("--executor", default="local", choices=("local", "ray"),
                   help="local: a process pool (default); ray: Ray tasks, on a local Ray instance or, "
                        "with --address / RAY_ADDRESS, on an existing cluster (pip install 'lfd-arm[ray]')")
    q.add_argument("--address", metavar="HOST:PORT",
                   help="with --executor ray: join the Ray cluster there (default: $RAY_ADDRESS; unset: "
                        "start Ray locally)")


def _add_outputs(q: argparse.ArgumentParser) -> None:
    """--option, --json, --report, --cache, --fresh, --notes (both suites)."""
    q.add_argument("--option", action="append", default=[], metavar="LEARNER.KEY=VALUE",
                   help="a learner option, e.g. contraction.rate=1.0 (VALUE is JSON, else a string)")
    q.add_argument("--json", required=True, metavar="PATH", help="write all results here")
    q.add_argument("--report", required=True, metavar="PATH",
                   help="write the markdown report here (its figures: figures/<report name>_<...>.png beside it)")
    q.add_argument("--cache", metavar="DIR",
                   help="finished cells (default: .cache/<json stem>/ beside --json)")
    q.add_argument("--fresh", action="store_true", help="recompute every cell, ignoring the cache")
    q.add_argument("--notes", metavar="PATH", help="markdown appended to the report's Reading section")


def _quick_tasks() -> tuple[str, ...]:
    from lfd.commands import source_constant

    return tuple(source_constant("lfd.bench.robottasks", "QUICK_TASKS"))  # without importing numpy


def _quick_shapes() -> tuple[str, ...]:
    from lfd.commands import source_constant

    return tuple(source_constant("lfd.bench.protocol", "QUICK_SHAPES"))  # without importing numpy


def resolve_learners(spec: str) -> list[str]:
    """``all`` or a comma list of BENCH_LEARNERS, in BENCH_LEARNERS order."""
    from lfd.errors import ConfigError

    names = list(BENCH_LEARNERS) if spec == "all" else [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in BENCH_LEARNERS]
    if unknown or not names:
        raise ConfigError(f"unknown learner(s) {', '.join(unknown) or '(none given)'}; "
                          f"known: {', '.join(BENCH_LEARNERS)}, all")
    return [n for n in BENCH_LEARNERS if n in names]


def resolve_shape_sets(items: list[str], learners: list[str], quick: bool) -> dict[str, list[str]]:
    """``--shapes`` values -> {learner: shapes}: an unprefixed value sets every learner's shapes,
    ``LEARNER:NAMES`` one learner's (default: all, or the quick shapes with --quick)."""
    from lfd.bench.protocol import resolve_shapes
    from lfd.errors import ConfigError

    def prefixed(v: str) -> bool:
        return ":" in v and v.partition(":")[0] in BENCH_LEARNERS

    common = [v for v in items if not prefixed(v)]
    if len(common) > 1:
        raise ConfigError(f"--shapes given {len(common)} times without a LEARNER: prefix")
    default = resolve_shapes(common[0] if common else "all", quick=quick)
    out = {learner: default for learner in learners}
    for v in filter(prefixed, items):
        learner, _, names = v.partition(":")
        if learner not in learners:
            raise ConfigError(f"--shapes {v}: learner '{learner}' is not being benchmarked")
        out[learner] = resolve_shapes(names, quick=quick)
    return out


def parse_options(items: list[str], learners: list[str]) -> dict[str, dict[str, Any]]:
    """``["contraction.rate=1.0", ...]`` -> {"contraction": {"rate": 1.0}}."""
    from lfd.errors import ConfigError

    out: dict[str, dict[str, Any]] = {name: {} for name in learners}
    for item in items:
        key, eq, raw = item.partition("=")
        learner, dot, name = key.partition(".")
        if not (eq and dot and name):
            raise ConfigError(f"--option {item}: expected LEARNER.KEY=VALUE")
        if learner not in BENCH_LEARNERS:
            raise ConfigError(f"--option {item}: unknown learner '{learner}'")
        try:
            value = json.loads(raw)
        except ValueError:
            value = raw
        out.setdefault(learner, {})[name] = value
    return out


def run(args: argparse.Namespace) -> int:
    if args.suite == "robottasks":
        return run_robottasks(args)
    from lfd.bench import protocol as proto
    from lfd.bench.report import summarize, write_report
    from lfd.bench.runner import Cell, load_arrays, run_cells, write_json

    address = _check_run(args)
    learners = resolve_learners(args.learner)
    shapes_by = resolve_shape_sets(args.shapes, learners, args.quick)
    shapes = list(dict.fromkeys(s for learner in learners for s in shapes_by[learner]))
    protocol = proto.LasaProtocol(train_demos=args.train_demos)
    options, configs = _learner_options(args, learners, QUICK_OPTIONS, _lasa_config)
    notes = Path(args.notes).read_text() if args.notes else None
    seeds = list(range(args.seeds))
    cells = [Cell.make(learner, shape, seed, options[learner], protocol)
             for learner in learners for shape in shapes_by[learner] for seed in seeds]
    json_path, cache = _paths(args)

    load_start = _load()
    t0 = time.perf_counter()
    result = run_cells(cells, cache, workers=min(args.workers, max(len(cells), 1)), fresh=args.fresh,
                       progress=sys.stderr.isatty(),  # a bar only on a terminal
                       executor=args.executor, address=address)
    run_info = _run_info(args, _command(args), result, time.perf_counter() - t0, load_start, cache)
    figures = write_report(args.report, result.records, learners, shapes, protocol.to_dict(), run_info,
                           lambda r: load_arrays(cache, r), notes)
    write_json(json_path, {
        "protocol": protocol.to_dict(), "protocol_hash": proto.stable_hash(protocol.to_dict()),
        "learners": configs, "shapes": shapes, "shapes_by_learner": shapes_by, "seeds": seeds,
        "quick": bool(args.quick),
        "summary": summarize(result.records, learners), "run": run_info, "results": result.records,
    })
    _done(result, cache, run_info, json_path, args.report, figures)
    return 0


def run_robottasks(args: argparse.Namespace) -> int:
    """``lfd bench robottasks``: every learner on every task and seed (``lfd.bench.robottasks``)."""
    from lfd.bench import robottasks as rt
    from lfd.bench.protocol import stable_hash
    from lfd.bench.runner import write_json

    address = _check_run(args)
    learners = resolve_learners(args.learner)
    tasks = rt.resolve_tasks(args.tasks, quick=args.quick)
    protocol = rt.RobotTasksProtocol(perturbed_starts=args.perturbed_starts)
    options, configs = _learner_options(args, learners, QUICK_ROBOT_OPTIONS, rt.resolve_config)
    notes = Path(args.notes).read_text() if args.notes else None
    seeds = list(range(args.seeds))
    cells = [rt.TaskCell.make(learner, task, seed, options[learner], protocol)
             for learner in learners for task in tasks for seed in seeds]
    json_path, cache = _paths(args)

    load_start = _load()
    t0 = time.perf_counter()
    result = rt.run_task_cells(cells, cache, workers=min(args.workers, max(len(cells), 1)), fresh=args.fresh,
                               progress=sys.stderr.isatty(), executor=args.executor, address=address)
    run_info = _run_info(args, _command_robottasks(args), result, time.perf_counter() - t0, load_start, cache)
    figures = rt.write_report(args.report, result.records, learners, tasks, protocol.to_dict(), run_info,
                              lambda r: rt.load_task_arrays(cache, r), notes)
    write_json(json_path, {
        "protocol": protocol.to_dict(), "protocol_hash": stable_hash(protocol.to_dict()),
        "learners": configs, "tasks": tasks, "seeds": seeds, "quick": bool(args.quick),
        "summary": rt.summarize(result.records, learners), "run": run_info, "results": result.records,
    })
    _done(result, cache, run_info, json_path, args.report, figures)
    return 0


def _check_run(args: argparse.Namespace) -> str | None:
    """The checks of both suites before any work: counts, the executor (returns its Ray address or
    None) and that the outputs can be written."""
    from lfd.bench.executor import check_executor
    from lfd.commands import check_output
    from lfd.errors import ConfigError

    if args.seeds < 1 or args.workers < 1:
        raise ConfigError("--seeds and --workers must be >= 1")
    if args.workers > 4096:
        raise ConfigError(f"--workers {args.workers}: at most 4096")
    address = check_executor(args.executor, args.address)
    check_output(args.json, "--json", {"--notes file": args.notes})  # before hours of benchmark
    check_output(args.report, "--report", {"--json file": args.json, "--notes file": args.notes})
    return address


def _lasa_config(learner: str, options: dict[str, Any]) -> dict[str, Any]:
    from lfd.bench.runner import resolve_config

    return resolve_config(learner, options)


def _learner_options(args: argparse.Namespace, learners: list[str], quick: dict[str, dict[str, Any]],
                     resolve: Any) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, Any]]]:
    """({learner: options}, {learner: resolved config}): ``--option`` values over the quick
    options (with --quick); ``resolve(learner, options)`` checks them (ConfigError)."""
    options = parse_options(args.option, learners)
    if args.quick:
        options = {k: {**quick.get(k, {}), **v} for k, v in options.items()}
    options = {k: v for k, v in options.items() if k in learners}
    return options, {k: resolve(k, options[k]) for k in learners}


def _paths(args: argparse.Namespace) -> tuple[Path, Path]:
    """(--json, the cache folder: --cache, or .cache/<json stem>/ beside --json)."""
    json_path = Path(args.json)
    return json_path, Path(args.cache) if args.cache else json_path.parent / ".cache" / json_path.stem


def _run_info(args: argparse.Namespace, command: str, result: Any, wall: float, load_start: str,
              cache: Path) -> dict[str, Any]:
    """The ``run`` entry of the JSON (how this invocation ran); warns once per cell given up."""
    for f in result.failed:   # shown by lfd.cli as one line "lfd: warning: ..."
        why = f"refused by its learner: {f['reason']}" if f.get("refused") else \
            f"given up after {f['attempts']} tries ({f['reason']})"
        warnings.warn(f"cell {f['cell']} {why}; it is not in the report or the cache: run again to retry it",
                      RuntimeWarning, stacklevel=1)
    return {
        "command": command, "seeds": list(range(args.seeds)), "workers": args.workers, "executor": args.executor,
        "cpus": os.cpu_count(),
        "wall_s": wall, "computed": len(result.computed), "cached": len(result.cached),
        "load_start": load_start, "load_end": _load(), "cache": str(cache), "failed": result.failed,
    }


def _done(result: Any, cache: Path, run_info: dict[str, Any], json_path: Path, report: str,
          figures: list[Path]) -> None:
    print(f"{len(result.computed)} cell(s) computed, {len(result.cached)} from {cache}, in {run_info['wall_s']:.1f} s")
    more = f" and {len(figures) - 4} more figures" if len(figures) > 4 else ""
    shown = ", ".join(str(f) for f in figures[:4]) + more
    print(f"wrote {json_path}, {report} and {shown}")


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def _command(args: argparse.Namespace) -> str:
    """The command line that reproduces a LASA run (for the report)."""
    return _command_line(args, ["lfd bench lasa", f"--learner {args.learner}", *(f"--shapes {s}" for s in args.shapes),
                                f"--seeds {args.seeds}", f"--workers {args.workers}",
                                f"--train-demos {args.train_demos}"])


def _command_robottasks(args: argparse.Namespace) -> str:
    """The command line that reproduces a RoboTasks9 run (for the report)."""
    return _command_line(args, ["lfd bench robottasks", f"--learner {args.learner}", f"--tasks {args.tasks}",
                                f"--seeds {args.seeds}", f"--workers {args.workers}",
                                f"--perturbed-starts {args.perturbed_starts}"])


def _command_line(args: argparse.Namespace, parts: list[str]) -> str:
    """``parts`` and the options both suites share."""
    parts += [f"--executor {args.executor}"] if args.executor != "local" else []
    parts += [f"--address {args.address}"] if args.address else []
    parts += ["--quick"] if args.quick else []
    parts += [f"--option {o}" for o in args.option]
    parts += [f"--json {args.json}", f"--report {args.report}"]
    return " ".join(parts)
