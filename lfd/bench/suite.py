"""One interface for every benchmark suite: its units, its cells, its scores, its report.

A suite (``LasaSuite``, ``RobotTasksSuite``; any later set the same way) names its units (LASA
shapes, RoboTasks9 tasks), its state space (``lfd.bench.spaces``), its per-demo metrics and what it
measures beyond them. Every suite shares the rest:

- cells (``Cell``): one learner of ``lfd.bench.spaces.bench_learners()`` with one seed on one unit
  and one split; run, cached and resumed by ``lfd.bench.runner.run_cells``;
- the splits (``SPLITS``): ``in-sample``, every demo trains and is scored; ``held-out``,
  leave-one-demo-out: N cells per unit, cell i trained on the other N - 1 demos and run from demo
  i's start toward demo i's own end (``Model.toward``), scored on demo i alone;
- ``Suite.evaluate``: a cell trained and scored; the summaries (``lfd.bench.summary``) and the
  report (``lfd.bench.report``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from lfd.bench.model import Model
from lfd.bench.protocol import resolve_names, stable_hash
from lfd.bench.spaces import Space, fit, learner_code, resolve_config
from lfd.demos import DemoSet
from lfd.fingerprint import code_fingerprint

IN_SAMPLE, HELD_OUT = "in-sample", "held-out"
SPLITS: tuple[str, ...] = (IN_SAMPLE, HELD_OUT)
#: --quick caps the iterations of a learner the suite's ``quick_options`` do not name
QUICK_ITERATIONS = 200


def resolve_splits(spec: str) -> list[str]:
    """``in-sample``, ``held-out``, a comma list of them, or ``both`` (``SPLITS``) -> the splits."""
    return resolve_names(",".join(SPLITS) if spec == "both" else spec, SPLITS, None, "split")


@dataclass(frozen=True)
class Column:
    """A column of a report table: its ``label``, its ``value`` in a learner's summary or a unit's
    row, and that value's ``text``."""

    label: str
    value: Callable[[dict[str, Any]], Any]
    text: Callable[[Any], str]


@dataclass(frozen=True)
class Cell:
    """One unit of work: one learner trained with one seed on one unit of a suite and one split,
    and scored. Build it with ``Suite.cell``, which computes ``hash`` (the cache key)."""

    suite: Suite = field(hash=False, compare=False)   # the suite, its protocol with it
    learner: str                                       # a name of lfd.bench.spaces.bench_learners()
    unit: str                                          # a shape or task of the suite
    seed: int                                          # the learner's seed
    fold: int | None                                   # held-out: the demo left out; in-sample: None
    options: dict[str, Any] = field(hash=False)        # the learner's keyword options
    hash: str = ""                                     # protocol, learner, config, code, unit, seed, fold

    @property
    def split(self) -> str:
        return IN_SAMPLE if self.fold is None else HELD_OUT

    @property
    def stem(self) -> str:
        """The cache file stem (``lfd.bench.runner``)."""
        return cell_stem(self.learner, self.unit, self.seed, self.fold)

    def evaluate(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Train and score the cell (``Suite.evaluate``)."""
        return self.suite.evaluate(self)


#: modules that only present results (report text, pages, plots): left out of the scoring code's fingerprint
PRESENTATION: tuple[str, ...] = ("lfd.bench.report", "lfd.bench.report_page", "lfd.bench.robottasks_figures",
                                 "lfd.bench.summary", "lfd.pages", "lfd.plotting")

#: demos whose ends lie within this fraction of the states' extent of their mean end share one goal
SAME_END = 1e-4


def cell_stem(learner: str, unit: str, seed: int, fold: int | None) -> str:
    """``<learner>__<unit>__seed<seed>``, and ``__out<fold>`` for a held-out cell."""
    return f"{learner}__{unit}__seed{seed}" + ("" if fold is None else f"__out{fold}")


class Suite(ABC):
    """A benchmark suite (module docstring). A subclass sets the class attributes and implements
    the abstract methods; ``protocol`` (a frozen dataclass with ``to_dict``) holds every setting a
    number depends on other than the learner and its seed."""

    name: ClassVar[str]                      # the command's suite name: ``lfd bench <name>``
    title: ClassVar[str]                     # the report's title
    unit: ClassVar[str]                      # what a unit is ("shape", "task"): the records' key
    units: ClassVar[tuple[str, ...]]         # every unit
    quick_units: ClassVar[tuple[str, ...]]   # the units of --quick
    protocol_type: ClassVar[type]            # its protocol: a frozen dataclass with ``to_dict``
    quick_options: ClassVar[dict[str, dict[str, Any]]]   # learner options of --quick
    n_demos: ClassVar[int]                   # demos per unit
    space: ClassVar[Space]
    metrics: ClassVar[tuple[str, ...]]       # per-demo metrics, each under its own name
    labels: ClassVar[dict[str, str]]         # metric -> report column
    formats: ClassVar[dict[str, str]]        # metric -> format spec
    headline: ClassVar[tuple[str, ...]]      # metrics of the in-sample / held-out table

    def __init__(self, protocol: Any) -> None:
        self.protocol = protocol

    # ---------------------------------------------------------------- cells

    def resolve_units(self, spec: str, quick: bool = False) -> list[str]:
        """``all`` (with quick: ``quick_units``) or a comma list of units."""
        return resolve_names(spec, self.units, self.quick_units if quick else None, f"{self.title} {self.unit}(s)")

    def quick(self, learner: str) -> dict[str, Any]:
        """The options of ``learner`` under --quick: ``quick_options``' entry, else at most
        ``QUICK_ITERATIONS`` iterations for a learner that has them (a learner added later)."""
        if learner in self.quick_options:
            return dict(self.quick_options[learner])
        iterations = self.config(learner, {}).get("iterations")
        return {} if iterations is None else {"iterations": min(int(iterations), QUICK_ITERATIONS)}

    def config(self, learner: str, options: dict[str, Any]) -> dict[str, Any]:
        """The learner's full config in this suite's space (ConfigError if invalid)."""
        return resolve_config(learner, options, self.space)

    def cell(self, learner: str, unit: str, seed: int, fold: int | None, options: dict[str, Any]) -> Cell:
        key = {"protocol": self.protocol.to_dict(), "learner": learner, "config": self.config(learner, options),
               self.unit: unit, "seed": seed, "fold": fold,
               "code": {"learner": learner_code(learner), "scoring": self.scoring_code()}}
        return Cell(self, learner, unit, seed, fold, dict(options), stable_hash(key))

    def cells(self, learners: list[str], units: dict[str, list[str]], seeds: list[int],
              options: dict[str, dict[str, Any]], splits: list[str]) -> list[Cell]:
        """Every (learner, unit, seed, split) of the run: one in-sample cell, ``n_demos`` held-out cells."""
        folds: list[int | None] = ([None] if IN_SAMPLE in splits else []) + (
            list(range(self.n_demos)) if HELD_OUT in splits else [])
        return [self.cell(learner, unit, seed, fold, options[learner])
                for learner in learners for unit in units[learner] for seed in seeds for fold in folds]

    def scoring_code(self) -> str:
        """The fingerprint of the code that scores this suite's cells (``lfd.fingerprint``): the
        suite's module and all it imports of lfd, less the code that only presents (``PRESENTATION``)."""
        return code_fingerprint(type(self).__module__, __name__, exclude=PRESENTATION)

    def evaluate(self, cell: Cell) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Train ``cell.learner`` on the split's training demos and score it on its scored demos
        (module docstring). Returns the JSON record and the figure arrays; an in-sample cell adds
        what ``in_sample`` measures, a held-out cell keeps its reproduction (``reproduction``)."""
        demos = self.demos(cell.unit)
        train = list(range(demos.n_demos)) if cell.fold is None else [i for i in range(demos.n_demos) if i != cell.fold]
        scored = train if cell.fold is None else [cell.fold]
        model = fit(cell.learner, demos.subset(train), cell.seed, cell.options, self.space)
        if model.history.get("interrupted"):  # the learner swallowed Ctrl-C: never score or cache it
            raise KeyboardInterrupt
        y, v, per = self._reproduce(model, demos, scored, own_ends=cell.fold is not None)
        record: dict[str, Any] = {
            "learner": cell.learner, self.unit: cell.unit, "seed": cell.seed, "split": cell.split, "fold": cell.fold,
            "train_demos": train, "scored_demos": scored, "config": model.config, "train_time_s": model.train_time_s,
            "metrics": {m: float(np.mean(v)) for m, v in per.items()}, "per_demo": per}
        if cell.fold is None:
            extra, arrays = self.in_sample(model, demos, cell.unit, y)
            extra["equilibria"] = model.equilibria(demos)
        else:
            extra, arrays = {}, {"reproduction": y}
        record.update(extra)
        record.update(history=model.history, integrators=dict(model.integrators))
        return record, arrays

    def _reproduce(self, model: Model, demos: DemoSet, scored: list[int], own_ends: bool
                   ) -> tuple[np.ndarray, np.ndarray, dict[str, list[float]]]:
        """Reproduce and score the demos ``scored``, each toward its own end (a field learns every demo
        relative to its end, Eqs. (R1)-(R2) of docs/equations.md; a held-out demo always, in-sample
        ones where the ends lie apart) or, where they coincide, all at once toward the common goal.
        Returns the reproductions y, the model's velocities v and the per-demo metrics."""
        ends, goal = self.space.ends(demos), self.space.goal(demos)
        extent = float(np.max(np.ptp(self.space.states(demos).reshape(-1, ends.shape[-1]), axis=0)))
        if not own_ends and float(np.max(np.abs(ends - goal))) <= SAME_END * extent:
            sub = demos.subset(scored)
            y, v = model.reproduce(self.space.states(sub), sub.t)
            return y, v, self.score(y, v, demos, scored, goal)
        ys: list[np.ndarray] = []
        vs: list[np.ndarray] = []
        per: dict[str, list[float]] = {}
        for i in scored:
            sub = demos.subset([i])
            moved = model.toward(ends[i])
            yi, vi = moved.reproduce(self.space.states(sub), sub.t)
            model.integrators.update(moved.integrators)
            for m, values in self.score(yi, vi, demos, [i], ends[i]).items():
                per.setdefault(m, []).extend(values)
            ys.append(yi[0])
            vs.append(vi[0])
        return np.stack(ys), np.stack(vs), per

    def record_stem(self, record: dict[str, Any]) -> str:
        """The cache file stem of a record."""
        return cell_stem(record["learner"], record[self.unit], record["seed"], record.get("fold"))

    # ---------------------------------------------------------------- what a suite measures

    @abstractmethod
    def demos(self, unit: str) -> DemoSet:
        """The demos of a unit."""

    @abstractmethod
    def score(self, y: np.ndarray, v: np.ndarray, demos: DemoSet, scored: list[int],
              goal: np.ndarray) -> dict[str, list[float]]:
        """Per-demo metrics {metric: [len(scored) floats]} (inf for a diverged reproduction) of the
        reproductions y, shape (len(scored), T, D), and the model's velocities v of the demos
        ``scored`` of ``demos``, the model run toward ``goal``, shape (D,)."""

    @abstractmethod
    def in_sample(self, model: Model, demos: DemoSet, unit: str,
                  y: np.ndarray) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """What an in-sample cell records beyond the metrics (convergence, timings) and its figure
        arrays, given the model trained on every demo and its reproductions y, shape (N, T, D)."""

    @abstractmethod
    def unit_row(self, records: list[dict[str, Any]]) -> dict[str, Any]:
        """A unit's in-sample values beyond the metrics, from its records (one per seed)."""

    @abstractmethod
    def summary_extras(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """A learner's in-sample summary beyond the metrics, from its units' rows (``unit_row``)."""

    # ---------------------------------------------------------------- its report

    @abstractmethod
    def intro(self, units: list[str], run: dict[str, Any]) -> list[str]:
        """The report's lines on the protocol (markdown bullets)."""

    @abstractmethod
    def summary_columns(self) -> list[Column]:
        """The in-sample summary table's columns beyond the metrics, of a learner's summary."""

    @abstractmethod
    def unit_columns(self) -> list[Column]:
        """The in-sample per-unit table's columns beyond the metrics, of a unit's row."""

    @abstractmethod
    def reading(self, learner: str, summary: dict[str, Any], rows: dict[str, dict[str, Any]],
                run: dict[str, Any]) -> str:
        """A paragraph on one learner's in-sample numbers, from its summary and unit rows."""

    def closing(self, summary: dict[str, Any]) -> list[str]:
        """Paragraphs on all learners after theirs (none by default)."""
        return []

    def sections(self, summary: dict[str, Any]) -> list[str]:
        """Report sections after the summaries (none by default)."""
        return []

    @abstractmethod
    def figures(self, path: Path, records: list[dict[str, Any]], learners: list[str], units: list[str],
                arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]]) -> dict[str, list[tuple[str, Path]]]:
        """Draw the figures beside the report at ``path`` (``arrays`` reads a record's figure
        arrays): {where: [(alt text, figure path)]}, where a learner's name puts them under its
        per-unit tables and ``""`` at the report's end."""
