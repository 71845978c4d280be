"""A suite report's results page: ``<report>.html`` beside ``<report>.md`` (``lfd.bench.report``),
written with ``lfd.pages``.

Beside the report, not ``index.html``: one folder holds several reports (``reports/lasa.md``,
``reports/robottasks.md``), each with its own page. First what was run (the command, seeds,
versions), then the verdict: a row per learner of the suite's headline metrics (means over units,
in-sample and held-out), the best of each column marked, and every failure in words (cells given
up or refused, diverged reproductions); then the figures; per-unit tables folded; the files.
"""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path
from typing import Any

from lfd.bench.suite import HELD_OUT, IN_SAMPLE, Suite
from lfd.pages import Cell, DataFile, Media, MediaGroup, Page, Table, mark_best, number, pointer, text

__all__ = ["DISTRIBUTIONS", "bench_failures", "bench_page"]

#: the distributions whose versions the page names
DISTRIBUTIONS = ("lfd-arm", "numpy", "torch", "torchdiffeq", "movement-primitives")


def _summary_table(suite: Suite, summary: dict[str, Any]) -> Table:
    """A row per learner and split (grouped by split): units, each headline metric's mean over
    units, the suite's own columns (in-sample), the best of each split marked."""
    rows, groups = [], []
    extras = suite.summary_columns()
    for split in (IN_SAMPLE, HELD_OUT):
        for learner, both in summary.items():
            s = both[split]
            if s is None:
                continue
            cells: list[Cell] = [text(learner), number(s["units"], ".0f")]
            for m in suite.headline:
                v = s["metrics"][m]["mean"]
                cells.append(number(v, suite.formats[m], pointer("summary", learner, split, "metrics", m, "mean"),
                                    better="lower", bad=math.isinf(v)))
            cells += [text(c.text(c.value(s)) if split == IN_SAMPLE else "—") for c in extras]
            rows.append(tuple(cells))
            groups.append(f"{split}: mean over {suite.unit}s" + (
                "" if split == IN_SAMPLE else " (each demo scored by a field trained without it)"))
    columns = (f"{suite.unit}s", *(suite.labels[m] for m in suite.headline), *(c.label for c in extras))
    return mark_best(Table("Every learner, by split", ("learner", *columns), tuple(rows), tuple(groups)))


def _unit_table(suite: Suite, rows: dict[str, Any], units: list[str], metric: str, split: str) -> Table | None:
    """A row per unit, a column per learner: ``metric`` of ``split``, the best of each row marked."""
    learners = [lr for lr in rows if rows[lr][split]]
    if not learners:
        return None
    body = [(text(u), *(number(rows[lr][split][u]["metrics"][metric], suite.formats[metric], better="lower")
                        if u in rows[lr][split] else number(None, ".0f") for lr in learners))
            for u in units if any(u in rows[lr][split] for lr in learners)]
    return mark_best(Table(f"{suite.labels[metric]} per {suite.unit}, {split}", (suite.unit, *learners),
                           tuple(body)), along="rows")


def bench_failures(suite: Suite, rows: dict[str, Any], run: dict[str, Any]) -> list[str]:
    """Each failure in a sentence: cells given up or refused (``run["failed"]``), units whose
    reproduction diverged (an infinite metric in ``rows``, ``lfd.bench.summary.rows_by``)."""
    out = []
    for f in run.get("failed") or []:
        if f.get("refused"):
            out.append(f"Cell {f['cell']} was refused by its learner ({f['reason']}); it is not in the tables.")
        else:
            out.append(f"Cell {f['cell']} was given up after {f['attempts']} tries ({f['reason']}); "
                       "it is not in the tables.")
    for learner, by_split in rows.items():
        for split, by_unit in by_split.items():
            bad = [u for u, r in by_unit.items() if any(math.isinf(v) for v in r["metrics"].values())]
            if bad:
                out.append(f"{learner} diverged on {len(bad)} {suite.unit}(s), {split}: {', '.join(bad)} "
                           "(a reproduction left every bound; its metrics are infinite).")
    return out


def _best_sentence(table: Table) -> str:
    """'Best in-sample: DTW tracking, RMSE dmp; held-out: ...' from the table's marks."""
    parts = []
    for group in dict.fromkeys(table.groups):
        said = []
        for j, column in enumerate(table.columns):
            best = [row[0].text for i, row in enumerate(table.rows) if table.groups[i] == group and row[j].best]
            if best:
                said.append(f"{column} {' and '.join(best)}")
        if said:
            parts.append(f"{group.split(':')[0]}: {', '.join(said)}")
    return "Best " + "; ".join(parts) + "." if parts else ""


def bench_page(suite: Suite, summary: dict[str, Any], rows: dict[str, Any], units: list[str], run: dict[str, Any],
               figures: dict[str, list[tuple[str, Path]]], report: Path, json_path: Path | None,
               versions: dict[str, str]) -> Page:
    """The page of the report at ``report``: ``summary`` and ``rows`` are ``lfd.bench.summary``'s
    ``summarize`` and ``rows_by`` of the records, ``figures`` the suite's, ``json_path`` the
    results JSON (whose ``summary`` the table's numbers point into; None: not linked)."""
    table = _summary_table(suite, summary)
    fallback = sorted({f"{lr} ({u}, {s})" for lr, by in rows.items() for s, bu in by.items()
                       for u, r in bu.items() if r["fallback"]})
    verdict = [v for v in (_best_sentence(table),) if v]
    if fallback:
        verdict.append("A rollout needed the fixed-step RK4 fallback: " + ", ".join(fallback) + ".")
    details = [t for m in suite.headline for s in (IN_SAMPLE, HELD_OUT)
               if (t := _unit_table(suite, rows, units, m, s)) is not None]
    groups = [MediaGroup(where or "Figures", tuple(Media(p, alt, wide=True) for alt, p in shown))
              for where, shown in figures.items() if shown]
    files = [DataFile(report, "the report (markdown)", _size(report))]
    if json_path is not None:
        files.append(DataFile(json_path, "every cell's record and the summary"))   # written after the page
    files += [DataFile(p, f"figure: {alt}", _size(p)) for shown in figures.values() for alt, p in shown]
    shown_units = ", ".join(units) if len(units) <= 12 else f"{', '.join(units[:12])}, ... ({len(units)} in all)"
    facts = (("seeds", ", ".join(str(s) for s in run.get("seeds", []))), (f"{suite.unit}s", shown_units),
             ("protocol", f"{suite.name}, version {suite.protocol.to_dict()['version']}"),
             ("cells", f"{run['computed']} computed, {run['cached']} from the cache"),
             ("workers", f"{run['workers']} on {run['cpus']} CPU cores, {run['wall_s']:.0f} s"),
             ("written", _dt.datetime.now().isoformat(timespec="seconds")),
             ("versions", ", ".join(f"{k} {v}" for k, v in versions.items())))
    return Page(title=suite.title, subtitle=f"{len(summary)} learner(s) on {len(units)} {suite.unit}(s)",
                command=run["command"], facts=facts, verdict=tuple(verdict),
                failures=tuple(bench_failures(suite, rows, run)), tables=(table,), figures=tuple(groups),
                details=tuple(details), files=tuple(files), data_file=json_path,
                all_passed="No failures: every cell ran, and no reproduction diverged.")


def _size(path: Path) -> int | None:
    return path.stat().st_size if path.exists() else None
