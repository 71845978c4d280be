"""The command stream a real arm would take: the default job and the nine RoboTasks9 tasks at 1 kHz
through ``robots.controller.ArmController`` and its jerk-limited limiter, against today's 500 Hz runs;
writes reports/stream.md. Run by ``scripts/stream_limits.py``.

Part 1, the default job's spiral (tracking learner, torque-driven Panda): the scenarios none,
offset and push at 500 Hz without a limiter (``scripts/demo_arm.py``'s default) and at 1 kHz with
``--limiter``; per run the tool tracking RMSE, the DTW to the demo, the goal error, the push
recovery, the command stream's peak fractions of the Panda's limits (``robots.limits``) and the
time the limiter acted. Part 2: the goal contraction's field with its goal jumping 10 cm in 0.1 s
at t = 2 s (``lfd.goal.shift_goal``). Part 3: every RoboTasks9 task (poses) at 1 kHz with the
limiter, unperturbed and pushed. Part 4: the spiral at ``--speed`` 0.5, 1.5 and 2 through the
limiter: the arrival (the time after which the tool stays within 2 mm of the goal) times S over
that of S = 1, the DTW to the demo over that of S = 1, and how long the limiter held the stream.
Part 5: ``--via``, a point 3 cm off the path mid-motion, for the tracking learner and the goal
contraction, through the limiter. Part 6: the limiter's own cost per call, against the scene's bare
``mj_step`` at 1 kHz.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

import lfd
import sim
from lfd.demos import ROBOTTASKS
from lfd.errors import LfdError
from lfd.goal import shift_goal
from lfd.io import atomic_write, check_writable
from lfd.metrics import dtw
from robots import RobotError, load_robot
from robots.limiter import JointLimiter
from robots.limits import PANDA
from sim.errors import SimError
from sim.run.experiment import Experiment
from sim.run.parsing import OneLineParser, fail
from sim.run.plan import plan_job
from sim.studies.robottasks import SHIFTS

__all__ = ["main"]

PROG = "stream_limits"
PRELOAD = ("sim.run.pipeline",)


def _peaks(m: dict[str, Any], key: str) -> str:
    joint = m[key]["joint"]
    return " / ".join(f"{joint[o]['peak']:.2f}" for o in ("velocity", "acceleration", "jerk"))


def _row(label: str, scenario: str, m: dict[str, Any]) -> str:
    rec = m.get("recovery_time_s")
    back = "-" if "recovery_time_s" not in m else "never" if rec is None else f"{rec:.2f}"
    lim = f"{m['limiter_active_s']:.2f}" if "limiter_active_s" in m else "-"
    cmd = _peaks(m, "command_limits") if "command_limits" in m else "-"
    viol = m["command_limits"]["violations"] if "command_limits" in m else "-"
    return (f"| {label} | {scenario} | {1e3 * m['tracking_rmse_m']:.2f} | {1e3 * m['imitation_dtw_m']:.2f} | "
            f"{1e3 * m['final_goal_error_m']:.2f} | {back} | "
            f"{_peaks(m, 'motion_limits')} | {cmd} | {viol} | {lim} |")


def _arrival(r: Any) -> float:
    """The time after which the run's tool stays within 2 mm of its goal, s."""
    err = np.linalg.norm(r.trace.ee - r.trace.goal_world, axis=1)
    far = np.flatnonzero(err > 2e-3)
    return float(r.trace.t[far[-1] + 1]) if len(far) else 0.0


def _speeds() -> list[str]:
    """Part 4's rows."""
    base: dict[str, Any] = dict(learners=("tracking",), scenarios=("none",), control_hz=1000.0, limiter=True,
                                videos=False, plots=False, quiet=True, overwrite=True)
    runs = {S: sim.run_job(sim.ArmJob(speed=S, out=f"out/stream/speed-{S:g}", **base)).results[0]
            for S in (1.0, 0.5, 1.5, 2.0)}
    one = runs[1.0]
    rows = []
    for S, r in runs.items():
        m = r.metrics
        rows.append(f"| {S:g} | {_arrival(r) * S / _arrival(one):.3f} | "
                    f"{m['imitation_dtw_m'] / one.metrics['imitation_dtw_m']:.2f} | {1e3 * m['tracking_rmse_m']:.2f} | "
                    f"{1e3 * m['final_goal_error_m']:.2f} | {m['limiter_active_s']:.2f} | "
                    f"{m['command_limits']['violations']} |")
    return rows


def _vias() -> list[str]:
    """Part 5's rows: each learner with and without a point 3 cm off its path at phase 0.5."""
    rows = []
    for learner in ("tracking", "contraction"):
        base: dict[str, Any] = dict(learners=(learner,), scenarios=("none",), control_hz=1000.0, limiter=True,
                                    videos=False, plots=False, quiet=True, overwrite=True)
        plan = plan_job(sim.ArmJob(out=f"out/stream/via-{learner}-plan", **base))
        exp, field = plan.exp, plan.fields[learner]
        T = float(exp.setup.demo_t[-1])
        path = field.trajectory(exp.start, np.linspace(0.0, T, 1001))[0]
        tangent = path[501] - path[499]
        v = path[500] + 0.03 / exp.placement.scale * np.array([-tangent[1], tangent[0]]) / np.linalg.norm(tangent)
        plain = sim.run_job(sim.ArmJob(out=f"out/stream/via-{learner}-plain", **base)).results[0]
        via = sim.run_job(sim.ArmJob(out=f"out/stream/via-{learner}", via=(f"{float(v[0])!r},{float(v[1])!r}@0.5",),
                                     **base)).results[0]
        demo, t = exp.setup.task_demos.x[0], exp.setup.task_demos.t[0]
        point = exp.placement.to_world(v[None])[0]
        for name, r in (("without", plain), ("with", via)):
            xs = exp.placement.to_task(r.trace.ee[r.trace.steps_at(t)])
            outside = sum(dtw(xs[m], demo[m]) / np.count_nonzero(m) for m in (t < 0.3 * T, t > 0.7 * T))
            rows.append(f"| {learner} | {name} | {1e3 * np.linalg.norm(r.trace.ee - point, axis=1).min():.2f} | "
                        f"{1e3 * r.metrics['final_goal_error_m']:.2f} | {1e3 * exp.placement.scale * outside:.2f} | "
                        f"{r.metrics['command_limits']['violations']} |")
    return rows


def _limiter_cost() -> tuple[float, float]:
    """(limiter us per call, bare mj_step us at 1 kHz) on the Panda."""
    lim = JointLimiter(PANDA, 1e-3)
    rng = np.random.default_rng(0)
    targets = rng.uniform(-1, 1, (4000, 7))
    t0 = time.perf_counter()
    for t in targets:
        lim(t)
    us = (time.perf_counter() - t0) / len(targets) * 1e6
    robot = load_robot("panda", actuation="torque")
    model = robot.mj_model
    model.opt.timestep = 1e-3
    data = mujoco.MjData(model)
    t0 = time.perf_counter()
    for _ in range(4000):
        mujoco.mj_step(model, data)
    return us, (time.perf_counter() - t0) / 4000 * 1e6


def main(argv: list[str] | None = None) -> int:
    """Run the parts of the module docstring and write the report; returns the exit code."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--report", default="reports/stream.md", help="the report (default reports/stream.md)")
    args = p.parse_args(argv)
    report = Path(args.report)
    header = ["| run | scenario | track mm | DTW mm | goal mm | recovery s | measured v / a / j peak | "
              "command v / a / j peak | command over | limiter s |", "|---|---|---|---|---|---|---|---|---|---|"]
    try:
        check_writable(report)
        spiral = []
        for hz, limiter in ((500.0, False), (1000.0, True)):
            job = sim.ArmJob(learners=("tracking",), control_hz=hz, limiter=limiter, videos=False, plots=False,
                             quiet=True, overwrite=True, out=f"out/stream/spiral-{int(hz)}")
            spiral += [_row(f"spiral {hz:g} Hz{' limited' if limiter else ''}", r.scenario, r.metrics)
                       for r in sim.run_job(job).results]
        print("spiral: done", flush=True)
        robot = load_robot("panda", actuation="torque")
        demos = lfd.load_demos("spiral")
        auto = lfd.train("contraction", demos, seed=0)
        jumps = []
        for hz, limiter in ((500.0, False), (1000.0, True)):
            exp = Experiment(robot, demos, control_hz=hz, limiter=limiter)
            jump = shift_goal(auto, 2.0, np.array([0.1, 0.0])[:auto.dim] / exp.placement.scale, blend=0.1)
            jumps.append(_row(f"goal jump {hz:g} Hz{' limited' if limiter else ''}", "none",
                              exp.run(jump, "none").metrics))
        print("goal jump: done", flush=True)
        tasks = []
        for task in ROBOTTASKS:
            job = sim.ArmJob(learners=("tracking",), demos=f"robottasks:{task}", scenarios=("none", "push"),
                             shift=SHIFTS.get(task), control_hz=1000.0, limiter=True, videos=False, plots=False,
                             quiet=True, overwrite=True, out=f"out/stream/{task}")
            tasks += [_row(task, r.scenario, r.metrics) for r in sim.run_job(job).results]
            print(f"{task}: done", flush=True)
        speeds = _speeds()
        print("speed: done", flush=True)
        vias = _vias()
        print("via: done", flush=True)
        us, step_us = _limiter_cost()
    except (LfdError, SimError, RobotError, OSError) as e:
        return fail(PROG, str(e))
    text = "\n".join([
        "# The command stream at 1 kHz within the Panda's limits", "",
        "Protocol: not a benchmark suite's; `python scripts/stream_limits.py` (sim.studies.stream), 2-core machine.",
        "Torque-driven Panda; 500 Hz rows are",
        "today's default (no limiter); `limited` rows run at 1 kHz (1 ms physics) through",
        "`robots.controller.ArmController` with its Ruckig limiter at 0.95 of each published limit",
        "(`--control-hz 1000 --limiter`). Peaks are fractions of the limit, worst joint: `measured` from the",
        "arm's motion by differences, `command` from the joint-velocity stream sent. Push: 20 N for 0.2 s.", "",
        "## The default job's spiral (tracking learner)", "", *header, *spiral, "",
        "## A goal jump of 10 cm in 0.1 s at t = 2 s (goal contraction)", "", *header, *jumps, "",
        "## RoboTasks9 on the Panda at 1 kHz, limited (tracking learner)", "", *header, *tasks, "",
        "## Speed through the limiter (`--speed S`, tracking learner)", "",
        "| S | arrival x S / S=1 | DTW / S=1 | track mm | goal mm | limiter s | command over |",
        "|---|---|---|---|---|---|---|", *speeds, "",
        "## A via-point 3 cm off the path at phase 0.5 (`--via`), through the limiter", "",
        "DTW outside: the DTW per demo sample over the phases outside [0.3, 0.7], away from the detour.", "",
        "| learner | via-point | closest to it mm | goal mm | DTW outside mm | command over |",
        "|---|---|---|---|---|---|", *vias, "",
        "## Cost", "",
        f"The limiter: {us:.2f} us per call (7 joints, Ruckig's velocity interface); the Panda scene's bare",
        f"`mj_step` at 1 ms: {step_us:.2f} us on the same machine.", ""])
    atomic_write(report, lambda f: f.write(text.encode()))
    print(f"wrote {report}")
    return 0
