"""The sweep's results page (``index.html`` in its output folder), from its summary and records
(``sim.studies.sweep``), written with ``lfd.pages``.

First what was run (the command, versions, the grid), then the verdict: a row per robot and learner
for each kind of run (success rate, final goal error, recovery, deviation, errors), the best of each
kind marked, and each failed run said in a sentence (a diverged simulation or a lost run with its
error, a goal missed beyond the tolerance, joint limits left, a push never recovered from); then the
heatmap and basin figures, and links to summary.json and every run's record.
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path
from typing import Any

from lfd.pages import DataFile, Media, MediaGroup, Page, Table, mark_best, number, pointer, text
from sim.metrics import RECOVERY_TOLERANCE_M

__all__ = ["failure_sentence", "sweep_page"]

#: (summary key, column, scale, format, better): a kind's columns (None: not compared)
COLUMNS: tuple[tuple[str, str, float, str, str | None], ...] = (
    ("runs", "runs", 1.0, ".0f", None),
    ("success_rate", "success (%)", 100.0, ".1f", "higher"),
    ("final_goal_error_m_median", "goal error, median (mm)", 1e3, ".2f", "lower"),
    ("recovered_rate", "recovered (%)", 100.0, ".1f", "higher"),
    ("recovery_time_s_median", "recovery, median (s)", 1.0, ".2f", "lower"),
    ("max_deviation_m_median", "max deviation, median (mm)", 1e3, ".1f", None),
    ("errors", "errors", 1.0, ".0f", None),
)
#: how many failed runs the verdict names one by one
MAX_NAMED = 25
UNITS = {"push": "N", "offset": "m", "goal": "m"}


def _run_label(r: dict[str, Any]) -> str:
    deg = math.degrees(float(r["angle_rad"])) % 360
    return (f"{r['robot']} / {r['learner']} / {r['kind']} {r['magnitude']:g} {UNITS.get(r['kind'], '')} "
            f"at {deg:.0f}°, seed {r['seed']}")


def failure_sentence(r: dict[str, Any]) -> str:
    """Why the failed run of record ``r`` failed, in one sentence."""
    label = _run_label(r)
    if r.get("error"):
        return f"{label}: {r['error']}."
    m = r.get("metrics") or {}
    why = []
    err, tol = float(m.get("final_goal_error_m", math.nan)), float(r.get("goal_tol_m", math.nan))
    if not err <= tol:
        how = " (blocked)" if m.get("blocked") else " (stopped short)" if m.get("stopped_short") else ""
        why.append(f"ended {err * 1e3:.1f} mm from its goal, beyond the tolerance of {tol * 1e3:g} mm{how}")
    if m.get("joint_limit_violations"):
        why.append(f"left its joint limits in {m['joint_limit_violations']} control steps")
    if r["kind"] == "push" and "recovery_time_s" in m and m["recovery_time_s"] is None:
        why.append(f"never came back within {RECOVERY_TOLERANCE_M * 1e3:g} mm of its unpushed path")
    return f"{label}: " + ("; ".join(why) or "failed") + "."


def _table(summary: dict[str, Any], kinds: list[str]) -> Table:
    """A row per robot and learner, grouped by kind (in the order of ``kinds``), the best marked."""
    rows, groups = [], []
    for kind in kinds:
        for key, s in summary.items():
            robot, learner, k = key.split("/")
            if k != kind:
                continue
            cells = [text(f"{robot} / {learner}")]
            for name, _, scale, spec, better in COLUMNS:
                cells.append(number(s[name], spec, pointer("summary", key, name), scale, better,
                                    bad=name == "errors" and s[name] > 0))
            rows.append(tuple(cells))
            groups.append(kind)
    return mark_best(Table("Every robot and learner, by kind of run", ("robot / learner", *(c[1] for c in COLUMNS)),
                           tuple(rows), tuple(groups)))


def sweep_page(out: Path, summary: dict[str, Any], records: list[dict[str, Any]], figures: list[Path],
               record_paths: list[Path]) -> Page:
    """The page of the sweep in ``out``: ``summary`` is summary.json's content, ``records`` the runs'
    records, ``figures`` the figures written, ``record_paths`` the records' files."""
    failed = [r for r in records if not r["success"]]
    ok = len(records) - len(failed)
    named = [failure_sentence(r) for r in failed[:MAX_NAMED]]
    if len(failed) > MAX_NAMED:
        named.append(f"... and {len(failed) - MAX_NAMED} more failed runs (their records are in runs/).")
    table = _table(summary["summary"], list(dict.fromkeys(r["kind"] for r in records)))
    best = []
    j = table.columns.index("success (%)")
    for kind in dict.fromkeys(table.groups):
        rows = [row for i, row in enumerate(table.rows) if table.groups[i] == kind]
        top = [row for row in rows if row[j].best]
        if top:
            who = "all tied" if len(top) == len(rows) else ", ".join(row[0].text for row in top)
            best.append(f"{kind}: {who} at {top[0][j].text} %")
    verdict = [f"{ok} of {len(records)} runs succeeded (ended within the goal tolerance, inside the joint limits)."]
    if best:
        verdict.append("Highest success rate: " + "; ".join(best) + ".")
    run = summary.get("run", {})
    grid = sorted({(r["kind"], r["magnitude"]) for r in records})
    facts = [("runs", f"{len(records)} ({run.get('computed', '?')} computed, {run.get('cached', '?')} from earlier)"),
             ("robots", ", ".join(sorted({r["robot"] for r in records}))),
             ("learners", ", ".join(dict.fromkeys(r["learner"] for r in records))),
             ("demos", ", ".join(sorted({r["demos"] for r in records}))),
             ("magnitudes", ", ".join(f"{k} {m:g} {UNITS.get(k, '')}" for k, m in grid)),
             ("directions", str(len({round(r["angle_rad"], 9) for r in records}))),
             ("seeds", ", ".join(str(s) for s in sorted({r["seed"] for r in records}))),
             ("executor", f"{run.get('executor', '?')}, {run.get('workers', '?')} worker(s), "
                          f"{run.get('wall_s', 0.0):.1f} s"),
             ("versions", ", ".join(f"{k} {v}" for k, v in summary.get("versions", {}).items()) or "not recorded")]
    captions = {"heatmap": "pushes: median recovery time and success rate by direction and force",
                "basin": "start offsets: where the runs started, filled where they reached the goal"}
    media = tuple(Media(p, captions.get(p.stem, p.stem), wide=True) for p in figures)
    files = [DataFile(out / "summary.json", "the summary: every group's rates and medians, how the sweep ran")]
    files += [DataFile(p, f"figure: {captions.get(p.stem, p.stem)}", _size(p)) for p in figures]
    files += [DataFile(p, f"record of {_run_label(r)}" + ("" if r["success"] else " (failed)"), _size(p))
              for p, r in zip(record_paths, records)]
    return Page(
        title="Arm sweep: robustness to pushes, start offsets and goal shifts",
        subtitle=f"{len(records)} runs, {ok} succeeded", command=shlex.join(summary.get("command") or []),
        facts=tuple(facts), verdict=tuple(verdict), failures=tuple(named), tables=(table,),
        figures=(MediaGroup("Robustness heatmap and basin of attraction", media),) if media else (), files=tuple(files),
        data_file=out / "summary.json", all_passed="No failures: every run succeeded.")


def _size(path: Path) -> int | None:
    return path.stat().st_size if path.exists() else None
