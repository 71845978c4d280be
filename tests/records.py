"""Comparing records of runs (sweep and benchmark JSON) by their numbers, wall-clock timings left out."""

from __future__ import annotations

from typing import Any

#: keys of wall-clock numbers, which differ from run to run
TIMINGS = {"cell_s", "elapsed_s", "train_time_s", "train_cpu_s", "step_time_us", "run_s", "run_cpu_s",
           "control_step_us", "realtime_factor"}
#: keys of how a run went rather than what it computed: its tries and the node (host) that ran it
HOST_FIELDS = {"attempts", "node"}


def numbers(obj: Any, prefix: str = "") -> dict[str, float]:
    """The numbers of a nested record, {path: value}, the ``TIMINGS`` left out (booleans as 0 / 1)."""
    if isinstance(obj, dict):
        return {k: v for key, val in obj.items() if key not in TIMINGS
                for k, v in numbers(val, f"{prefix}/{key}").items()}
    if isinstance(obj, list):
        return {k: v for i, val in enumerate(obj) for k, v in numbers(val, f"{prefix}/{i}").items()}
    if isinstance(obj, bool) or obj is None:
        return {prefix: float(bool(obj))} if isinstance(obj, bool) else {}
    return {prefix: float(obj)} if isinstance(obj, (int, float)) else {}


def results(obj: Any) -> Any:
    """A nested record without its ``TIMINGS`` and ``HOST_FIELDS`` (at any depth), for an exact
    comparison: two runs of the same spec give equal results, bit for bit."""
    if isinstance(obj, dict):
        return {k: results(v) for k, v in obj.items() if k not in TIMINGS | HOST_FIELDS}
    if isinstance(obj, list):
        return [results(v) for v in obj]
    return obj
