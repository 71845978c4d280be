"""Comparing records of runs (sweep and benchmark JSON) by their numbers, wall-clock timings left out."""

from __future__ import annotations

from typing import Any

#: keys of wall-clock numbers, which differ from run to run
TIMINGS = {"cell_s", "train_time_s", "step_time_us", "run_s", "run_cpu_s", "control_step_us", "realtime_factor"}


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
