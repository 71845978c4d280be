"""The arm job's results page (``index.html`` in its output folder), assembled from what its
metrics.json holds (``sim.run.job_files``) and written with ``lfd.pages``.

First what was run (the command, seed, versions, settings), then the verdict: a task's success first
(``--task``), a table per run (learner x scenario) of the headline metrics, the best of each scenario
marked, and every failure said in a sentence (a task not done, blocked, stopped short, a goal error
above ``BLOCKED_GOAL_M``, joint-limit violations, a push never recovered from, obstacle contacts); then
the videos (the side-by-side and grid videos first, then a row of learners per scenario), the figures
and every file.
"""

from __future__ import annotations

import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lfd.pages import Cell, DataFile, Media, MediaGroup, Page, Table, mark_best, number, pointer, text
from sim.metrics import BLOCKED_GOAL_M, RECOVERY_TOLERANCE_M

__all__ = ["HEADLINE", "job_page", "run_problems"]

#: (metric, column, scale, format, compared): the verdict table's columns, each shown when a run has it
COLUMNS: tuple[tuple[str, str, float, str, bool], ...] = (
    ("final_goal_error_m", "goal error (mm)", 1e3, ".2f", True),
    ("tracking_rmse_m", "tracking RMSE (mm)", 1e3, ".2f", True),
    ("imitation_dtw_m", "imitation DTW (mm)", 1e3, ".2f", True),
    ("recovery_time_s", "recovery (s)", 1.0, ".2f", True),
    ("max_deviation_m", "max deviation (mm)", 1e3, ".1f", False),
    ("final_goal_error_deg", "goal error (°)", 1.0, ".2f", True),
    ("tracking_rmse_deg", "tracking RMSE (°)", 1.0, ".2f", True),
    ("obstacle_min_clearance_m", "obstacle clearance (mm)", 1e3, ".1f", False),
    ("joint_limit_violations", "joint-limit violations", 1.0, ".0f", False),
    ("limiter_active_s", "limiter acting (s)", 1.0, ".2f", False),
)
#: the metrics whose best is named in the verdict's sentence, with their words
HEADLINE: dict[str, str] = {"final_goal_error_m": "goal error", "tracking_rmse_m": "tracking",
                            "imitation_dtw_m": "imitation DTW", "recovery_time_s": "recovery"}
#: the distributions whose versions a page names
DISTRIBUTIONS = ("lfd-arm", "numpy", "torch", "mujoco", "pin", "dm-control")


def describe_scenario(name: str, perturbations: list[dict[str, Any]]) -> str:
    """A scenario in words, from its perturbations' ``describe()`` dicts."""
    words = []
    for p in perturbations:
        kind = p.get("kind")
        if kind == "push":
            words.append(f"{p['force_n']:g} N push for {p['duration_s']:g} s from t = {p['start_s']:g} s")
        elif kind in ("offset", "goal"):
            what = "start" if kind == "offset" else "goal"
            turn = f", turned {p['angle_deg']:g}°" if p.get("angle_deg") else ""
            words.append(f"{what} moved {p['distance_m'] * 100:g} cm{turn}")
        elif kind == "hold":
            words.append(f"held still for {p['duration_s']:g} s from t = {p['start_s']:g} s")
        elif kind == "noise":
            words.append(f"joint-velocity noise {p['std_rad_s']:g} rad/s")
        else:
            words.append(str(kind))
    return f"{name}: {'; '.join(words) or 'no perturbation'}"


def run_problems(label: str, m: dict[str, Any], duration_s: float) -> list[str]:
    """Each failure of a run with metrics ``m`` in one sentence (none: it passed)."""
    out = []
    task = m.get("task")
    if task and not task["success"]:
        out.append(f"{label} did not do its {task['task']} ({task['cause']}): {task['summary']}.")
    err = float(m["final_goal_error_m"]) * 1e3
    if m.get("blocked"):
        clear = m.get("final_clearance_m")
        held = "" if clear is None else f", {clear * 1e3:.0f} mm clear of what is in its way"
        out.append(f"{label} was blocked {err:.1f} mm from its goal: a collision damper held the arm back{held}.")
    elif m.get("stopped_short"):
        out.append(f"{label} stopped short, {err:.1f} mm from its goal with nothing holding it back: the field "
                   f"did not bring it there in the run's {duration_s:g} s.")
    elif err > BLOCKED_GOAL_M * 1e3:
        out.append(f"{label} ended {err:.1f} mm from its goal, more than {BLOCKED_GOAL_M * 1e3:g} mm.")
    if m.get("joint_limit_violations"):
        out.append(f"{label} left its joint limits in {m['joint_limit_violations']} control steps.")
    if "recovery_time_s" in m and m["recovery_time_s"] is None:
        dev = m.get("max_deviation_m")
        worst = "" if dev is None else f" (it was pushed up to {dev * 1e3:.1f} mm away)"
        out.append(f"{label} never came back within {RECOVERY_TOLERANCE_M * 1e3:g} mm of its unpushed path "
                   f"after the push{worst}.")
    over = m.get("command_limits", {}).get("violations")
    if over:
        out.append(f"{label} sent {over} commands over the arm's published limits.")
    if m.get("obstacle_steps_in_contact"):
        out.append(f"{label} touched an obstacle in {m['obstacle_steps_in_contact']} control steps.")
    return out


def _status(m: dict[str, Any]) -> Cell:
    """A run's status in a few words."""
    words = [w for w, bad in (("blocked", m.get("blocked")), ("stopped short", m.get("stopped_short")),
                              ("goal missed", not m.get("blocked") and not m.get("stopped_short")
                               and float(m["final_goal_error_m"]) > BLOCKED_GOAL_M),
                              ("joint limits", m.get("joint_limit_violations")),
                              ("not recovered", "recovery_time_s" in m and m["recovery_time_s"] is None),
                              ("contact", m.get("obstacle_steps_in_contact"))) if bad]
    return text(", ".join(words), bad=True) if words else text("ok")


def _metric_cell(m: dict[str, Any], key: str, scale: float, spec: str, compared: bool, source: str) -> Cell:
    if key not in m:
        return number(None, spec)
    v = m[key]
    if key == "recovery_time_s" and v is None:
        return number(None, spec, source, scale, missing="never", bad=True)
    bad = (key == "final_goal_error_m" and v > BLOCKED_GOAL_M) or (key == "joint_limit_violations" and v > 0)
    return number(v, spec, source, scale, better="lower" if compared else None, bad=bool(bad))


def runs_table(title: str, runs: list[dict[str, Any]], at: tuple[str, ...], by_scenario: bool = True) -> Table:
    """The metrics of ``runs`` (metrics.json entries, the list at the keys ``at``), a row per run, grouped
    by scenario (learners in their order), the best of each group marked."""
    shown = [c for c in COLUMNS if any(c[0] in r["metrics"] for r in runs)]
    order = list(range(len(runs)))
    if by_scenario:
        scenarios = list(dict.fromkeys(r["scenario"] for r in runs))
        order.sort(key=lambda i: scenarios.index(runs[i]["scenario"]))
    rows, groups = [], []
    for i in order:
        r = runs[i]
        name = r["learner"] + (f", seed {r['seed']}" if "seed" in r else "")
        cells = [text(name), *(_metric_cell(r["metrics"], k, s, f, c, pointer(*at, i, "metrics", k))
                               for k, _, s, f, c in shown), _status(r["metrics"])]
        rows.append(tuple(cells))
        groups.append(describe_scenario(r["scenario"], r["perturbations"]))
    return mark_best(Table(title, ("learner", *(c[1] for c in shown), "status"), tuple(rows),
                           tuple(groups) if by_scenario else ()))


def _best_sentence(table: Table) -> str:
    """'Best per scenario: goal error contraction (2 of 3); ...' from the table's marks: per headline
    metric, how often each learner was best among the scenarios that compare it."""
    parts = []
    for key, words in HEADLINE.items():
        label = next(c[1] for c in COLUMNS if c[0] == key)
        if label not in table.columns:
            continue
        j = table.columns.index(label)
        wins: dict[str, int] = {}
        compared = set()
        for i, row in enumerate(table.rows):
            if row[j].best:
                wins[row[0].text] = wins.get(row[0].text, 0) + 1
                compared.add(table.group_of(i))
        if wins:
            who = ", ".join(f"{k} ({v} of {len(compared)})" for k, v in sorted(wins.items(), key=lambda kv: -kv[1]))
            parts.append(f"{words} {who}")
    return ("Best per scenario (ties count for each): " + "; ".join(parts) + ".") if parts else ""


def _short(spec: str) -> str:
    """A demo spec for a title: a file's name, or the spec (``spiral``, ``lasa:Angle``)."""
    return spec if ":" in spec else Path(spec).name


def _videos(report: dict[str, Any], learners: list[str], scenarios: list[str]) -> list[MediaGroup]:
    """The side-by-side and grid videos (each with its runs' table), then a row of learners per scenario."""
    out = []
    if "side_by_side" in report:
        sbs = report["side_by_side"]
        out.append(MediaGroup(f"Side by side: {sbs['runs'][0]['scenario']}", (Media(
            Path(sbs["video"]), " | ".join(r["learner"] for r in sbs["runs"]), wide=True),), columns=1,
            tables=(runs_table("The side-by-side runs", sbs["runs"], ("side_by_side", "runs"), by_scenario=False),)))
    if "grid" in report:
        grid = report["grid"]
        out.append(MediaGroup(f"{len(grid['runs'])} seeded pushes of {grid['runs'][0]['learner']}", (Media(
            Path(grid["video"]), "one panel per seed", wide=True),), columns=1,
            tables=(runs_table("The grid's runs", grid["runs"], ("grid", "runs"), by_scenario=False),)))
    for name in scenarios:
        mine = [r for r in report["runs"] if r["scenario"] == name]
        items = tuple(Media(Path(r["video"]), f"{r['learner']} / {name}") for r in mine if "video" in r)
        if items:
            out.append(MediaGroup(describe_scenario(name, mine[0]["perturbations"]), items, columns=len(learners)))
    return out


def _loss_or_paths(name: str) -> str:
    """What the job figure ``name`` (``paths``, ``loss_<learner>``) shows."""
    return "tool paths over the demos" if name == "paths" else f"training loss of {name.removeprefix('loss_')}"


def _figures(report: dict[str, Any], learners: list[str], scenarios: list[str]) -> list[MediaGroup]:
    """The tool paths and training losses, then each scenario's run figures."""
    extra = report.get("figures", {})
    out = [MediaGroup("Tool paths and training", tuple(Media(Path(p), _loss_or_paths(k)) for k, p in extra.items()))
           ] if extra else []
    for name in scenarios:
        items = tuple(Media(Path(r["plot"]), f"{r['learner']} / {name}: tracking error, deviation and joints")
                      for r in report["runs"] if r["scenario"] == name and "plot" in r)
        if items:
            out.append(MediaGroup(f"Time series: {name}", items, columns=min(len(learners), 3)))
    return out


def _files(report: dict[str, Any], json_path: Path, size: Callable[[Path], int | None]) -> list[DataFile]:
    """metrics.json, then each run's video, time series and figure, the extra videos and figures."""
    listed = [(json_path, "the runs' metrics, the settings and every file's path")]
    for r in report["runs"]:
        label = f"{r['learner']} / {r['scenario']}"
        listed += [(Path(r[k]), f"{what} of {label}")
                   for k, what in (("video", "video"), ("timeseries", "time series"), ("plot", "figure")) if k in r]
    listed += [(Path(report[k]["video"]), what) for k, what in (("side_by_side", "side-by-side video"),
                                                                ("grid", "grid video")) if k in report]
    listed += [(Path(p), f"figure: {_loss_or_paths(k)}") for k, p in report.get("figures", {}).items()]
    return [DataFile(p, what, size(p)) for p, what in listed]


def _facts(report: dict[str, Any]) -> list[tuple[str, str]]:
    """Seed, robot, demos, run length, learners, video, time and versions."""
    s = report["settings"]
    video = s["video"]
    return [("seed", str(s["seed"])), ("robot", f"{s['robot']} ({s['actuation']}, IK {s['ik']}, "
                                                 f"{s['control_hz']:g} Hz"
                                                 + (", joint velocities through the limiter" if s.get("limiter")
                                                    else "") + ")"),
            ("demos", f"{s['demos']} (demo {s['demo_index']})"), ("run length", f"{s['duration_s']:g} s"),
            ("learners", ", ".join(f"{k} ({'trained' if v.get('trained_now') else 'cached'})"
                                   for k, v in report["models"].items())),
            ("video", f"{video['size'][0]}x{video['size'][1]} at {video['fps']:g} fps, camera {video['camera']}"),
            ("created", str(report["created"])),
            ("versions", ", ".join(f"{k} {v}" for k, v in report.get("versions", {}).items()) or "not recorded")]


def job_page(report: dict[str, Any], json_path: Path, size: Callable[[Path], int | None]) -> Page:
    """The page of the arm job whose metrics.json content is ``report`` (module docstring);
    ``json_path`` is that metrics.json, ``size`` gives a written file's size in bytes (or None)."""
    s, runs = report["settings"], report["runs"]
    learners = list(dict.fromkeys(r["learner"] for r in runs))
    scenarios = list(dict.fromkeys(r["scenario"] for r in runs))
    table = runs_table("Every run: headline metrics by scenario", runs, ("runs",))
    said = [(f"{r['learner']} / {r['scenario']}", r["metrics"]) for r in runs]
    done = {(r["learner"], r["scenario"]) for r in runs}   # a side-by-side panel of a run above: said once
    said += [(f"{r['learner']} / {r['scenario']} (side by side)", r["metrics"])
             for r in report.get("side_by_side", {}).get("runs", []) if (r["learner"], r["scenario"]) not in done]
    said += [(f"{r['learner']} / push, seed {r['seed']} (grid)", r["metrics"])
             for r in report.get("grid", {}).get("runs", [])]
    failures = [p for label, m in said for p in run_problems(label, m, float(s["duration_s"]))]
    tasks = [r for r in runs if r["metrics"].get("task")]   # a task's success first: what the user asked
    done_task = [r for r in tasks if r["metrics"]["task"]["success"]]
    first = [f"{tasks[0]['metrics']['task']['task']}: {len(done_task)} of {len(tasks)} runs succeeded ("
             + "; ".join(f"{r['learner']} / {r['scenario']}: {r['metrics']['task']['summary']}" for r in tasks)
             + ")."] if tasks else []
    return Page(
        title=f"Arm run: {_short(s['demos'])} on {s['robot']}",
        subtitle=f"{len(learners)} learner(s) x {len(scenarios)} scenario(s), {len(runs)} run(s); seed {s['seed']}",
        command=shlex.join(report.get("command") or []), facts=tuple(_facts(report)),
        verdict=tuple(v for v in (*first, _best_sentence(table)) if v), failures=tuple(failures), tables=(table,),
        videos=tuple(_videos(report, learners, scenarios)), figures=tuple(_figures(report, learners, scenarios)),
        files=tuple(_files(report, json_path, size)), data_file=json_path,
        all_passed=f"No failures: every run ended within {BLOCKED_GOAL_M * 1e3:g} mm of its goal, inside its "
                   "joint limits" + (", and came back after its push." if "push" in scenarios else "."))
