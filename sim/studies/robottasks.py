"""All nine RoboTasks9 tasks on the Panda, where they were recorded, with the tracking learner;
writes reports/robottasks_arm.md. Run by ``scripts/robottasks_arm.py``.

Each task runs as ``scripts/demo_arm.py --demos robottasks:TASK --learner tracking --perturb
none,push,offset,goal --no-video`` would (``sim.run_job``), with the translation ``SHIFTS`` where a
few recorded samples lie beyond the arm's reach: tool tracking and goal errors in mm and degrees,
push recovery, joint-limit violations, per task and scenario. ``--quick``: the first task,
unperturbed, into out/robottasks_arm-quick/.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import sim
from lfd.demos import ROBOTTASKS
from lfd.errors import LfdError
from lfd.io import atomic_write, check_writable
from robots import RobotError
from sim.errors import SimError
from sim.run.parsing import OneLineParser, fail

__all__ = ["SCENARIOS", "SHIFTS", "main", "row"]

PROG = "robottasks_arm"
#: task -> translation (m) of the recorded poses: the tasks whose samples the arm cannot all reach
#: where recorded (the smallest shift of a small grid that makes every checked sample reachable)
SHIFTS: dict[str, tuple[float, float, float]] = {"openbox": (0.0, 0.02, -0.02), "pan2stove": (0.0, 0.04, 0.0)}
SCENARIOS: dict[str, tuple[str, ...]] = {"pan2stove": ("none", "push", "goal")}   # offset: start out of reach
DEFAULT_SCENARIOS = ("none", "push", "offset", "goal")
# what ``sim.ArmJob`` and ``sim.run_job`` load on first use, imported before main with interrupts
# deferred (lfd.interrupts.run_script)
PRELOAD = ("sim.run.pipeline",)


def row(task: str, scenario: str, m: dict[str, Any]) -> str:
    """The report's table row of one run's metrics ``m``."""
    rec = m.get("recovery_time_s")
    return (f"| {task} | {scenario} | {1e3 * m['tracking_rmse_m']:.2f} | {m['tracking_rmse_deg']:.3f} | "
            f"{1e3 * m['final_goal_error_m']:.2f} | {m['final_goal_error_deg']:.3f} | "
            f"{'-' if 'recovery_time_s' not in m else 'never' if rec is None else f'{rec:.2f}'} | "
            f"{m['joint_limit_violations']} | {1e3 * m['imitation_dtw_m']:.1f} | "
            f"{m['imitation_orientation_error_deg']:.1f} | {m['realtime_factor']:.0f} |")


def main(argv: list[str] | None = None) -> int:
    """Run every task (module docstring) and write the report; returns the exit code."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--out", help="the runs' folders (default out/robottasks_arm; --quick: out/robottasks_arm-quick)")
    p.add_argument("--report", help="the report (default reports/robottasks_arm.md; --quick: "
                                     "out/robottasks_arm-quick/robottasks_arm.md)")
    p.add_argument("--quick", action="store_true", help="a smoke test: the first task, unperturbed")
    args = p.parse_args(argv)
    quick = Path("out") / "robottasks_arm-quick"
    out = Path(args.out or (quick if args.quick else Path("out") / "robottasks_arm"))
    report = Path(args.report or (quick / "robottasks_arm.md" if args.quick else Path("reports") / "robottasks_arm.md"))
    rows = []
    try:
        check_writable(report)
        for task in ROBOTTASKS[:1] if args.quick else ROBOTTASKS:
            job = sim.ArmJob(robot="panda", learners=("tracking",), demos=f"robottasks:{task}",
                             scenarios=("none",) if args.quick else SCENARIOS.get(task, DEFAULT_SCENARIOS),
                             shift=SHIFTS.get(task), out=str(out / task), overwrite=True, videos=False, plots=False,
                             quiet=True)
            rows += [row(task, r.scenario, r.metrics) for r in sim.run_job(job).results]
            print(f"{task}: done", flush=True)
    except (LfdError, SimError, RobotError, OSError) as e:
        return fail(PROG, str(e))
    shifts = ", ".join(f"{k} by ({', '.join(f'{v:g}' for v in s)}) m" for k, s in SHIFTS.items())
    text = "\n".join([
        "# RoboTasks9 on the Panda, where recorded (tracking learner)", "",
        "Regenerate: `python scripts/robottasks_arm.py`. Each task is trained on its 9 demos and run from",
        "demo 0's start for its duration plus 1.5 s, at 500 Hz with computed torque, through the 6 x 7 DLS.",
        f"Poses are the recorded ones in the Panda's base frame, except: {shifts} (a few samples are",
        "beyond the arm's reach in its tool frame `panda_hand_tcp` where recorded). pan2stove runs no",
        "`offset`: its start moved 5 cm is out of reach.", "",
        "Scenarios: `none`; `push` (20 N for 0.2 s at t = 1 s); `offset` (start 5 cm away, turned 30 deg);",
        "`goal` (goal moved 2 cm and turned 15 deg). Tracking: RMSE against the field's own rollout from",
        "the measured start. Imitation: the tool path's DTW per sample (mm) and RMS angle (deg) against",
        "demo 0, which the field does not copy (it follows the mean of the 9 demos).", "",
        "| task | scenario | track mm | track deg | goal mm | goal deg | recovery s | limit viol. | "
        "imit DTW mm | imit deg | RTF |",
        "|---|---|---|---|---|---|---|---|---|---|---|", *rows, ""])
    atomic_write(report, lambda f: f.write(text.encode()))
    print(f"wrote {report}")
    return 0
