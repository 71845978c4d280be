"""The arm job as one library call: plan (demos -> models -> placement -> fields), then execute (runs ->
scores -> files).

::

    import sim
    job = sim.ArmJob(robot="planar", learners=("contraction",), scenarios=("none", "push"),
                     videos=False, out="out/quick")
    report = sim.run_job(job)          # trains or takes cached models, runs, writes, returns
    report.results[0].metrics          # sim.metrics' scores of the first run

``sim.run.plan.plan_job`` resolves and checks the job before any simulation, and trains or loads its
models; ``run_job`` executes the plan: each planned run on the plan's ``sim.Experiment``, the
obstacle contacts scored, and the files written by ``sim.run.outputs.OutputSet``: staged, then moved
into place together, ``metrics.json`` last (see ``sim.run.job_files``).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robots.limits import worst
from sim.run.experiment import RunResult
from sim.run.job import ArmJob, PushSpec
from sim.run.obstacle_runs import OBSTACLE_LEAD_S, OBSTACLE_TIME_FACTOR, grown
from sim.run.plan import JobPlan, PlannedRun, describe_goal_motion, plan_job
from sim.scene.obstacles import obstacle_contacts

__all__ = ["ArmJob", "JobReport", "OBSTACLE_LEAD_S", "OBSTACLE_TIME_FACTOR", "PushSpec", "grown", "run_job"]


@dataclass
class JobReport:
    """What ``run_job`` did: the scored runs, the models and where the files went."""

    results: list[RunResult]
    side_by_side: list[RunResult]
    grid: list[RunResult]
    models: dict[str, dict[str, Any]]
    out: Path
    json_path: Path
    n_videos: int
    report: dict[str, Any]


def run_job(job: ArmJob, on_run: Callable[[RunResult], None] | None = None) -> JobReport:
    """Run ``job`` (module docstring): plan, then run, score and write.

    Parameters
    ----------
    job : ArmJob
        The job's options.
    on_run : callable, optional
        Called with each scored run as it finishes.

    Returns
    -------
    JobReport
        The runs and where their files are (all written when this returns).
    """
    plan = plan_job(job)
    done: dict[str, list[RunResult]] = {"main": [], "side": [], "grid": []}
    t_sim = time.perf_counter()
    for run in plan.runs:
        same = [r for r in done["main"] if run.group == "side" and (r.learner, r.scenario) == (run.learner,
                                                                                             run.scenario)]
        done[run.group].append(same[0] if same else execute(plan, run, on_run))
    t_sim = time.perf_counter() - t_sim
    unique = list({id(r): r for group in done.values() for r in group}.values())   # a shared run once
    if plan.obstacles:
        for r in unique:
            contacts = obstacle_contacts(plan.exp.robot, r.trace.q, r.trace.t, r.trace.mocap_pos)
            r.metrics.update(obstacle_contacts=contacts.contacts, obstacle_steps_in_contact=contacts.steps_in_contact,
                             obstacle_min_clearance_m=contacts.min_clearance_m)
    if plan.task is not None:
        model = plan.exp.physics.model.ptr
        for r in unique:
            r.metrics["task"] = plan.task.score(model, plan.exp.robot, r.trace.frame_t, r.trace.frame_qpos,
                                                r.metrics["final_goal_error_m"])
        _say_task(plan, unique)
    _say_limits(plan, unique)
    settings = {"seed": job.seed, "goal_motion": describe_goal_motion(job),
                "goal": None if job.goal is None else list(job.goal)}
    files = plan.files
    report = files.write(plan.exp, done["main"], done["side"], done["grid"], plan.fields, plan.models, t_sim,
                         plan.progress, settings=settings)
    return JobReport(done["main"], done["side"], done["grid"], plan.models, files.out, files.json_path,
                     files.n_videos, report)


def execute(plan: JobPlan, run: PlannedRun, on_run: Callable[[RunResult], None] | None = None) -> RunResult:
    """One planned run, scored; a run that ended blocked or short of its goal is said on stderr."""
    exp, what = plan.exp, f"{run.learner} / {run.scenario}{run.note}"
    plan.say(f"running {what}")
    result = exp.run(plan.fields[run.learner], run.scenario, run.perturbations, seed=run.seed, progress=plan.progress)
    m = result.metrics
    if m.get("blocked"):
        print(f"blocked: {what} stopped {m['final_goal_error_m'] * 1e3:.0f} mm from its goal, "
              f"held {m['final_clearance_m'] * 1e3:.0f} mm clear of what is in its way", file=sys.stderr)
    elif m.get("stopped_short"):
        print(f"short: {what} ended {m['final_goal_error_m'] * 1e3:.0f} mm from its goal with nothing holding "
              f"it back: the field did not bring it there in {exp.duration_s:g} s", file=sys.stderr)
    if on_run is not None:
        on_run(result)
    return result


def _say_task(plan: JobPlan, runs: list[RunResult]) -> None:
    """One line on stderr (unless quiet): of ``runs`` (each once), those that did the task, and why the
    others did not."""
    if plan.job.quiet or not runs:
        return
    done = [r for r in runs if r.metrics["task"]["success"]]
    each = "; ".join(f"{r.learner}/{r.scenario} {r.metrics['task']['summary']}"
                     + ("" if r.metrics["task"]["success"] else f" ({r.metrics['task']['cause']})") for r in runs)
    print(f"{plan.job.task}: {len(done)} of {len(runs)} runs succeeded: {each}", file=sys.stderr)


def _say_limits(plan: JobPlan, runs: list[RunResult]) -> None:
    """One line on stderr (unless quiet) when ``runs`` (each once) went over the arm's published limits
    (``robots.limits``; metrics.json ``motion_limits`` holds each run's peaks, and with ``--limiter``
    ``command_limits`` those of the command stream), or when the limiter held the stream back."""
    key = "command_limits" if runs and "command_limits" in runs[0].metrics else "motion_limits"
    over = [r for r in runs if r.metrics[key]["violations"]]
    if plan.job.quiet:
        return
    name = plan.exp.limits.name
    if over:
        where = max(over, key=lambda r: worst(r.metrics[key])[1])
        what, peak = worst(where.metrics[key])
        rest = "the limiter's command stream went over them (a defect: please report it)" if key == "command_limits" \
            else "--limiter keeps the command stream within them"
        print(f"limits: {len(over)} of {len(runs)} runs went over {name}'s published limits, most {what} at "
              f"{peak:.2f}x its limit ({where.learner} / {where.scenario}); {rest} (metrics.json {key})",
              file=sys.stderr)
    elif key == "command_limits":
        held = max(runs, key=lambda r: r.metrics["limiter_active_s"])
        m = held.metrics
        if m["limiter_active_s"] > 0:
            t0, t1 = m["limiter_window_s"]
            print(f"limiter: held the command stream within {name}'s limits for {m['limiter_active_s']:.2f} s "
                  f"between {t0:.2f} s and {t1:.2f} s in the longest case ({held.learner} / {held.scenario}); "
                  "where it acts the motion lags its field", file=sys.stderr)
