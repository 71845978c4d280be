"""The task benchmark's results page (``index.html`` in its output folder), from its episodes' records
(``sim.studies.task_bench``), written with ``lfd.pages``.

Success first: the verdict gives each learner's success rate with its 95% Wilson interval, in-sample
and held out; then the table (every split, learner and condition: all, unpushed, pushed), each failed
episode in a sentence, the videos (one success and one failure per learner where there is one), and
links to every episode's record.
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path
from typing import Any

from lfd.pages import DataFile, Media, MediaGroup, Page, Table, mark_best, number, text

__all__ = ["failure_sentence", "rates", "task_page", "wilson"]

#: what each task is called in a title
TITLES = {"pour": "pour", "place": "placement", "lid": "opening of a lid"}
#: how many failed episodes the page names one by one
MAX_NAMED = 25


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval (lo, hi) of a success rate successes / n at the normal quantile z."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def failure_sentence(r: dict[str, Any]) -> str:
    """Why the failed episode of record ``r`` failed, in one sentence."""
    split = f"held out (demo {r['held_out']} left out)" if r.get("held_out") is not None else "in-sample"
    where = "" if r["target_m"] is None else "object at " + ", ".join(f"{v:.3f}" for v in r["target_m"]) + " m"
    push = ("; " if where else "") + "pushed" if r["pushed"] else ""
    detail = f"{r['in_bowl']} of 12 balls in the bowl" if "in_bowl" in r else \
        f"the lid opened {r['angle_deg']:.0f} deg" if "angle_deg" in r else \
        f"the bottle {r['off_spot_m'] * 1e3:.0f} mm from its spot, tilted {r['tilt_deg']:.0f} deg"
    said = f" ({where}{push})" if where or push else ""
    return (f"{r['learner']}, {split} episode {r['episode']}{said}: {r['cause']}; "
            f"{detail}; the tool ended {r['goal_error_m'] * 1e3:.1f} mm from its goal.")


def rates(records: dict[tuple[str, str], list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Per split, learner and condition (all, unpushed, pushed): ``split``, ``learner``, ``label``, the
    episodes ``chosen``, ``k`` successes of ``n``, the Wilson interval ``lo``, ``hi`` and the failures'
    causes counted in words, ``why`` ("-" for none)."""
    out = []
    for (split, learner), recs in records.items():
        for label, chosen in (("all", recs), ("unpushed", [r for r in recs if not r["pushed"]]),
                              ("pushed", [r for r in recs if r["pushed"]])):
            k, n = sum(r["success"] for r in chosen), len(chosen)
            causes: dict[str, int] = {}
            for r in chosen:
                if not r["success"]:
                    causes[r["cause"]] = causes.get(r["cause"], 0) + 1
            out.append({"split": split, "learner": learner, "label": label, "chosen": chosen, "k": k, "n": n,
                        **dict(zip(("lo", "hi"), wilson(k, n))),
                        "why": ", ".join(f"{c} {m}" for c, m in sorted(causes.items())) or "-"})
    return out


def _table(records: dict[tuple[str, str], list[dict[str, Any]]]) -> Table:
    rows, groups = [], []
    for c in rates(records):
        k, n = c["k"], c["n"]
        rows.append((text(f"{c['learner']}, {c['label']}"), number(float(n), ".0f"),
                     number(k / n if n else None, ".2f", better="higher" if c["label"] == "all" else None),
                     text(f"[{c['lo']:.2f}, {c['hi']:.2f}]"), text(c["why"], bad=c["why"] != "-")))
        groups.append(c["split"])
    return mark_best(Table("Success by learner, split and condition (95% Wilson intervals)",
                           ("learner, condition", "episodes", "success rate", "95% interval", "failures"),
                           tuple(rows), tuple(groups)))


def task_page(out: Path, task: str, demos: str, records: dict[tuple[str, str], list[dict[str, Any]]],
              videos: list[tuple[Path, str]], record_paths: list[Path], report: Path, command: list[str],
              run: dict[str, Any]) -> Page:
    """The page of the benchmark in ``out``: ``records`` by (split, learner), ``videos`` (path, caption),
    every record's file, the Markdown ``report``, the ``command`` and how it ran (``run``)."""
    every = [r for recs in records.values() for r in recs]
    failed = [r for r in every if not r["success"]]
    named = [failure_sentence(r) for r in failed[:MAX_NAMED]]
    if len(failed) > MAX_NAMED:
        named.append(f"... and {len(failed) - MAX_NAMED} more failed episodes (their records are linked below).")
    verdict = []
    for split in dict.fromkeys(s for s, _ in records):
        parts = []
        for (s, learner), recs in records.items():
            if s == split:
                k, n = sum(r["success"] for r in recs), len(recs)
                lo, hi = wilson(k, n)
                parts.append(f"{learner} {k} of {n} ({k / max(n, 1):.2f}, [{lo:.2f}, {hi:.2f}])")
        verdict.append(f"{split}: " + "; ".join(parts) + ".")
    facts = [("task", task), ("demos", demos), ("episodes", f"{len(every)} ({run.get('computed', 0)} computed now)"),
             ("executor", f"{run.get('executor', '?')}, {run.get('workers', '?')} worker(s), "
                          f"{run.get('wall_s', 0.0):.0f} s")]
    media = tuple(Media(p, caption) for p, caption in videos)
    files = [DataFile(report, "the report (Markdown)")]
    files += [DataFile(p, f"record of {r['learner']}, {'held out' if r.get('held_out') is not None else 'in-sample'} "
                          f"episode {r['episode']}" + ("" if r["success"] else f" ({r['cause']})"),
                       p.stat().st_size if p.exists() else None) for p, r in zip(record_paths, every)]
    return Page(
        title=f"The learned {TITLES.get(task, task)}: success over randomized episodes",
        subtitle=f"{len(every)} episodes, {len(every) - len(failed)} succeeded", command=shlex.join(command),
        facts=tuple(facts), verdict=tuple(verdict), failures=tuple(named), tables=(_table(records),),
        videos=(MediaGroup("One success and one failure per learner", media),) if media else (),
        files=tuple(files), all_passed="No failures: every episode succeeded.")
