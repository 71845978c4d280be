"""The sweep's figures (``sim.studies.sweep``): a robustness heatmap of the pushes (direction x
magnitude -> median recovery time and success rate) and a basin-of-attraction plot of the start
offsets, from the sweep's records.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from lfd.io import atomic_write

__all__ = ["basin", "heatmap"]


def heatmap(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Push direction x magnitude -> median recovery time and success rate, one row per robot x learner."""
    pushes = [r for r in records if r["kind"] == "push"]
    if not pushes:
        return None
    combos = sorted({(r["robot"], r["learner"]) for r in pushes})
    angles = sorted({round(r["angle_rad"], 9) for r in pushes})
    mags = sorted({r["magnitude"] for r in pushes})
    fig = Figure(figsize=(10, 3.2 * len(combos)))
    axes = fig.subplots(len(combos), 2, squeeze=False)
    for row, (robot, learner) in enumerate(combos):
        rec = np.full((len(mags), len(angles)), np.nan)
        suc = np.full((len(mags), len(angles)), np.nan)
        for i, mg in enumerate(mags):
            for j, a in enumerate(angles):
                rs = [r for r in pushes if r["robot"] == robot and r["learner"] == learner
                      and r["magnitude"] == mg and round(r["angle_rad"], 9) == a]
                if not rs:
                    continue
                suc[i, j] = np.mean([r["success"] for r in rs])
                times = [r["metrics"].get("recovery_time_s") if r.get("metrics") else None for r in rs]
                ok = [t for t in times if t is not None]
                rec[i, j] = np.median(ok) if len(ok) * 2 > len(times) else np.inf   # inf: mostly never recovered
        deg = [f"{math.degrees(a):.0f}" for a in angles]
        for col, (data, title, cmap) in enumerate(((rec, "median recovery time (s); x: never", "viridis"),
                                                   (suc, "success rate", "RdYlGn"))):
            ax = axes[row, col]
            shown = np.where(np.isinf(data), np.nan, data)
            vmin, vmax = (0.0, 1.0) if col == 1 else (None, None)
            im = ax.imshow(shown, aspect="auto", origin="lower", cmap=cmap, vmin=vmin, vmax=vmax)
            for i, j in zip(*np.nonzero(np.isinf(data))):
                ax.text(j, i, "x", ha="center", va="center", color="k")
            ax.set_xticks(range(len(angles)), deg)
            ax.set_yticks(range(len(mags)), [f"{m:g}" for m in mags])
            ax.set_xlabel("push direction in the task plane (deg)")
            ax.set_ylabel("force (N)")
            ax.set_title(f"{robot} / {learner}: {title}", fontsize=9)
            fig.colorbar(im, ax=ax)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    return path


def basin(records: list[dict[str, Any]], path: Path) -> Path | None:
    """Start points of the ``offset`` runs in task space (first two coordinates), filled where the
    run reached its goal, with the goal; one panel per robot x learner."""
    offs = [r for r in records if r["kind"] == "offset" and r.get("start_task")]
    if not offs:
        return None
    combos = sorted({(r["robot"], r["learner"]) for r in offs})
    fig = Figure(figsize=(4.5 * len(combos), 4.2))
    axes = fig.subplots(1, len(combos), squeeze=False)
    for ax, (robot, learner) in zip(axes[0], combos):
        rs = [r for r in offs if r["robot"] == robot and r["learner"] == learner]
        xs = np.array([r["start_task"][:2] for r in rs])
        ok = np.array([r["success"] for r in rs])
        err = np.array([r["metrics"]["final_goal_error_m"] * 1e3 for r in rs])
        sc = ax.scatter(xs[ok, 0], xs[ok, 1], c=err[ok], cmap="viridis", s=30, label="reached goal")
        ax.scatter(xs[~ok, 0], xs[~ok, 1], marker="x", c="r", s=30, label="missed")
        g = np.array(rs[0]["goal_task"][:2])
        ax.plot(*g, "k*", ms=12, label="goal")
        for r in rs:
            ax.plot([r["start_task"][0], r["end_task"][0]], [r["start_task"][1], r["end_task"][1]],
                    color="0.8", lw=0.5, zorder=0)
        ax.set_aspect("equal")
        ax.set_title(f"{robot} / {learner}: start offsets", fontsize=9)
        ax.set_xlabel("x1 (task units)")
        ax.set_ylabel("x2 (task units)")
        ax.legend(fontsize=7, loc="best")
        fig.colorbar(sc, ax=ax, label="final goal error (mm)")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    return path
