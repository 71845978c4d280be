"""``lfd bench obstacles``: the field-level obstacle sweep, reports/obstacle_fields.md and its figure.

``run_obstacle_sweep`` trains every learner of ``lfd.bench.obstacles.LEARNERS`` on every demo set of
the sweep once, in this process (the model cache, ``lfd.cache``), then runs the seeded scenes of
``lfd.bench.obstacles.make_cells``, with and without the convergence terms of Eqs. (O2)-(O3), through
the benchmark's content-checked cache (``lfd.bench.runner.run_cells``: a killed sweep resumes), and
writes the report: per learner and modulation the starts that converged, the scenes where every
start did, the entries and the worst final error; per shape; the failing scenes; and a figure of
scenes where the plain modulation misses. The report's hand-written section (``KEPT_HEADING``) is
kept on a rewrite.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from lfd.bench import obstacles as ob
from lfd.bench.runner import run_cells
from lfd.cache import cached_field
from lfd.demos import DemoSet
from lfd.io import atomic_path, kept_section
from lfd.obstacles import random_scene

#: the report's hand-written section (the NODE's misses investigated), kept on a rewrite
KEPT_HEADING = "## Why the NODE misses"


def run_obstacle_sweep(placements: int, workers: int, cache: str | Path, report: str | Path,
                       plain: bool = True, learners: tuple[str, ...] = ob.LEARNERS) -> int:
    """Run ``placements`` scenes of ``learners`` (with ``plain``, also the ablation without Eqs.
    (O2)-(O3)), ``workers`` at a time, cells cached in ``cache``; write the report and its figure
    ``figures/obstacle_fields.png`` beside it. Returns the exit code (0)."""
    cells = ob.make_cells(placements, learners, plain=plain)
    for shape in sorted({c.shape for c in cells}, key=ob.SHAPES.index):   # train once, in this process
        demos = ob.demo_set(shape)
        for learner in learners:
            cached_field(learner, demos, 0, {}, progress=sys.stderr.isatty())
    result = run_cells(cells, cache, workers=workers, compute=ob.compute_obstacle_cell, desc="obstacles",
                       progress=sys.stderr.isatty())
    for f in result.failed:   # shown by lfd.cli as one line "lfd: warning: ..."
        warnings.warn(f"cell {f['cell']} failed ({f['reason']}); run again to retry it", RuntimeWarning, stacklevel=1)
    report = Path(report)
    lines = report_lines(result.records, placements, learners)
    figure = figure_scenes(result.records, Path(cache), report.parent / "figures" / "obstacle_fields.png")
    if figure:
        lines += ["", f"![Trajectories of scenes where the plain modulation fails]({figure})", ""]
    kept = kept_section(report, KEPT_HEADING)
    if kept:
        lines += ([""] if lines[-1] else []) + kept
    with atomic_path(report) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    print(f"wrote {report}")
    return 0


def report_lines(recs: list[dict[str, Any]], placements: int, learners: tuple[str, ...] = ob.LEARNERS) -> list[str]:
    """The report's markdown lines (module docstring)."""
    lines = ["# Obstacles at the field level: every learner still reaches its goal", "",
             "Protocol: not a benchmark suite's: `lfd bench obstacles`' own seeded scenes, stated below.", "",
             "Made by `lfd bench obstacles` (`lfd.bench.obstacles`). "
             f"{placements} seeded scenes (`lfd.obstacles.random_scene`: 1 to 3 spheres or boxes, 3-10 % of "
             "the extent, margins 0-4 %, a quarter of them beside the goal), dealt over "
             f"{', '.join(ob.SHAPES)}; every demo start rolled out for "
             f"{ob.HORIZON} x the demo duration. *Converged*: final position within "
             f"{ob.GOAL_RADIUS_MM} mm of the goal (LASA in mm; the spirals at "
             f"{ob.SPIRAL_EXTENT_M} m of extent). *Entries*: trajectories that met Gamma < 1 "
             "(inside an obstacle grown by its margin).", "",
             "| learner | modulation | scenes | starts converged | scenes with every start converged | entries "
             "| worst final error (mm) |",
             "|---|---|---|---|---|---|---|"]
    for learner in learners:
        for conv in (True, False):
            rs = [r for r in recs if r["learner"] == learner and r["convergence"] == conv]
            if not rs:
                continue
            conv_starts, starts = sum(r["converged"] for r in rs), sum(r["starts"] for r in rs)
            whole = sum(r["converged"] == r["starts"] for r in rs)
            worst = max(max(r["final_error_mm"]) for r in rs)
            name, share = "Eqs. (O1)-(O3)" if conv else "plain (KZB 2012)", 100 * conv_starts / starts
            lines.append(f"| {learner} | {name} | {len(rs)} | {conv_starts}/{starts} ({share:.1f} %) "
                         f"| {whole}/{len(rs)} | {sum(r['entries'] for r in rs)} | {worst:.3g} |")
    lines += ["", "Per shape, Eqs. (O1)-(O3), starts converged:", "",
              "| shape | " + " | ".join(learners) + " |", "|---|" + "---|" * len(learners)]
    for shape in ob.SHAPES:
        row = [shape]
        for learner in learners:
            rs = [r for r in recs if r["learner"] == learner and r["shape"] == shape and r["convergence"]]
            row.append(f"{sum(r['converged'] for r in rs)}/{sum(r['starts'] for r in rs)}" if rs else "-")
        lines.append("| " + " | ".join(row) + " |")
    fails = [r for r in recs if r["convergence"] and (r["converged"] < r["starts"] or r["entries"])]
    lines += ["", f"Scenes that fail with Eqs. (O1)-(O3): {len(fails)}."]
    for r in fails[:20]:
        lines.append(f"- {r['learner']} on {r['shape']}, scene {r['scene']}: {r['converged']}/{r['starts']} converged, "
                     f"worst {max(r['final_error_mm']):.3g} mm, entries {r['entries']}; " + "; ".join(r["obstacles"]))
    cell_s = np.array([r["cell_s"] for r in recs])
    lines += ["", f"Cell time: median {np.median(cell_s):.2f} s, max {cell_s.max():.2f} s."]
    return lines


def figure_scenes(recs: list[dict[str, Any]], cache: Path, path: Path) -> str | None:
    """Up to 6 2-D scenes where the plain modulation misses and Eqs. (O1)-(O3) do not: the path of
    the figure relative to the report's folder, or None without such a scene."""
    from matplotlib.figure import Figure

    by = {(r["learner"], r["shape"], r["scene"], r["convergence"]): r for r in recs}
    picks = [k for k, r in by.items() if not k[3] and r["converged"] < r["starts"]
             and (k[0], k[1], k[2], True) in by and not k[1].startswith("spiral3d")][:6]
    if not picks:
        return None
    fig = Figure(figsize=(3.2 * len(picks), 6.4))
    axes = fig.subplots(2, len(picks), squeeze=False)
    for j, (learner, shape, scene, _) in enumerate(picks):
        demos = ob.demo_set(shape)
        obs = random_scene(demos, scene)
        for i, conv in enumerate((False, True)):
            ax = axes[i, j]
            cell = ob.ObstacleCell.make(learner, shape, scene, conv)
            with np.load(cache / f"{cell.stem}.npz") as z:
                y = z["y"]
            for x in demos.x:
                ax.plot(x[:, 0], x[:, 1], color="0.75", lw=1)
            g = np.stack(np.meshgrid(*[np.linspace(*lim, 300) for lim in _limits(demos, y)]), -1)
            gam = np.min([o.gamma(g) for o in obs], axis=0)
            ax.contourf(g[..., 0], g[..., 1], gam, levels=[0, 1], colors=["#d9534f"], alpha=0.6)
            for yy in y:
                ax.plot(yy[:, 0], yy[:, 1], color="#1f77b4" if conv else "#ff7f0e", lw=1.2)
                ax.plot(*yy[-1, :2], "k.", ms=5)
            ax.plot(*demos.goal[:2], "k*", ms=10)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            r = by[(learner, shape, scene, conv)]
            ax.set_title(f"{learner}, {shape.split(':')[-1]} #{scene}\n"
                         f"{'Eqs. (O1)-(O3)' if conv else 'plain'}: {r['converged']}/{r['starts']} reach", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    return f"figures/{path.name}"


def _limits(demos: DemoSet, y: np.ndarray) -> list[tuple[float, float]]:
    """The axes' ranges of a panel: the demos and the trajectories y, padded by 10% of the larger side."""
    pts = np.concatenate([demos.x.reshape(-1, 2), np.asarray(y).reshape(-1, 2)])
    lo, hi = pts.min(0), pts.max(0)
    pad = 0.1 * (hi - lo).max()
    return [(float(lo[k] - pad), float(hi[k] + pad)) for k in range(2)]
