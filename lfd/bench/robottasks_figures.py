"""The RoboTasks9 report's figures (``lfd bench robottasks``): per task, the learners' 3-D paths and their
angles to the goal orientation. Presentation only: no number of the suite depends on this module, so
it is left out of the suite's code fingerprint (``lfd.bench.suite.PRESENTATION``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lfd.bench.report import fmt
from lfd.bench.suite import IN_SAMPLE
from lfd.demos import DemoSet
from lfd.io import atomic_write

COLORS: dict[str, str] = {"node": "tab:purple", "contraction": "tab:red", "tracking": "tab:green",
                          "stable_node": "tab:blue", "contracting_node": "tab:brown", "dmp": "tab:orange"}


def task_records(records: list[dict[str, Any]], task: str, learners: list[str]) -> dict[str, dict[str, Any]]:
    """{learner: its in-sample record of ``task`` with the lowest seed}."""
    out: dict[str, dict[str, Any]] = {}
    for r in sorted(records, key=lambda r: r["seed"]):
        if r["task"] == task and r["learner"] in learners and r["split"] == IN_SAMPLE:
            out.setdefault(r["learner"], r)
    return {k: out[k] for k in learners if k in out}


def figure_paths_3d(recs: dict[str, dict[str, Any]], demos: DemoSet, task: str, arrays: Any, path: Path) -> None:
    """One 3-D panel per learner, equal axis scales, viewed across the demos' thinnest horizontal
    extent: the task's demos (wide, grey-black), the reproductions from the demo starts (the
    learner's colour) and the rollouts from the perturbed starts (light grey, cut off outside the
    demos' bounding box grown by 15%), positions in m."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    lo, hi = demos.bounds(0.15)
    ext = np.maximum(hi - lo, 1e-3)
    n = max(len(recs), 1)
    cols = n if n <= 3 else (2 if n == 4 else 3)   # four learners as 2 x 2, five or six as 3 per row
    rows = -(-n // cols)
    fig = Figure(figsize=(4.6 * cols, 3.4 * rows + 0.4))
    for i, (learner, r) in enumerate(recs.items()):
        a = arrays(r)
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        inside = ((a["rollouts_x"] >= lo) & (a["rollouts_x"] <= hi)).all(axis=-1, keepdims=True)
        for traj in np.where(inside, a["rollouts_x"], np.nan):
            ax.plot(*traj.T, color="0.7", lw=0.4, alpha=0.6)
        for x in demos.x:
            ax.plot(*x.T, color="0.15", lw=1.8, alpha=0.45)
        for y in a["repro_x"]:
            ax.plot(*y.T, color=COLORS.get(learner, "tab:blue"), lw=0.9)
        ax.scatter(*demos.goal, marker="*", s=70, color="gold", edgecolor="k", zorder=5)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(ext), zoom=1.25)
        ax.view_init(elev=25, azim=-20 if ext[0] < ext[1] else -70)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(3))
        ax.tick_params(labelsize=6, pad=0)
        for name, label in (("x", ax.set_xlabel), ("y", ax.set_ylabel), ("z", ax.set_zlabel)):
            label(name, fontsize=7, labelpad=-8)
        ax.set_title(f"{learner}  DTW {fmt(r['metrics']['dtw_mm'], '.0f')} mm", fontsize=9)
    fig.suptitle(f"{task}: demos (wide, dark), reproductions from the demo starts (colour),"
                 f"{' ' if cols > 1 else chr(10)}rollouts from the perturbed starts (light grey); m", fontsize=9,
                 y=0.995)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.02, top=1.0 - 0.75 / (3.4 * rows + 0.4), wspace=0.05,
                        hspace=0.15)
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))


def figure_angles(recs: dict[str, dict[str, Any]], demos: DemoSet, demo_deg: np.ndarray, task: str, arrays: Any,
                  path: Path, radius_deg: float) -> None:
    """One panel per learner: the geodesic angle to the goal orientation over time (log scale), of
    the demos (black), the reproductions (the learner's colour) and the perturbed rollouts over the
    horizon (grey), with the convergence bound (dashed)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.4 * max(len(recs), 1), 2.9))
    floor = 1e-3
    axes: list[Any] = []
    for i, (learner, r) in enumerate(recs.items()):
        a = arrays(r)
        ax = fig.add_subplot(1, max(len(recs), 1), i + 1, sharey=axes[0] if axes else None)
        axes.append(ax)
        for v in a["rollouts_deg"]:
            ax.plot(a["horizon_t"], np.maximum(v, floor), color="0.6", lw=0.4, alpha=0.5)
        for ti, v in zip(demos.t, demo_deg):
            ax.plot(ti - ti[0], np.maximum(v, floor), color="k", lw=0.9, alpha=0.8)
        for v in a["repro_deg"]:
            ax.plot(a["t"], np.maximum(v, floor), color=COLORS.get(learner, "tab:blue"), lw=1.0)
        ax.axhline(radius_deg, color="k", ls="--", lw=0.7)
        ax.set_yscale("log")
        ax.set_ylim(floor, 200.0)
        ax.set_xlabel("t (s)", fontsize=7)
        ax.tick_params(labelsize=6)
        conv = r["convergence"]["rate"]
        ax.set_title(f"{learner}  converged {'—' if conv is None else f'{100 * conv:.0f}%'}", fontsize=8)
    if axes:
        axes[0].set_ylabel("angle to goal (°)", fontsize=7)
    fig.suptitle(f"{task}: geodesic angle to the goal orientation; demos (black), reproductions (colour), "
                 f"perturbed starts (grey), {radius_deg:g}° (dashed)", fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))
