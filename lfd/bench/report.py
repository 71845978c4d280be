"""A suite's report: one markdown file and its figures, the same sections for every suite.

``write_report`` writes: the protocol (``Suite.intro``) and how the run went; the in-sample summary
(mean / median over units of every metric, and the suite's columns), the in-sample and held-out
table (each headline metric in both splits and their ratio, ``lfd.bench.summary.compare_splits``),
the held-out summary; the suite's own sections; a reading generated from the numbers; per learner
a table with a row per unit, **Mean** and **Median** rows, in each split; and the suite's figures.
Beside it, its results page (``lfd.bench.report_page``): ``<report stem>.html``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lfd.bench.report_page import DISTRIBUTIONS, bench_page
from lfd.bench.suite import HELD_OUT, IN_SAMPLE, Column, Suite
from lfd.bench.summary import COMPARISON, rows_by, summarize
from lfd.io import atomic_write
from lfd.pages import versions, write_page

Arrays = Callable[[dict[str, Any]], dict[str, np.ndarray]]


def fmt(v: Any, spec: str) -> str:
    """A number for a report table with ``spec``: a dash for None or NaN, ``inf`` for infinity."""
    if v is None:
        return "—"
    v = float(v)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "inf"
    return format(v, spec)


def pct(v: Any) -> str:
    """A fraction as a percentage with one decimal (a dash for None or NaN)."""
    return "—" if v is None or math.isnan(float(v)) else f"{100 * float(v):.1f}%"


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table of ``header`` and ``rows`` (strings)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def mean_median(label: str, key: str, spec: str) -> Column:
    """A summary column: the learner's ``key`` {mean, median} as 'mean / median'."""
    return Column(label, lambda s: s[key], lambda v: f"{fmt(v['mean'], spec)} / {fmt(v['median'], spec)}")


def row_value(label: str, key: str, spec: str) -> Column:
    """A per-unit column: the row's number ``key`` with ``spec``."""
    return Column(label, lambda r: r[key], lambda v: fmt(v, spec))


def metric_column(suite: Suite, metric: str) -> Column:
    """A per-unit column of a metric: the row's mean of it."""
    return Column(suite.labels[metric], lambda r: r["metrics"][metric], lambda v: fmt(v, suite.formats[metric]))


TRAIN_SUMMARY = mean_median("train (s)", "train_time_s", ".2f")
TRAIN_ROW = row_value("train (s)", "train_time_s", ".2f")


def _equilibria_text(e: dict[str, Any] | None) -> str:
    if e is None:
        return "—"
    return (f"{e['units_clean']} clean; {e['spurious_attractors']} attractor(s), "
            f"{e['closed_orbits']} orbit(s)")


#: the search for spurious equilibria and closed orbits (``lfd.equilibria``): units whose field has
#: none, and how many there are in all; per unit, the spurious attractors of the worst seed
EQUILIBRIA_SUMMARY = Column("spurious equilibria (search)", lambda s: s.get("equilibria"), _equilibria_text)
EQUILIBRIA_ROW = Column("spurious attractors", lambda r: math.nan if r.get("equilibria") is None
                        else float(r["equilibria"]["spurious_attractors"] + r["equilibria"]["closed_orbits"]),
                        lambda v: fmt(v, ".0f"))


def summary_table(suite: Suite, summary: dict[str, Any], split: str) -> str:
    """One row per learner with the split: each metric 'mean / median' over units, then (in-sample)
    the suite's columns, (held-out) the training time."""
    extras = [*suite.summary_columns(), EQUILIBRIA_SUMMARY] if split == IN_SAMPLE else [TRAIN_SUMMARY]
    header = ["learner", f"{suite.unit}s"] + [suite.labels[m] for m in suite.metrics] + [c.label for c in extras]
    return table(header, _learner_rows(summary, split, lambda s: [
        *(mean_median("", m, suite.formats[m]).text(s["metrics"][m]) for m in suite.metrics),
        *(c.text(c.value(s)) for c in extras)]))


def _learner_rows(summary: dict[str, Any], key: str, cells: Callable[[dict[str, Any]], list[str]]) -> list[list[str]]:
    """A row per learner whose summary has ``key``: the learner, its units, then ``cells`` of it."""
    return [[learner, str(both[key]["units"]), *cells(both[key])] for learner, both in summary.items()
            if both[key] is not None]


def unit_table(suite: Suite, rows: dict[str, dict[str, Any]], units: list[str], split: str) -> str:
    """One row per unit, then the **Mean** and **Median** rows over units."""
    units = [u for u in units if u in rows]
    cols = [metric_column(suite, m) for m in suite.metrics]
    cols += [*suite.unit_columns(), EQUILIBRIA_ROW] if split == IN_SAMPLE else [TRAIN_ROW]
    body = [[u] + [c.text(c.value(rows[u])) for c in cols] for u in units]
    for name, agg in (("**Mean**", np.mean), ("**Median**", np.median)):
        with np.errstate(invalid="ignore"):
            body.append([name] + [c.text(float(agg([c.value(rows[u]) for u in units]))) for c in cols])
    return table([suite.unit] + [c.label for c in cols], body)


def split_table(suite: Suite, summary: dict[str, Any]) -> str:
    """One row per learner with both splits: each headline metric in-sample, held-out (means over
    the units both ran) and held-out / in-sample."""
    header = ["learner", f"{suite.unit}s"]
    for m in suite.headline:
        header += [f"{suite.labels[m]} in-sample", "held-out", "ratio"]
    return table(header, _learner_rows(summary, COMPARISON, lambda c: [
        text for m in suite.headline for text in (fmt(c[m][IN_SAMPLE], suite.formats[m]),
                                                  fmt(c[m][HELD_OUT], suite.formats[m]), fmt(c[m]["ratio"], ".2f"))]))


def held_out_sentence(suite: Suite, both: dict[str, Any]) -> str:
    """The held-out numbers of a learner's reading (means over units; against in-sample where both ran)."""
    c, s = both[COMPARISON], both[HELD_OUT]
    if s is None:
        return ""
    head = (" Held out (each demo scored by a model trained without it, run from its start toward its own end), "
            f"over {(c or s)['units']} {suite.unit}(s): ")
    if c is None:
        return head + ", ".join(f"{suite.labels[m]} {fmt(s['metrics'][m]['mean'], suite.formats[m])}"
                                for m in suite.headline) + "."
    return head + ", ".join(f"{suite.labels[m]} {fmt(c[m][HELD_OUT], suite.formats[m])} against "
                            f"{fmt(c[m][IN_SAMPLE], suite.formats[m])} in-sample ({fmt(c[m]['ratio'], '.2f')}x)"
                            for m in suite.headline) + "."


def run_line(run: dict[str, Any]) -> str:
    """How this invocation ran: workers, wall time, cache use, load, and the cells given up."""
    failed = [f for f in run.get("failed") or [] if not f.get("refused")]
    lost = "" if not failed else (
        f" {len(failed)} cell(s) are missing from the tables, given up after their worker process "
        "died on each try: " + "; ".join(f"{f['cell']} ({f['attempts']} tries: {f['reason']})" for f in failed)
        + ".")
    head = f"- Run: {run['workers']} worker process(es), one torch thread each, on {run['cpus']} CPU cores; "
    tail = "Timings are inflated by whatever else ran on the machine."
    if run["computed"] == 0:
        return head + (f"all {run['cached']} cells came from the cache of earlier runs, with the timings "
                       f"taken there (each learner's worker time is in the Reading). {tail}") + lost
    return head + (f"wall time {run['wall_s']:.0f} s for the cells computed in this run ({run['computed']} "
                   f"computed, {run['cached']} from the cache; each learner's worker time is in the "
                   f"Reading); load average {run['load_start']} at start, {run['load_end']} at end. {tail}") + lost


def figure_paths(path: str | Path, names: list[str]) -> dict[str, Path]:
    """{name: figure path} of the report at ``path``: ``figures/<report stem>_<name>.png`` beside
    it, so reports written into one folder (``lasa.md``, ``quick.md``) keep their own figures."""
    path = Path(path)
    return {name: path.parent / "figures" / f"{path.stem}_{name}.png" for name in names}


def _reading(suite: Suite, summary: dict[str, Any], rows: dict[str, Any], run: dict[str, Any]) -> str:
    parts = []
    for learner, both in summary.items():
        if both[IN_SAMPLE] is not None:
            parts.append(suite.reading(learner, both[IN_SAMPLE], rows[learner][IN_SAMPLE], run)
                         + held_out_sentence(suite, both))
        else:
            parts.append(f"**{learner}** ran held out only." + held_out_sentence(suite, both))
    parts += suite.closing(summary)
    refused = [f for f in run.get("failed") or [] if f.get("refused")]
    if refused:
        parts.append("Cells missing from the tables, their learner refused the unit (not cached; a later run "
                      "tries them again): " + "; ".join(f"{f['cell']} ({f['reason']})" for f in refused) + ".")
    return "\n\n".join(parts)


def page_path(report: str | Path) -> Path:
    """The results page of the report at ``report``: ``<stem>.html`` beside it (``<stem>_page.html``
    for a report named ``.html``)."""
    report = Path(report)
    return report.with_name(f"{report.stem}_page.html" if report.suffix == ".html" else f"{report.stem}.html")


def write_report(path: str | Path, suite: Suite, records: list[dict[str, Any]], learners: list[str],
                 units: list[str], run: dict[str, Any], arrays: Arrays, notes: str | None = None,
                 json_path: str | Path | None = None) -> list[Path]:
    """Write the markdown report, its figures and its results page (``page_path``; module
    docstring); ``json_path`` is the results JSON the page links to. Returns the figure paths."""
    path = Path(path)
    summary = summarize(suite, records, learners)
    rows = rows_by(suite, records, learners)
    figures = suite.figures(path, records, list(summary), units, arrays)
    u, n = suite.unit, suite.n_demos
    md = [f"# {suite.title}", "",
          f"Generated by `{run['command']}`. Protocol: [docs/benchmark.md](../docs/benchmark.md) "
          f"({suite.name}, version {suite.protocol.to_dict()['version']}).", "",
          *suite.intro(units, run),
          f"- Splits: in-sample, every learner trained on all {n} demos of a {u} and scored on them; held-out "
          f"(leave one demo out), {n} fields per {u}, each trained on the other {n - 1} demos and run from the "
          "left-out demo's start toward its own end (the DMP: its goal), scored on that demo with the same metrics.",
          run_line(run), ""]
    if any(both[IN_SAMPLE] is not None for both in summary.values()):
        md += [f"## Summary (mean / median over {u}s)", "", f"In-sample: all {n} demos train and are scored.", "",
               summary_table(suite, summary, IN_SAMPLE), ""]
        common = [x for x in units if all(x in rows[learner][IN_SAMPLE] for learner in summary)]
        if len(summary) > 1 and any(len(rows[learner][IN_SAMPLE]) != len(common) for learner in summary):
            sub = summarize(suite, [r for r in records if r[u] in common], list(summary))
            md += [f"## Summary on the {len(common)} {u}s every learner ran (mean / median)", "",
                   f"{u.capitalize()}s: {', '.join(common)}.", "", summary_table(suite, sub, IN_SAMPLE), ""]
    if any(both[COMPARISON] is not None for both in summary.values()):
        md += ["## In-sample and held-out", "",
               f"Means over the {u}s both splits ran; ratio = held-out / in-sample.", "",
               split_table(suite, summary), ""]
    if any(both[HELD_OUT] is not None for both in summary.values()):
        md += [f"## Held-out demos (mean / median over {u}s)", "", summary_table(suite, summary, HELD_OUT), ""]
    md += [*suite.sections(summary), "## Reading", "", _reading(suite, summary, rows, run), ""]
    if notes:
        md += [notes.strip(), ""]
    for learner in summary:
        md += [f"## Per {u}: {learner}", ""]
        if rows[learner][IN_SAMPLE]:
            md += [unit_table(suite, rows[learner][IN_SAMPLE], units, IN_SAMPLE), ""]
        if rows[learner][HELD_OUT]:
            md += [f"Held-out demos, {learner}:", "", unit_table(suite, rows[learner][HELD_OUT], units, HELD_OUT), ""]
        md += _images(figures.get(learner, []), path)
    if figures.get(""):
        md += ["## Figures", "", *_images(figures[""], path)]
    text = "\n".join(md)
    atomic_write(path, lambda f: f.write(text.encode()))
    write_page(page_path(path), bench_page(suite, summary, rows, units, run, figures, path,
                                           None if json_path is None else Path(json_path), versions(DISTRIBUTIONS)))
    return [p for shown in figures.values() for _, p in shown]


def _images(figures: list[tuple[str, Path]], path: Path) -> list[str]:
    """Markdown image lines, each followed by a blank line, relative to the report at ``path``."""
    return [line for alt, p in figures for line in (f"![{alt}]({p.relative_to(path.parent).as_posix()})", "")]
