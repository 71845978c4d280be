"""The LASA benchmark harness behind ``lfd bench lasa`` (protocol: docs/benchmark.md).

- ``protocol``: data, split, starts, horizon (``LasaProtocol``);
- ``evaluate``: one (learner, shape, seed) cell, trained and scored (``evaluate_cell``);
- ``dmp``: the DMP baseline from ``movement_primitives`` (``fit_dmp``);
- ``runner``: parallel, resumable runs of cells (``Cell``, ``run_cells``);
- ``report``: aggregates, markdown and figures (``summarize``, ``write_report``);
- ``comparison``: the NODE against the contraction learners on the spiral (``scripts/compare_learners.py``).
"""

from lfd.bench.dmp import fit_dmp
from lfd.bench.evaluate import evaluate_cell
from lfd.bench.protocol import LasaProtocol
from lfd.bench.report import summarize, write_report
from lfd.bench.runner import Cell, run_cells

__all__ = ["Cell", "LasaProtocol", "evaluate_cell", "fit_dmp", "run_cells", "summarize", "write_report"]
