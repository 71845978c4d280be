"""Whole-arm safety on the Panda: seeded obstacle scenes on the path, every learner, with and
without a push; writes reports/obstacles_arm.md. Run by ``scripts/panda_obstacles.py``.

The demos are a user's 3-demo spiral (extent 0.23 units, radius 0.13). Scene 0 is that user's
case: a sphere of 6 % of the extent on the first demo at 40 % of its arc length, no margin.
Scenes 1.. are ``lfd.obstacles.random_scene`` (1 to 3 spheres or boxes, a quarter beside the
goal). Every run uses the job's defaults (``sim.run_job``): the field keeps the tool point the
hand's size (``sim.scene.collision.hand_margin_m``) plus each obstacle's margin away, and the IK's
collision dampers keep every arm geom clear (``sim.scene.collision``). Per run: contact steps between
any robot geom and any obstacle (the joints replayed through MuJoCo's collision detection), the
final goal error, ``blocked``, the smallest clearance and the real-time factor. Runs are cached
(``--cache``, ``lfd.bench.runner.run_cells``), so a killed sweep resumes. ``--quick``: the user's
case with the tracking learner, unperturbed, into out/obstacles_arm-quick/.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import Any

import numpy as np

import lfd
import sim
from lfd.bench.protocol import stable_hash
from lfd.bench.runner import run_cells
from lfd.cache import cached_field
from lfd.errors import LfdError
from lfd.io import atomic_write, check_writable, kept_section
from lfd.obstacles import Obstacle, Sphere, random_scene
from lfd.obstacles.avoidance import settings
from robots import load_robot
from sim.run.obstacle_runs import OBSTACLE_TIME_FACTOR, ObstacleRuns
from sim.run.parsing import OneLineParser, fail
from sim.scene.obstacles import obstacle_contacts

__all__ = ["COST_HEADING", "Cell", "LEARNERS", "arc_point", "compute", "main", "report", "spiral3", "user_case"]

PROG = "panda_obstacles"
LEARNERS = ("contraction", "contracting_node", "node", "stable_node", "tracking")
SCENARIOS = ("none", "push")
GOAL_MM = 5.0
#: the report's hand-written section (``scripts/speed.py arm-clearance``'s measurements), kept on a rewrite
COST_HEADING = "## What whole-arm clearance costs per control step"


def spiral3() -> lfd.DemoSet:
    """The user's demos: a 3-demo spiral of radius 0.13."""
    return lfd.spiral(n_demos=3, radius=0.13)


def arc_point(demos: lfd.DemoSet, fraction: float) -> np.ndarray:
    """The first sample of demo 0 at or past ``fraction`` of its arc length, shape (d,)."""
    x = demos.x[0]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=1))])
    return x[np.searchsorted(s, fraction * s[-1])]


def user_case(demos: lfd.DemoSet) -> list[Obstacle]:
    """The user's sphere: 6 % of the extent, on demo 0 at 40 % of its arc length."""
    return [Sphere(arc_point(demos, 0.4), 0.06 * demos.extent)]


class Cell:
    """One learner on one scene, with each of ``scenarios`` (``lfd.bench.runner.run_cells``' cell)."""

    def __init__(self, learner: str, scene: int, scenarios: tuple[str, ...] = SCENARIOS) -> None:
        self.learner, self.scene, self.scenarios = learner, scene, scenarios
        self.hash = stable_hash({"v": 2, "learner": learner, "scene": scene, "scenarios": scenarios,
                                 "modulation": settings(learner == "tracking"), "time_factor": OBSTACLE_TIME_FACTOR})
        self.stem = f"{learner}__scene{scene:03d}"


def compute(cell: Cell) -> tuple[dict[str, Any], bytes]:
    """Run one cell: (its record, an empty NPZ archive)."""
    demos = spiral3()
    robot = load_robot("panda")
    among = ObstacleRuns()                      # as sim.run_job sets up a run among obstacles
    hand = among.hand_margin_m(robot)
    probe = sim.Experiment(robot, demos, clearance=None)
    scale = probe.placement.scale
    scene = user_case(demos) if cell.scene == 0 else random_scene(demos, cell.scene, extra_margin=hand / scale)
    exp = among.experiment(robot, demos, scene)
    field, _, _ = cached_field(cell.learner, demos, 0, {}, verbose=False)
    avoiding = among.avoiding(field, scene, robot, scale)
    runs = []
    for name in cell.scenarios:
        r = exp.run(avoiding, name)
        c = obstacle_contacts(exp.robot, r.trace.q, r.trace.t, r.trace.mocap_pos)
        m = r.metrics
        runs.append({"scenario": name, "contact_steps": c.steps_in_contact, "contacts": c.contacts,
                     "pairs": list(c.pairs), "min_clearance_m": c.min_clearance_m,
                     "final_goal_error_mm": m["final_goal_error_m"] * 1e3, "blocked": bool(m.get("blocked")),
                     "guard_active_s": m.get("guard_active_s"), "arm_min_clearance_m": m.get("arm_min_clearance_m"),
                     "realtime_factor": m["realtime_factor"], "control_step_us": m["control_step_us"]})
    record = {"hash": cell.hash, "learner": cell.learner, "scene": cell.scene,
              "obstacles": [o.describe() for o in scene], "hand_margin_m": hand, "scale_m_per_unit": scale,
              "runs": runs}
    buf = io.BytesIO()
    np.savez_compressed(buf, none=np.zeros(0))
    return record, buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    """Run the scenes (module docstring) and write the report; returns the exit code (2: bad input)."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--placements", type=int, default=50, help="scenes, the user's case first (default 50)")
    p.add_argument("--cache", help="folder of the cached runs (default out/panda_obstacles; --quick: "
                                    "out/obstacles_arm-quick)")
    p.add_argument("--report", help="the report (default reports/obstacles_arm.md; --quick: "
                                     "out/obstacles_arm-quick/obstacles_arm.md)")
    p.add_argument("--learner", default="all", help="learners, comma-separated (default: all of "
                                                     f"{', '.join(LEARNERS)})")
    p.add_argument("--quick", action="store_true", help="a smoke test: the user's case, the tracking learner, "
                                                        "no push")
    a = p.parse_args(argv)
    if not 1 <= a.placements <= 1000:
        return fail(PROG, "--placements must be between 1 and 1000")
    chosen = LEARNERS if a.learner == "all" else tuple(s.strip() for s in a.learner.split(","))
    if not chosen or any(n not in LEARNERS for n in chosen):
        return fail(PROG, f"--learner takes {', '.join(LEARNERS)} or all, got {a.learner!r}")
    quick = Path("out") / "obstacles_arm-quick"
    placements, learners, scenarios = (1, ("tracking",), ("none",)) if a.quick else (a.placements, chosen, SCENARIOS)
    cache = a.cache or str(quick if a.quick else Path("out") / "panda_obstacles")
    path = Path(a.report or (quick / "obstacles_arm.md" if a.quick else Path("reports") / "obstacles_arm.md"))
    try:
        check_writable(path)
        demos = spiral3()
        for learner in learners:
            cached_field(learner, demos, 0, {}, progress=sys.stderr.isatty())
        cells = [Cell(learner, i, scenarios) for i in range(placements) for learner in learners]
        result = run_cells(cells, cache, workers=1, compute=compute, desc="panda")   # in this process
    except LfdError as e:
        return fail(PROG, str(e))
    lines = report(result.records, placements, learners)
    if result.failed:
        lines += ["", f"Failed cells: {result.failed}"]
    kept = kept_section(path, COST_HEADING)
    text = "\n".join(lines + ([""] + kept if kept else [])) + "\n"
    atomic_write(path, lambda f: f.write(text.encode()))
    print(f"wrote {path}")
    return 0


def report(recs: list[dict], placements: int, learners: tuple[str, ...] = LEARNERS) -> list[str]:
    """The report's lines (without its kept section)."""
    hand = recs[0]["hand_margin_m"] if recs else float("nan")
    scale = recs[0]["scale_m_per_unit"] if recs else float("nan")
    lines = ["# Whole-arm safety on the Panda: obstacle scenes, every learner, with and without a push", "",
             "Protocol: not a benchmark suite's: the Panda obstacle study's own seeded scenes, stated below.", "",
             f"Made by `scripts/panda_obstacles.py`. {placements} scenes on a user's 3-demo spiral "
             f"(placed at {scale:.3f} m per unit): scene 0 is the user's case (a sphere of 6 % of the extent "
             "on the path, no margin), the others `lfd.obstacles.random_scene` (1-3 spheres or boxes, "
             "3-10 % of the extent, margins 0-4 %, a quarter beside the goal). Default job options: the "
             f"field keeps the tool point the hand's size ({hand * 1e3:.1f} mm, `sim.scene.collision.hand_margin_m`) "
             "plus the obstacle's margin away; collision dampers in the IK keep every arm geom 10 mm clear "
             f"(`sim.scene.collision`); each run lasts {OBSTACLE_TIME_FACTOR:g} x the demo's duration plus 1.5 s "
             "(`sim.run.obstacle_runs.OBSTACLE_TIME_FACTOR`). *Contact steps*: replayed states in which any robot geom "
             f"touches any obstacle. *Reached*: final tool position within {GOAL_MM:g} mm of the goal. "
             "*Blocked*: the run ended further away with a damper holding the arm (metrics.json `blocked`).", "",
             "| learner | scenario | runs | contact steps | reached | blocked | neither | worst goal error (mm) "
             "| min clearance (mm) | median RTF |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for learner in learners:
        for scen in SCENARIOS:
            runs = [(r, x) for r in recs if r["learner"] == learner for x in r["runs"] if x["scenario"] == scen]
            if not runs:
                continue
            steps = sum(x["contact_steps"] for _, x in runs)
            reached = sum(x["final_goal_error_mm"] <= GOAL_MM for _, x in runs)
            blocked = sum(x["blocked"] and x["final_goal_error_mm"] > GOAL_MM for _, x in runs)
            neither = len(runs) - reached - blocked
            worst = max(x["final_goal_error_mm"] for _, x in runs)
            clear = min(x["min_clearance_m"] for _, x in runs) * 1e3
            rtf = float(np.median([x["realtime_factor"] for _, x in runs]))
            share = 100 * reached / len(runs)
            lines.append(f"| {learner} | {scen} | {len(runs)} | {steps} | {reached} ({share:.0f} %) "
                         f"| {blocked} | {neither} | {worst:.2f} | {clear:.1f} | {rtf:.0f} |")
    case = [r for r in recs if r["scene"] == 0]
    if case:
        lines += ["", "The user's case (scene 0), default options:", "",
                  "| learner | scenario | contact steps | goal error (mm) | min clearance (mm) |",
                  "|---|---|---|---|---|"]
        for r in case:
            for x in r["runs"]:
                lines.append(f"| {r['learner']} | {x['scenario']} | {x['contact_steps']} | "
                             f"{x['final_goal_error_mm']:.2f} | {x['min_clearance_m'] * 1e3:.1f} |")
    odd = [(r, x) for r in recs for x in r["runs"] if x["contact_steps"] or x["final_goal_error_mm"] > GOAL_MM]
    lines += ["", f"Runs that touch or miss the goal: {len(odd)}."]
    for r, x in odd[:30]:
        lines.append(f"- {r['learner']} / {x['scenario']}, scene {r['scene']}: {x['contact_steps']} contact steps, "
                     f"goal {x['final_goal_error_mm']:.1f} mm, blocked {x['blocked']}; " + "; ".join(r["obstacles"]))
    return lines
