"""What a results page holds, as plain data: the run's facts, the verdict (sentences, failures in
words, tables of numbers with the best marked), the videos, the figures, the data files.

A ``Cell`` of a number keeps the number behind its text (``value``, in the data file's units) and
where the data file holds it (``source``, a JSON pointer, RFC 6901), so a reader (or a test) can
check every number on the page against the file. ``mark_best`` marks, per column and group of
rows, the best of the cells that say which way is better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

__all__ = ["Cell", "DataFile", "Media", "MediaGroup", "Page", "Table", "mark_best", "number", "pointer", "text"]


@dataclass(frozen=True)
class Cell:
    """One table cell: its ``text``; for a number, the ``value`` shown (data-file units, None for
    a missing or non-finite one), ``scale`` (text = value x scale, e.g. 1000 for m shown in mm),
    its ``source`` in the page's data file, which way is ``better`` (``"lower"``, ``"higher"`` or
    None: not compared), whether it is the ``best`` of its group, ``bad`` (a failing value) and
    ``numeric`` (a number's place, shown aligned as numbers are, even when it holds none)."""

    text: str
    value: float | None = None
    scale: float = 1.0
    source: str = ""
    better: str | None = None
    best: bool = False
    bad: bool = False
    numeric: bool = False


def text(s: str, bad: bool = False) -> Cell:
    """A cell of words."""
    return Cell(s, bad=bad)


def number(value: float | None, spec: str, source: str = "", scale: float = 1.0, better: str | None = None,
           missing: str = "—", bad: bool = False) -> Cell:
    """A cell of the number ``value`` (data-file units) shown as ``value * scale`` with the format
    ``spec``; ``missing`` for None, ``inf`` for an infinite value (neither is compared)."""
    if value is None or math.isnan(value):
        return Cell(missing, None, scale, source, better, bad=bad, numeric=True)
    if math.isinf(value):
        return Cell("inf" if value > 0 else "-inf", None, scale, source, better, bad=bad, numeric=True)
    return Cell(format(value * scale, spec), float(value), scale, source, better, bad=bad, numeric=True)


def pointer(*parts: str | int) -> str:
    """The JSON pointer (RFC 6901) of ``parts``: ``pointer("runs", 0, "metrics")`` is
    ``/runs/0/metrics``; ``~`` and ``/`` inside a part are escaped."""
    return "".join("/" + str(p).replace("~", "~0").replace("/", "~1") for p in parts)


@dataclass(frozen=True)
class Table:
    """A table: ``columns`` (header texts), ``rows`` of cells, and each row's ``group`` (a
    heading row is shown where it changes; ``mark_best`` compares within a group). ``rows[i][0]``
    names the row."""

    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]
    groups: tuple[str, ...] = ()
    note: str = ""

    def group_of(self, i: int) -> str:
        """The group of row ``i`` ("" when the table has no groups)."""
        return self.groups[i] if self.groups else ""


def mark_best(table: Table, along: str = "columns") -> Table:
    """``table`` with the cells holding the best value marked ``best``: per column and group of rows
    (``along="columns"``) or per row (``"rows"``); the best is the lowest (``better == "lower"``) or
    the highest (``"higher"``), ties all marked; fewer than two comparable cells mark none."""
    rows = [list(r) for r in table.rows]
    sets: dict[tuple[Any, ...], list[tuple[int, int]]] = {}
    for i, r in enumerate(rows):
        for j, c in enumerate(r):
            if c.better is not None and c.value is not None:
                key = (i,) if along == "rows" else (j, table.group_of(i))
                sets.setdefault(key, []).append((i, j))
    for members in sets.values():
        if len(members) < 2:
            continue
        sign = {i_j: -1.0 if rows[i_j[0]][i_j[1]].better == "higher" else 1.0 for i_j in members}
        score = {i_j: sign[i_j] * float(rows[i_j[0]][i_j[1]].value or 0.0) for i_j in members}
        best = min(score.values())
        for i, j in members:
            if score[i, j] == best:
                rows[i][j] = replace(rows[i][j], best=True)
    return replace(table, rows=tuple(tuple(r) for r in rows))


@dataclass(frozen=True)
class Media:
    """A video or an image file and its caption; ``wide`` spans the page's width."""

    path: Path
    caption: str
    wide: bool = False


@dataclass(frozen=True)
class MediaGroup:
    """Videos or images shown together under ``title`` (``note`` below it), in a grid of
    ``columns`` (0: as many as fit); ``tables`` follow them (e.g. the runs of a side-by-side video)."""

    title: str
    items: tuple[Media, ...]
    columns: int = 0
    note: str = ""
    tables: tuple[Table, ...] = ()


@dataclass(frozen=True)
class DataFile:
    """A file of the run, linked from the page: its ``path``, ``what`` it holds, its ``size`` in
    bytes (None: not known when the page was written)."""

    path: Path
    what: str
    size: int | None = None


@dataclass(frozen=True)
class Page:
    """One results page (``lfd.pages.render``), in the order it is shown.

    ``title``, ``subtitle``; what was run: the ``command``, ``facts`` ((label, text): seed,
    versions, settings); the verdict: ``verdict`` (sentences), ``failures`` (one sentence each;
    none: ``all_passed`` says so) and ``tables``; ``videos``; ``figures``; ``details`` (tables shown
    folded); ``files``. ``data_file`` is the JSON file the tables' ``source`` pointers point into.
    """

    title: str
    subtitle: str
    command: str
    facts: tuple[tuple[str, str], ...]
    verdict: tuple[str, ...]
    failures: tuple[str, ...]
    tables: tuple[Table, ...]
    videos: tuple[MediaGroup, ...] = ()
    figures: tuple[MediaGroup, ...] = ()
    details: tuple[Table, ...] = ()
    files: tuple[DataFile, ...] = ()
    data_file: Path | None = None
    all_passed: str = "No failures."
