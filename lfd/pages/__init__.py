"""Results pages: one self-contained ``index.html`` per run folder or benchmark report.

A ``Page`` (``lfd.pages.page``) is plain data: what was run, the verdict (sentences, failures in
words, tables with the best value of each group marked and each number's place in the data file),
the videos, the figures and the data files; ``write_page`` (``lfd.pages.render``) writes it through
a Jinja2 template, with nothing loaded from the network. The callers assemble their pages: the arm
job (``sim.media.job_page``), the sweep (``sim.studies.sweep_page``), ``lfd bench`` (``lfd.bench.report_page``).
"""

from __future__ import annotations

from lfd.pages.page import Cell, DataFile, Media, MediaGroup, Page, Table, mark_best, number, pointer, text
from lfd.pages.render import render, versions, write_page

__all__ = ["Cell", "DataFile", "Media", "MediaGroup", "Page", "Table", "mark_best", "number", "pointer", "render",
           "text", "versions", "write_page"]
