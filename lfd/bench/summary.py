"""Aggregates of a suite's records: per unit, per learner, and held-out against in-sample.

Per learner, split and unit a metric is the mean over the unit's records: over seeds, and for the
held-out split over the folds too (each fold scores one demo, so the mean is over the demos). The
summary then gives its mean and median over units. A diverged rollout's metric is infinite (null
in JSON): it makes the mean infinite and counts as the worst value for the median. The comparison
of the splits (``compare_splits``) is over the units both ran: the held-out mean, the in-sample
mean and their ratio.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lfd.bench.suite import HELD_OUT, IN_SAMPLE, SPLITS, Suite

#: a summary's key of the splits' comparison
COMPARISON = "held-out / in-sample"


def num(v: Any) -> float:
    """A record's number; None (a non-finite value in JSON) is infinity."""
    return float(v) if v is not None else math.inf


def stats(values: list[float]) -> dict[str, float]:
    """The mean and median of ``values`` (NaN for none)."""
    a = np.asarray(values, dtype=np.float64)
    if len(a) == 0:
        return {"mean": math.nan, "median": math.nan}
    with np.errstate(invalid="ignore"):
        return {"mean": float(np.mean(a)), "median": float(np.median(a))}


def per_unit(suite: Suite, records: list[dict[str, Any]], learner: str, split: str) -> dict[str, dict[str, Any]]:
    """{unit: row} of one learner and split: ``metrics`` {metric: mean}, ``train_time_s``,
    ``train_cpu_s`` (means), ``cell_s`` (summed), ``fallback`` (a rollout needed the fixed-step
    rk4 fallback of ``lfd.bench.fields.FieldModel``) and, in-sample, ``suite.unit_row``'s values."""
    by: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        if r["learner"] == learner and r["split"] == split:
            by.setdefault(r[suite.unit], []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for unit, rs in by.items():
        row: dict[str, Any] = {
            "metrics": {m: float(np.mean([num(r["metrics"][m]) for r in rs])) for m in suite.metrics},
            "train_time_s": float(np.mean([num(r["train_time_s"]) for r in rs])),
            "train_cpu_s": float(np.mean([r.get("history", {}).get("train_cpu_s", math.nan) for r in rs])),
            "cell_s": float(np.sum([num(r.get("cell_s")) for r in rs])),
            "fallback": any(str(v).startswith("rk4 (") for r in rs for v in r.get("integrators", {}).values()),
        }
        if split == IN_SAMPLE:
            row.update(suite.unit_row(rs))
            row["equilibria"] = equilibria_row(rs)
        out[unit] = row
    return out


def summarize_rows(suite: Suite, rows: dict[str, dict[str, Any]], split: str) -> dict[str, Any] | None:
    """A learner's summary of one split from its unit rows (None without any): ``units``,
    ``metrics`` {metric: {mean, median}}, ``train_time_s`` (mean, median, total), ``train_cpu_s``,
    ``cell_s_total`` (worker time of training and scoring all its cells) and, in-sample,
    ``suite.summary_extras``' values."""
    if not rows:
        return None
    vals = list(rows.values())
    s: dict[str, Any] = {
        "units": len(rows),
        "metrics": {m: stats([v["metrics"][m] for v in vals]) for m in suite.metrics},
        "train_time_s": {**stats([v["train_time_s"] for v in vals]),
                         "total": float(sum(v["train_time_s"] for v in vals))},
        "train_cpu_s": stats([v["train_cpu_s"] for v in vals]),
        "cell_s_total": float(sum(v["cell_s"] for v in vals)),
    }
    if split == IN_SAMPLE:
        s.update(suite.summary_extras(vals))
        found = [v["equilibria"] for v in vals if v.get("equilibria") is not None]
        s["equilibria"] = None if len(found) < len(vals) else {
            "units_clean": sum(e["clean"] for e in found),
            "spurious_attractors": int(sum(e["spurious_attractors"] for e in found)),
            "closed_orbits": int(sum(e["closed_orbits"] for e in found)),
            "goal_fraction": stats([e["goal_fraction"] for e in found])}
    return s


def equilibria_row(records: list[dict[str, Any]]) -> dict[str, Any] | None:
    """A unit's equilibria search (``lfd.equilibria.equilibria_summary``) over its records: whether
    every seed's field is clean, the most spurious attractors and closed orbits any seed's field has,
    the smallest fraction of search starts that reach the goal, and the points (the first seed's);
    None for a model without an autonomous field, or records made before the search."""
    found: list[dict[str, Any]] = [r["equilibria"] for r in records if r.get("equilibria") is not None]
    if not found or len(found) < len(records):
        return None
    return {"clean": all(e["clean"] for e in found),
            "spurious_attractors": max(int(e["spurious_attractors"]) for e in found),
            "closed_orbits": max(int(e["closed_orbits"]) for e in found),
            "goal_fraction": min(float(e["goal_fraction"]) for e in found),
            "points": found[0].get("points", [])}


def compare_splits(suite: Suite, inside: dict[str, dict[str, Any]],
                   outside: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """{metric: {in-sample, held-out, ratio}}: means over the units both splits ran (None: none)."""
    common = [u for u in inside if u in outside]
    if not common:
        return None
    out: dict[str, Any] = {"units": len(common)}
    for m in suite.metrics:
        a = float(np.mean([inside[u]["metrics"][m] for u in common]))
        b = float(np.mean([outside[u]["metrics"][m] for u in common]))
        with np.errstate(all="ignore"):
            out[m] = {IN_SAMPLE: a, HELD_OUT: b, "ratio": float(np.divide(b, a)) if a != 0 else math.nan}
    return out


def rows_by(suite: Suite, records: list[dict[str, Any]], learners: list[str]) -> dict[str, dict[str, dict[str, Any]]]:
    """{learner: {split: {unit: row}}} (``per_unit``) of the learners with records."""
    out = {learner: {split: per_unit(suite, records, learner, split) for split in SPLITS} for learner in learners}
    return {k: v for k, v in out.items() if any(v.values())}


def summarize(suite: Suite, records: list[dict[str, Any]], learners: list[str]) -> dict[str, Any]:
    """{learner: {"in-sample": summary or None, "held-out": summary or None, COMPARISON: or None}}
    of the learners with records (``summarize_rows``, ``compare_splits``)."""
    out: dict[str, Any] = {}
    for learner, rows in rows_by(suite, records, learners).items():
        out[learner] = {split: summarize_rows(suite, rows[split], split) for split in SPLITS}
        out[learner][COMPARISON] = compare_splits(suite, rows[IN_SAMPLE], rows[HELD_OUT])
    return out
