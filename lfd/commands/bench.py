"""``lfd bench``: the benchmark suites of docs/benchmark.md and the reports beside them.

One subcommand per suite of ``lfd.bench.SUITES`` (``lasa``: the 30 LASA shapes, positions;
``robottasks``: the 9 RoboTasks9 tasks, poses): every learner (the registered ones and the DMP) on
every unit and seed, in-sample and held-out (``--split``), in parallel worker processes, each
finished cell cached (resumable), then the results JSON and the markdown report with its figures.
``comparison``, ``tradeoff`` and ``obstacles`` regenerate reports/comparison.md,
reports/contraction_tradeoff.md and reports/obstacle_fields.md (``lfd.bench.comparison_report``,
``lfd.bench.tradeoff``, ``lfd.bench.obstacles_report``).
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

from lfd.bench import SUITES
from lfd.commands import check_output, source_constant


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("bench", help="run a benchmark and write its report",
                              description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="suite", metavar="SUITE", parser_class=type(p))
    sub.required = True
    for name, module in SUITES.items():
        _add_suite(sub, name, module)
    _add_reports(sub)
    return p


def _add_suite(sub: Any, name: str, module: str) -> None:
    """The options of a suite's command, its unit flag (``--shapes``, ``--tasks``) and protocol
    options read from its module's literals (without importing it)."""
    what, unit = source_constant(module, "HELP"), source_constant(module, "UNIT")
    quick = ",".join(source_constant(module, "QUICK_UNITS"))
    q = sub.add_parser(name, help=what, description=f"Train and score learners on {what}; see docs/benchmark.md.")
    q.add_argument("--learner", default="all", metavar="NAME,...|all",
                   help="learner(s) to benchmark, comma-separated: the registered learners and dmp (default: all)")
    q.add_argument(f"--{unit}s", dest="units", action="append", default=[], metavar="[LEARNER:]all|NAME,...",
                   help=f"{unit}s, comma-separated (default: all; with --quick: {quick}); repeat with a LEARNER: "
                        "prefix to give one learner fewer")
    q.add_argument("--split", default="both", metavar="in-sample|held-out|both",
                   help="in-sample (every demo trains and is scored), held-out (leave one demo out: a field per "
                        "demo, trained on the others, run toward that demo's end) or both (default)")
    for flag, field, text in source_constant(module, "PROTOCOL_OPTIONS"):
        q.add_argument(flag, type=int, dest=f"protocol_{field}", metavar="N", help=text)
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
    q.add_argument("--quick", action="store_true", help=f"smoke test: {unit}s {quick} and fewer iterations")
    q.add_argument("--option", action="append", default=[], metavar="LEARNER.KEY=VALUE",
                   help="a learner option, e.g. contraction.rate=1.0 (VALUE is JSON, else a string)")
    q.add_argument("--json", required=True, metavar="PATH", help="write all results here")
    q.add_argument("--report", required=True, metavar="PATH",
                   help="write the markdown report here (its figures: figures/<report name>_<...>.png beside it)")
    q.add_argument("--cache", metavar="DIR", help="finished cells (default: .cache/<json stem>/ beside --json)")
    q.add_argument("--fresh", action="store_true", help="recompute every cell, ignoring the cache")
    q.add_argument("--notes", metavar="PATH", help="markdown appended to the report's Reading section")


def _add_reports(sub: Any) -> None:
    """``comparison``, ``tradeoff`` and ``obstacles``."""
    c = sub.add_parser("comparison", help="the learners side by side on the spiral (reports/comparison.md)",
                       description="The paper's experiments on the noisy spiral: figures and comparison.md.")
    c.add_argument("--out", default="reports", metavar="DIR",
                   help="folder of comparison.md and figures/ (default: reports)")
    c.add_argument("--node-iterations", type=int, metavar="N", help="NODE iterations (default: the learner's)")
    c.add_argument("--cache", default=os.path.join("out", "compare_cache"), metavar="DIR",
                   help="trained models reused across runs (default: out/compare_cache)")
    c.add_argument("--no-cache", action="store_true", help="train every model afresh")
    t = sub.add_parser("tradeoff", help="what the contraction learner's bound costs (reports/contraction_tradeoff.md)",
                       description="What the contraction learner's condition bound KAPPA and its rate cost and buy.")
    t.add_argument("--shapes", default="all", metavar="all|NAME,...", help="LASA shapes (default: all 30)")
    t.add_argument("--workers", type=int, default=2, metavar="N", help="worker processes (default 2)")
    t.add_argument("--out", default=os.path.join("reports", "contraction_tradeoff.md"), metavar="PATH",
                   help="the report (and its .json beside it; default: reports/contraction_tradeoff.md)")
    t.add_argument("--node-results", default=os.path.join("reports", "lasa_results.json"), metavar="PATH",
                   help="a LASA results JSON whose NODE DTW goes beside (optional)")
    o = sub.add_parser("obstacles", help="obstacle scenes x every learner, field level (reports/obstacle_fields.md)",
                       description="Seeded obstacle scenes on the demonstrated paths, every learner, with and "
                                   "without the convergence terms of Eqs. (O2)-(O3).")
    o.add_argument("--placements", type=int, default=200, metavar="N", help="scenes (default 200)")
    o.add_argument("--workers", type=int, default=2, metavar="N", help="worker processes (default 2)")
    o.add_argument("--cache", default=os.path.join("out", "obstacle_sweep"), metavar="DIR",
                   help="finished cells (default: out/obstacle_sweep)")
    o.add_argument("--report", default=os.path.join("reports", "obstacle_fields.md"), metavar="PATH",
                   help="the report (default: reports/obstacle_fields.md)")
    o.add_argument("--no-plain", action="store_true", help="skip the ablation without Eqs. (O2)-(O3)")
    o.add_argument("--learner", default="all", metavar="NAME,...|all",
                   help="learners, comma-separated (default: all of node, stable_node, contraction, tracking)")


def resolve_learners(spec: str) -> list[str]:
    """``all`` or a comma list of ``lfd.bench.spaces.bench_learners()``, in that order."""
    from lfd.bench.spaces import bench_learners
    from lfd.errors import ConfigError

    known = bench_learners()
    names = list(known) if spec == "all" else [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise ConfigError(f"unknown learner(s) {', '.join(unknown) or '(none given)'}; known: {', '.join(known)}, all")
    return [n for n in known if n in names]


def resolve_unit_sets(items: list[str], learners: list[str], quick: bool, suite: Any) -> dict[str, list[str]]:
    """``--shapes`` / ``--tasks`` values -> {learner: units}: an unprefixed value sets every
    learner's units, ``LEARNER:NAMES`` one learner's (default: all, or the quick units)."""
    from lfd.bench.spaces import bench_learners
    from lfd.errors import ConfigError

    flag = f"--{suite.unit}s"

    def prefixed(v: str) -> bool:
        return ":" in v and v.partition(":")[0] in bench_learners()

    common = [v for v in items if not prefixed(v)]
    if len(common) > 1:
        raise ConfigError(f"{flag} given {len(common)} times without a LEARNER: prefix")
    default = suite.resolve_units(common[0] if common else "all", quick=quick)
    out = {learner: default for learner in learners}
    for v in filter(prefixed, items):
        learner, _, names = v.partition(":")
        if learner not in learners:
            raise ConfigError(f"{flag} {v}: learner '{learner}' is not being benchmarked")
        out[learner] = suite.resolve_units(names, quick=quick)
    return out


def parse_options(items: list[str], learners: list[str]) -> dict[str, dict[str, Any]]:
    """``["contraction.rate=1.0", ...]`` -> {"contraction": {"rate": 1.0}}."""
    from lfd.bench.spaces import bench_learners
    from lfd.errors import ConfigError

    out: dict[str, dict[str, Any]] = {name: {} for name in learners}
    for item in items:
        key, eq, raw = item.partition("=")
        learner, dot, name = key.partition(".")
        if not (eq and dot and name):
            raise ConfigError(f"--option {item}: expected LEARNER.KEY=VALUE")
        if learner not in bench_learners():
            raise ConfigError(f"--option {item}: unknown learner '{learner}'")
        try:
            value = json.loads(raw)
        except ValueError:
            value = raw
        out.setdefault(learner, {})[name] = value
    return out


def run(args: argparse.Namespace) -> int:
    if args.suite not in SUITES:
        return _run_report(args)
    from lfd.bench import get_suite
    from lfd.bench.protocol import stable_hash
    from lfd.bench.report import page_path, write_report
    from lfd.bench.runner import load_arrays, run_cells
    from lfd.bench.suite import resolve_splits
    from lfd.bench.summary import summarize
    from lfd.io import write_json

    address = _check_run(args)
    check_output(str(page_path(args.report)), "--report's page", {"--json file": args.json, "--notes file": args.notes})
    cls = get_suite(args.suite)
    protocol = cls.protocol_type(**{k.removeprefix("protocol_"): v for k, v in vars(args).items()
                                    if k.startswith("protocol_") and v is not None})
    suite = cls(protocol)
    learners = resolve_learners(args.learner)
    units_by = resolve_unit_sets(args.units, learners, args.quick, suite)
    units = list(dict.fromkeys(u for learner in learners for u in units_by[learner]))
    splits = resolve_splits(args.split)
    options = parse_options(args.option, learners)
    if args.quick:
        options = {k: {**suite.quick(k), **v} for k, v in options.items()}
    options = {k: v for k, v in options.items() if k in learners}
    configs = {k: suite.config(k, options[k]) for k in learners}
    notes = Path(args.notes).read_text() if args.notes else None
    seeds = list(range(args.seeds))
    cells = suite.cells(learners, units_by, seeds, options, splits)
    json_path, cache = _paths(args)

    load_start = _load()
    t0 = time.perf_counter()
    result = run_cells(cells, cache, workers=min(args.workers, max(len(cells), 1)), fresh=args.fresh,
                       progress=sys.stderr.isatty(),  # a bar only on a terminal
                       executor=args.executor, address=address, desc=suite.name)
    run_info = _run_info(args, _command(args, suite.unit), result, time.perf_counter() - t0, load_start, cache)
    figures = write_report(args.report, suite, result.records, learners, units, run_info,
                           lambda r: load_arrays(cache, suite.record_stem(r)), notes, json_path)
    unit = suite.unit
    write_json(json_path, {
        "suite": suite.name, "protocol": protocol.to_dict(), "protocol_hash": stable_hash(protocol.to_dict()),
        "learners": configs, f"{unit}s": units, f"{unit}s_by_learner": units_by, "splits": splits, "seeds": seeds,
        "quick": bool(args.quick), "summary": summarize(suite, result.records, learners), "run": run_info,
        "results": result.records,
    })
    print(f"{len(result.computed)} cell(s) computed, {len(result.cached)} from {cache}, in {run_info['wall_s']:.1f} s")
    shown = [str(json_path), args.report, str(page_path(args.report)), *(str(f) for f in figures[:4])]
    more = f" and {len(figures) - 4} more figures" if len(figures) > 4 else ""
    print(f"wrote {', '.join(shown[:-1])} and {shown[-1]}{more}")
    return 0


def _run_report(args: argparse.Namespace) -> int:
    """``comparison``, ``tradeoff`` or ``obstacles``: their checks before any work, then their library run."""
    from lfd.errors import ConfigError

    if args.suite == "comparison":
        from lfd.bench.comparison_report import run_comparison

        if args.node_iterations is not None and args.node_iterations < 1:
            raise ConfigError("--node-iterations must be >= 1")
        check_output(os.path.join(args.out, "comparison.md"), "--out")
        return run_comparison(args.out, args.node_iterations, None if args.no_cache else args.cache)
    if args.workers < 1:
        raise ConfigError("--workers must be >= 1")
    if args.suite == "tradeoff":
        from lfd.bench.tradeoff import run_tradeoff

        check_output(args.out, "--out", {"--node-results file": args.node_results})
        return run_tradeoff(args.shapes, args.workers, args.out, args.node_results)
    from lfd.bench.obstacles import LEARNERS
    from lfd.bench.obstacles_report import run_obstacle_sweep

    names = LEARNERS if args.learner == "all" else tuple(s.strip() for s in args.learner.split(",") if s.strip())
    unknown = [n for n in names if n not in LEARNERS]
    if unknown or not names:
        raise ConfigError(f"unknown learner(s) {', '.join(unknown) or '(none given)'}; "
                          f"known: {', '.join(LEARNERS)}, all")
    check_output(args.report, "--report")
    return run_obstacle_sweep(args.placements, args.workers, args.cache, args.report, plain=not args.no_plain,
                              learners=tuple(n for n in LEARNERS if n in names))


def _check_run(args: argparse.Namespace) -> str | None:
    """The checks of every suite before any work: counts, the executor (returns its Ray address or
    None) and that the outputs can be written."""
    from lfd.bench.executor import check_executor
    from lfd.errors import ConfigError

    if args.seeds < 1 or args.workers < 1:
        raise ConfigError("--seeds and --workers must be >= 1")
    if args.workers > 4096:
        raise ConfigError(f"--workers {args.workers}: at most 4096")
    address = check_executor(args.executor, args.address)
    check_output(args.json, "--json", {"--notes file": args.notes})  # before hours of benchmark
    check_output(args.report, "--report", {"--json file": args.json, "--notes file": args.notes})
    return address


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


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def _command(args: argparse.Namespace, unit: str) -> str:
    """The command line that reproduces a run (for the report)."""
    parts = [f"lfd bench {args.suite}", f"--learner {args.learner}", *(f"--{unit}s {s}" for s in args.units),
             f"--split {args.split}", f"--seeds {args.seeds}", f"--workers {args.workers}"]
    parts += [f"--{k.removeprefix('protocol_').replace('_', '-')} {v}" for k, v in vars(args).items()
              if k.startswith("protocol_") and v is not None]
    parts += [f"--executor {args.executor}"] if args.executor != "local" else []
    parts += [f"--address {args.address}"] if args.address else []
    parts += ["--quick"] if args.quick else []
    parts += [f"--option {o}" for o in args.option]
    parts += [f"--json {args.json}", f"--report {args.report}"]
    return " ".join(parts)
