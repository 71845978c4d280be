"""Success rates of the learned pour (``--task pour``) over randomized episodes, per learner, with 95%
Wilson intervals and each failure's cause; writes reports/pour.md. Run by ``scripts/pour_bench.py``.

Episode k of a learner (seeded by k): the bowl placed uniformly within +-10 cm (x and y) of its nominal
place (``sim.run.tasks``: the goal follows it); the start moved up to 2 cm in a direction drawn from the
seed (``StartOffset``); in odd episodes a 20 N push for 0.2 s at t = 5 s, while the cup is carried
(``Push``, its direction drawn from the seed). A pour that missed the bowl with its tool away from
its goal ``stopped short`` (``sim.run.tasks.STOPPED_SHORT_M``). In-sample, every learner is trained
on all nine RoboTasks9 pouring demos and runs from demo 0's start; held out, episode k leaves demo
k mod 9 out of the training and runs from its start (``--held-out``). Each episode's record is written
as it finishes (``out/pour_bench/<learner>/<k>.json`` in-sample, ``out/pour_bench/held_out/...``
held out, atomically) and a rerun skips the episodes on file: a killed run resumes where it stopped.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

import sim
from lfd.errors import LfdError
from lfd.io import atomic_write, check_writable
from robots import RobotError
from sim.errors import SimError
from sim.run.parsing import OneLineParser, fail
from sim.run.plan import plan_job
from sim.run.tasks import plan_pour
from sim.scene.perturbations import Push, StartOffset

__all__ = ["main", "wilson"]

PROG = "pour_bench"
PRELOAD = ("sim.run.pipeline",)
LEARNERS: tuple[str, ...] = ("tracking", "contraction", "node", "stable_node")
TARGET_SPREAD_M = 0.10
START_OFFSET_M = 0.02
PUSH_N, PUSH_S, PUSH_AT_S = 20.0, 0.2, 5.0
N_DEMOS = 9   # RoboTasks9's pouring demos
SPLITS: tuple[str, ...] = ("in-sample", "held-out")


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval (lo, hi) of a success rate successes / n at the normal quantile z."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _episode(learner: str, k: int, nominal: np.ndarray, out: Path, held_out: bool) -> dict[str, Any]:
    """Episode ``k`` of ``learner`` (module docstring), in-sample or ``held_out``: its record."""
    rng = np.random.default_rng(k)
    target = nominal[:2] + rng.uniform(-TARGET_SPREAD_M, TARGET_SPREAD_M, 2)
    offset = float(rng.uniform(0.0, START_OFFSET_M))
    pushed = k % 2 == 1
    plan = plan_job(sim.ArmJob(demos="robottasks:pouring", learners=(learner,), task="pour",
                               target=(float(target[0]), float(target[1])), scenarios=("none",), videos=False,
                               plots=False, quiet=True, overwrite=True, out=str(out / "job"),
                               held_out=k % N_DEMOS if held_out else None))
    assert plan.task is not None
    perts: tuple[Any, ...] = (StartOffset(distance_m=offset, seed=k),)
    if pushed:
        perts += (Push(force_n=PUSH_N, duration_s=PUSH_S, start_s=PUSH_AT_S, seed=k),)
    t0 = time.perf_counter()
    trace = plan.exp.simulate(plan.fields[learner], perts)
    goal_error = float(np.linalg.norm(trace.ee[-1] - trace.goal_world))
    score = plan.task.score(plan.exp.physics.model.ptr, trace.frame_t, trace.frame_qpos, goal_error)
    return {"learner": learner, "episode": k, "target_m": target.tolist(), "start_offset_m": offset,
            "pushed": pushed, "held_out": k % N_DEMOS if held_out else None, "wall_s": time.perf_counter() - t0,
            "goal_error_m": goal_error, **score}


def _write(path: Path, blob: bytes) -> None:
    """``blob`` into ``path``, whole or not at all (``lfd.io.atomic_write``)."""
    atomic_write(path, lambda f: f.write(blob))


def main(argv: list[str] | None = None) -> int:
    """Run the episodes of every learner (module docstring) and write the report; returns the exit code."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--episodes", type=int, default=20, help="episodes per learner (default 20)")
    p.add_argument("--learners", default=",".join(LEARNERS), help="comma-separated (default: all four)")
    p.add_argument("--split", choices=(*SPLITS, "both"), default="both", help="which split (default both)")
    p.add_argument("--out", default="out/pour_bench", help="the episodes' records (default out/pour_bench)")
    p.add_argument("--report", default="reports/pour.md", help="the report (default reports/pour.md)")
    args = p.parse_args(argv)
    learners = [s for s in args.learners.split(",") if s]
    if not 1 <= args.episodes <= 1000 or any(name not in LEARNERS for name in learners):
        return fail(PROG, f"--episodes must be 1 to 1000 and --learners among {', '.join(LEARNERS)}")
    out, report = Path(args.out), Path(args.report)
    splits = SPLITS if args.split == "both" else (args.split,)
    records: dict[tuple[str, str], list[dict[str, Any]]] = {}
    try:
        check_writable(report)
        import lfd
        nominal = plan_pour(lfd.load_demos("robottasks:pouring"), None).nominal
        for split in splits:
            for learner in learners:
                folder = out / learner if split == "in-sample" else out / "held_out" / learner
                recs = records[(split, learner)] = []
                for k in range(args.episodes):
                    path = folder / f"{k}.json"
                    if path.is_file():
                        rec = json.loads(path.read_text())
                    else:
                        rec = _episode(learner, k, nominal, folder, split == "held-out")
                        path.parent.mkdir(parents=True, exist_ok=True)
                        _write(path, json.dumps(rec).encode())
                    recs.append(rec)
                print(f"{split} {learner}: {sum(r['success'] for r in recs)} of {args.episodes}", flush=True)
    except (LfdError, SimError, RobotError, OSError) as e:
        return fail(PROG, str(e))
    rows = []
    for (split, learner), recs in records.items():
        for label, chosen in (("all", recs), ("unpushed", [r for r in recs if not r["pushed"]]),
                              ("pushed", [r for r in recs if r["pushed"]])):
            k, n = sum(r["success"] for r in chosen), len(chosen)
            lo, hi = wilson(k, n)
            causes: dict[str, int] = {}
            for r in chosen:
                if not r["success"]:
                    causes[r["cause"]] = causes.get(r["cause"], 0) + 1
            why = ", ".join(f"{c} {m}" for c, m in sorted(causes.items())) or "-"
            balls = np.mean([r["in_bowl"] for r in chosen]) if chosen else float("nan")
            rows.append(f"| {split} | {learner} | {label} | {k} / {n} | {k / max(n, 1):.2f} [{lo:.2f}, {hi:.2f}] | "
                        f"{balls:.1f} | {why} |")
    text = "\n".join([
        "# The learned pour: success over randomized episodes, in-sample and held out", "",
        "Protocol: not a benchmark suite's; `python scripts/pour_bench.py` (sim.studies.pour_bench), 2-core machine.",
        "RoboTasks9 pouring, 9 demos: in-sample every learner is trained on all of them and runs from demo 0's",
        "start; held out, episode k trains on all but demo k mod 9 and runs from its start. The Panda (torque, 500 Hz)",
        "holds a cup (7.8 cm across) with 12 balls of 1 cm radius; the bowl (14.8 cm across) stands within",
        "+-10 cm of its nominal place, the start moved up to 2 cm, and every other episode is pushed with",
        "20 N for 0.2 s at t = 5 s. Success: no ball leaves the cup before it tilts past 60 deg, and at least",
        "10 of 12 rest in the bowl 1 s after the motion ends. Rates with 95% Wilson intervals.", "",
        "| split | learner | episodes | successes | rate [95% CI] | balls in the bowl, mean | failures |",
        "|---|---|---|---|---|---|---|", *rows, ""])
    atomic_write(report, lambda f: f.write(text.encode()))
    print(f"wrote {report}")
    return 0
