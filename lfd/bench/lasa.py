"""The LASA suite behind ``lfd bench lasa``: 30 handwriting shapes, positions in mm.

The protocol is ``lfd.bench.protocol.LasaProtocol`` (docs/benchmark.md). Per demo i (x_i of shape
(T, 2), reproduced on its own time grid t_i): rmse, dtw (every ``dtw_step``-th sample), dtw_per_sample
(all samples, / T), chamfer_dtwd, chamfer_dtwd_std (on data divided by the shape's per-coordinate
std), frechet, swept_area, velocity_rmse and cosine_error (the model's velocities against the
demo's), in mm, mm², mm/s (``lfd.metrics``). In-sample, per shape: convergence from the demo, ring
and box starts (``lfd.bench.protocol.starts``) over the horizon, the spurious-attractor fraction of
the 35 x 35 grid of starts over the demos' box (autonomous models only), the single-point step
time, and the figure arrays.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lfd import metrics
from lfd.bench import protocol as proto
from lfd.bench.model import Model
from lfd.bench.report import TRAIN_ROW, TRAIN_SUMMARY, figure_paths, fmt, mean_median, pct, row_value, table
from lfd.bench.spaces import POSITIONS
from lfd.bench.suite import IN_SAMPLE, Column, Suite
from lfd.bench.summary import stats
from lfd.demos import LASA_SHAPES, DemoSet, lasa
from lfd.io import atomic_write

# Literals, read by ``lfd --help`` without importing this module: the command's help, the word for a
# unit, the units of --quick, the protocol's command-line options (flag, field, help).
HELP = "the LASA handwriting benchmark (30 shapes)"
UNIT = "shape"
QUICK_UNITS: tuple[str, ...] = ("Angle", "Sine", "GShape")
PROTOCOL_OPTIONS: tuple[tuple[str, str, str], ...] = (
    ("--ring-points", "ring_points", "perturbed starts on the ring around each demo start (default 8)"),
    ("--box-points", "box_points", "perturbed starts in the demos' box grown by half (default 64)"),
    ("--spurious-grid", "spurious_grid", "starts per side of the spurious-attractor grid (default 35)"))
# Each metric under its own name, in report order; formulas in docs/benchmark.md ("Reproduction metrics").
METRICS: tuple[str, ...] = ("dtw", "dtw_per_sample", "rmse", "chamfer_dtwd", "chamfer_dtwd_std", "frechet",
                            "swept_area", "velocity_rmse", "cosine_error")
LABELS: dict[str, str] = {
    "dtw": "DTW (sum, mm)", "dtw_per_sample": "DTW/T (mm)", "rmse": "RMSE (mm)", "chamfer_dtwd": "DTWD* (mm)",
    "chamfer_dtwd_std": "DTWD*/σ", "frechet": "Fréchet (mm)", "swept_area": "swept area (mm²)",
    "velocity_rmse": "vel. RMSE (mm/s)", "cosine_error": "cos. err.",
}
FORMATS: dict[str, str] = {"dtw": ".0f", "dtw_per_sample": ".2f", "rmse": ".2f", "chamfer_dtwd": ".2f",
                           "chamfer_dtwd_std": ".3f", "frechet": ".2f", "swept_area": ".0f",
                           "velocity_rmse": ".1f", "cosine_error": ".3f"}
# Peer reference points, not computed here: the numbers the project brief gives for two published
# learners, measured by peers on six LASA shapes (true DTW over every 4th sample, one torch thread).
# Methods: Euclideanizing Flows (Rana et al., L4DC 2020, arXiv:2005.13143) and ELCD. Printed as given.
PEER_REFERENCES: dict[str, dict[str, float]] = {
    "Euclideanizing Flows": {"train_time_s": 110.0, "dtw": 300.0, "rmse": 4.9, "step_time_us": 9700.0,
                             "converged": 0.99},
    "ELCD": {"train_time_s": 28.0, "dtw": 847.0, "rmse": 9.1, "step_time_us": 14600.0, "converged": 0.43},
}
TARGETS: dict[str, tuple[str, float]] = {  # contraction learner, over the 30 shapes
    "dtw": ("<=", 300.0), "rmse": ("<=", 4.9), "train_time_s": ("<=", 10.0), "step_time_us": ("<=", 100.0),
    "converged": (">=", 1.0),
}


def convergence(final: np.ndarray, goal: np.ndarray, st: proto.Starts, radius: float) -> dict[str, Any]:
    """Fractions of rollouts ending within ``radius`` of ``goal``: of all starts (``rate``) and
    of each group (``demo``, ``ring``, ``box``; None for an empty group), with the group sizes
    and the median and largest final distance (inf for a diverged rollout).
    final : array, shape (B, d), the rollouts' end points in the order of ``st.all``."""
    dist = np.linalg.norm(final - goal, axis=1)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    out: dict[str, Any] = {"rate": metrics.convergence_rate(final, goal, radius)}
    for name, sl in st.groups().items():
        out[name] = metrics.convergence_rate(final[sl], goal, radius) if len(dist[sl]) else None
    out.update(n_starts=len(dist), n_demo=len(st.demo), n_ring=len(st.ring), n_box=len(st.box),
               radius_mm=radius, median_final_mm=float(np.median(dist)), max_final_mm=float(np.max(dist)))
    return out


def spurious_grid(model: Model, demos: DemoSet, protocol: proto.LasaProtocol) -> float | None:
    """The spurious-attractor fraction of CONDOR/PUMA: of the ``protocol.spurious_grid`` squared
    starts of ``proto.grid_starts`` (over the demos' bounding box), the fraction whose rollout
    over the convergence horizon (``proto.horizon``) does not end within ``radius_mm`` of the
    goal; its solver is recorded as ``grid``. None for a time-indexed model (``autonomous``
    False: the DMP reaches the goal by construction)."""
    if not model.autonomous:
        return None
    h, n = proto.horizon(demos, protocol)
    final = model.rollouts(proto.grid_starts(demos, protocol), np.linspace(0.0, h, n), label="grid")[:, -1]
    return metrics.spurious_attractor_fraction(final, demos.goal, protocol.radius_mm)


class LasaSuite(Suite):
    """The LASA handwriting suite (module docstring); ``protocol`` is a ``LasaProtocol``."""

    name = "lasa"
    title = "LASA benchmark"
    unit = UNIT
    units = LASA_SHAPES
    quick_units = QUICK_UNITS
    protocol_type = proto.LasaProtocol
    quick_options = {"contraction": {"iterations": 60}, "node": {"iterations": 200},
                     "contracting_node": {"iterations": 100}}
    n_demos = proto.N_LASA_DEMOS
    space = POSITIONS
    metrics = METRICS
    labels = LABELS
    formats = FORMATS
    headline = ("dtw", "rmse", "frechet")
    protocol: proto.LasaProtocol

    def demos(self, unit: str) -> DemoSet:
        return lasa(unit)

    def score(self, y: np.ndarray, v: np.ndarray, demos: DemoSet, scored: list[int],
              goal: np.ndarray) -> dict[str, list[float]]:
        step = self.protocol.dtw_step
        per: dict[str, list[float]] = {m: [] for m in METRICS}
        std = demos.x.reshape(-1, demos.dim).std(axis=0)   # (d,): the shape's data, all demos
        for i, yi, vi in zip(scored, y, v):
            x, xd = demos.x[i], demos.xd[i]
            finite, vfinite = bool(np.isfinite(yi).all()), bool(np.isfinite(vi).all())
            row = {
                "rmse": metrics.rmse(yi, x) if finite else np.inf,
                "dtw": metrics.dtw(yi, x, step=step) if finite else np.inf,
                "dtw_per_sample": metrics.dtw_per_sample(yi, x) if finite else np.inf,
                "chamfer_dtwd": metrics.chamfer_dtwd(yi, x) if finite else np.inf,
                "chamfer_dtwd_std": metrics.chamfer_dtwd_std(yi, x, std) if finite else np.inf,
                "frechet": metrics.frechet(yi, x) if finite else np.inf,
                "swept_area": metrics.swept_area(yi, x) if finite else np.inf,
                "velocity_rmse": metrics.velocity_rmse(vi, xd) if vfinite else np.inf,
                "cosine_error": metrics.cosine_error(vi, xd) if vfinite else np.inf,
            }
            for m in METRICS:
                per[m].append(float(row[m]))
        return per

    def in_sample(self, model: Model, demos: DemoSet, unit: str,
                  y: np.ndarray) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """``convergence`` and ``step_time_us``; the arrays ``demo_rollouts`` (N, T, 2), ``starts``
        (B, 2), ``rollouts`` (B, keep, 2), ``final`` (B, 2), ``grid_x`` (G,), ``grid_y`` (G,),
        ``grid_v`` (G, G, 2) or (0,), ``n_demo``, ``n_ring``."""
        p = self.protocol
        st = proto.starts(demos, unit, p)
        h, n = proto.horizon(demos, p)
        traj = model.rollouts(st.all, np.linspace(0.0, h, n))
        conv = {**convergence(traj[:, -1], demos.goal, st, p.radius_mm), "horizon_s": h, "n_steps": n}
        conv["spurious_grid"] = spurious_grid(model, demos, p)
        conv["n_grid"] = 0 if conv["spurious_grid"] is None else p.spurious_grid ** 2
        points = demos.x.reshape(-1, demos.dim)
        step_us = model.step_time_us(points[::max(1, len(points) // p.timing_calls)], p.timing_calls)
        lo, hi = demos.bounds(p.box_grow)
        gx, gy = np.linspace(lo[0], hi[0], p.grid), np.linspace(lo[1], hi[1], p.grid)
        gv = model.velocities(np.stack(np.meshgrid(gx, gy), axis=-1))
        keep = np.unique(np.linspace(0, n - 1, p.keep_points).round().astype(int))
        arrays = {"demo_rollouts": y, "starts": st.all, "rollouts": traj[:, keep], "final": traj[:, -1],
                  "grid_x": gx, "grid_y": gy, "grid_v": gv if gv is not None else np.zeros(0),
                  "n_demo": np.array(len(st.demo)), "n_ring": np.array(len(st.ring))}
        return {"step_time_us": step_us, "convergence": conv}, arrays

    def unit_row(self, records: list[dict[str, Any]]) -> dict[str, Any]:
        """``converged`` (all starts), ``converged_perturbed`` (ring and box), ``n_perturbed``,
        ``n_perturbed_ok``, ``spurious`` (None for a time-indexed model), ``step_time_us``."""
        conv = [r["convergence"] for r in records]
        n_pert = [c["n_ring"] + c["n_box"] for c in conv]
        n_ok = [(c["ring"] or 0.0) * c["n_ring"] + (c["box"] or 0.0) * c["n_box"] for c in conv]
        grid = [c.get("spurious_grid") for c in conv]
        return {"converged": float(np.mean([c["rate"] for c in conv])),
                "spurious": None if any(g is None for g in grid) else float(np.mean(grid)),
                "converged_perturbed": float(np.sum(n_ok) / max(np.sum(n_pert), 1)),
                "n_perturbed": int(np.sum(n_pert)), "n_perturbed_ok": int(round(float(np.sum(n_ok)))),
                "step_time_us": float(np.mean([r["step_time_us"] if r["step_time_us"] is not None else math.inf
                                               for r in records]))}

    def summary_extras(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """``converged`` {mean, median}, ``spurious`` (or None), ``converged_perturbed`` (pooled over
        all perturbed starts), ``units_all_converged``, ``step_time_us``."""
        grid = [v["spurious"] for v in rows if v["spurious"] is not None]
        return {"converged": stats([v["converged"] for v in rows]),
                "spurious": stats(grid) if len(grid) == len(rows) else None,
                "converged_perturbed": (sum(v["n_perturbed_ok"] for v in rows)
                                        / max(sum(v["n_perturbed"] for v in rows), 1)),
                "units_all_converged": sum(v["converged"] == 1.0 for v in rows),
                "step_time_us": stats([v["step_time_us"] for v in rows])}

    # ---------------------------------------------------------------- report

    def intro(self, units: list[str], run: dict[str, Any]) -> list[str]:
        p, n = self.protocol, self.n_demos
        starts = n * (1 + p.ring_points) + p.box_points
        return [
            f"- {len(units)} shapes, seeds {run['seeds']}; metrics in mm, DTW = sum of distances along the optimal "
            f"warping path over every {p.dtw_step}th sample; DTW/T = DTW over all samples divided by the sample "
            "count (CONDOR, PUMA); DTWD* = closest-point (Chamfer) distance, not DTW; DTWD*/σ = the same on data "
            "divided by its per-coordinate std (ELCD, NCDS); swept area = sum of quadrilateral areas, a crossed "
            "one counted as the sum of its two lobes; formulas in docs/benchmark.md.",
            f"- Spurious attractors (CONDOR, PUMA): fraction of a {p.spurious_grid}×{p.spurious_grid} grid of starts "
            "over the demos' bounding box that does not converge (not computed for the time-indexed DMP).",
            f"- Convergence (in-sample): within {p.radius_mm:g} mm of the goal after {p.horizon_factor:g}x the longest "
            f"demo's duration, from {n} demo starts, {n * p.ring_points} ring starts ({p.ring_radius:g} x extent "
            f"around each demo start) and {p.box_points} box starts (bounding box grown by {100 * p.box_grow:g}%) "
            f"per shape: the fraction of all {starts}, and of all perturbed starts pooled.",
        ]

    def summary_columns(self) -> list[Column]:
        return [Column("converged (all starts)", lambda s: s,
                       lambda s: f"{pct(s['converged']['mean'])} ({s['units_all_converged']}/{s['units']} shapes all)"),
                Column("converged (perturbed)", lambda s: s["converged_perturbed"], pct),
                Column("spurious (35×35 grid)", lambda s: s["spurious"],
                       lambda v: "—" if v is None else f"{pct(v['mean'])} / {pct(v['median'])}"),
                TRAIN_SUMMARY, mean_median("step (µs)", "step_time_us", ".1f")]

    def unit_columns(self) -> list[Column]:
        return [Column("converged", lambda r: r["converged"], pct),
                Column("spurious (35×35)", lambda r: math.nan if r["spurious"] is None else r["spurious"], pct),
                TRAIN_ROW, row_value("step (µs)", "step_time_us", ".1f")]

    def reading(self, learner: str, summary: dict[str, Any], rows: dict[str, dict[str, Any]],
                run: dict[str, Any]) -> str:
        s, m, p = summary, summary["metrics"], self.protocol
        worst = sorted(rows, key=lambda k: -rows[k]["metrics"]["dtw"])[:3]
        failing = [k for k in rows if rows[k]["converged"] < 1.0]
        text = (f"**{learner}** reproduces the demos of {s['units']} shapes with DTW "
                f"{fmt(m['dtw']['mean'], '.0f')} (median {fmt(m['dtw']['median'], '.0f')}) and RMSE "
                f"{fmt(m['rmse']['mean'], '.2f')} mm (median {fmt(m['rmse']['median'], '.2f')} mm); "
                f"{pct(s['converged']['mean'])} of all starts and {pct(s['converged_perturbed'])} of the perturbed "
                f"starts end within {p.radius_mm:g} mm of the goal after {p.horizon_factor:g}x the longest demo's "
                "duration. Hardest shapes by DTW: "
                + ", ".join(f"{k} ({rows[k]['metrics']['dtw']:.0f})" for k in worst) + ". "
                f"Its cells took {s['cell_s_total'] / 60:.1f} min of worker time in all (training and scoring, one "
                f"process each); training took {fmt(s['train_cpu_s']['mean'], '.2f')} s of CPU time per shape on "
                f"average (mean wall time {fmt(s['train_time_s']['mean'], '.2f')} s, inflated by whatever else ran). ")
        if s["spurious"] is not None:
            text += (f"On the 35×35 grid of starts over the demos' box, {pct(s['spurious']['mean'])} do not reach the "
                     "goal (spurious-attractor fraction, mean over shapes). ")
        text += ("Starts that do not converge on: " + ", ".join(
            f"{k} ({100 * rows[k]['converged']:.0f}%)" for k in failing) + "." if failing
                 else "Every start converges on every shape.")
        est = s["train_time_s"]["mean"] * len(LASA_SHAPES) / max(int(run["workers"]), 1)
        if s["units"] < len(LASA_SHAPES) and est >= 60:
            text += (f" It ran on {s['units']} of the {len(LASA_SHAPES)} shapes; at its mean training time of "
                     f"{s['train_time_s']['mean']:.0f} s per shape, all {len(LASA_SHAPES)} would take about "
                     f"{est / 60:.0f} min of training with {run['workers']} worker(s).")
        fallback = [k for k in rows if rows[k]["fallback"]]
        if fallback:
            text += (" dopri5 gave up (a very stiff field) and the fixed-step rk4 fallback ran on: "
                     + ", ".join(fallback) + ".")
        return text

    def closing(self, summary: dict[str, Any]) -> list[str]:
        inside = {k: v[IN_SAMPLE] for k, v in summary.items() if v[IN_SAMPLE] is not None}
        parts = []
        if len(inside) > 1:
            best = {m: min(inside, key=lambda k: inside[k]["metrics"][m]["mean"]) for m in ("dtw", "rmse")}
            parts.append(f"Lowest mean DTW: {best['dtw']}; lowest mean RMSE: {best['rmse']}.")
        if "dmp" in summary:
            parts.append("The DMP is re-timed to each demo's duration (tau) and converges by construction "
                         "(a spring-damper to the goal once its phase has decayed), so its RMSE and "
                         "convergence are not the evidence they are for an autonomous field; it has no "
                         "streamlines, and its velocity metrics compare its rollout's velocity with the "
                         "demo's, sample by sample.")
        return parts

    def sections(self, summary: dict[str, Any]) -> list[str]:
        """The contraction learner's targets and the peers' reference numbers."""
        s = (summary.get("contraction") or {}).get(IN_SAMPLE)
        md = ["## Targets (contraction learner)", ""]
        if s is None:
            md.append("The contraction learner was not part of this run (in-sample).")
        else:
            measured = {"dtw": s["metrics"]["dtw"]["mean"], "rmse": s["metrics"]["rmse"]["mean"],
                        "train_time_s": s["train_time_s"]["mean"], "step_time_us": s["step_time_us"]["mean"],
                        "converged": s["converged"]["mean"]}
            names = {"dtw": "mean DTW", "rmse": "mean RMSE (mm)", "train_time_s": "mean training time per shape (s)",
                     "step_time_us": "mean single-point evaluation (µs)", "converged": "fraction of starts converged"}
            for key, (op, bound) in TARGETS.items():
                v = measured[key]
                verdict = "met" if (v <= bound if op == "<=" else v >= bound) else "**NOT met**"
                md.append(f"- {names[key]}: {fmt(v, '.4g')} (target {op} {bound:g}): {verdict}")
        md += ["", "Reference points measured by peers on six shapes (true DTW, every 4th sample, one torch thread):",
               "", table(["method", "train (s/shape)", "DTW", "RMSE (mm)", "step (µs)", "converged"],
                         [[name, f"{r['train_time_s']:g}", f"{r['dtw']:g}", f"{r['rmse']:g}", f"{r['step_time_us']:g}",
                           f"{100 * r['converged']:g}%"] for name, r in PEER_REFERENCES.items()]), ""]
        return md

    def figures(self, path: Path, records: list[dict[str, Any]], learners: list[str], units: list[str],
                arrays: Any) -> dict[str, list[tuple[str, Path]]]:
        """One grid per learner with in-sample records (``figure_grid``)."""
        drawn = [k for k in learners if any(r["learner"] == k and r["split"] == IN_SAMPLE for r in records)]
        paths = figure_paths(path, drawn)
        for learner in drawn:
            figure_grid(records, learner, units, arrays, paths[learner])
        return {learner: [(f"LASA {learner}", paths[learner])] for learner in drawn}


SUITE = LasaSuite


def figure_grid(records: list[dict[str, Any]], learner: str, shapes: list[str], arrays: Any, path: Path) -> None:
    """All shapes of one learner (in-sample, first seed): streamlines (fields only, grey), demos
    (black), rollouts from the demo starts (red), from ring starts (blue) and from box starts (green)."""
    from matplotlib.figure import Figure

    recs: dict[str, dict[str, Any]] = {}
    for r in sorted(records, key=lambda r: r["seed"]):
        if r["learner"] == learner and r["split"] == IN_SAMPLE:
            recs.setdefault(r["shape"], r)
    shapes = [s for s in shapes if s in recs]
    cols = min(6, len(shapes))
    rows = math.ceil(len(shapes) / cols)
    fig = Figure(figsize=(2.6 * cols, 2.6 * rows + 0.4))
    for i, shape in enumerate(shapes):
        ax = fig.add_subplot(rows, cols, i + 1)
        a = arrays(recs[shape])
        gx, gy, gv = a["grid_x"], a["grid_y"], a["grid_v"]
        if gv.size:
            v = np.where(np.isfinite(gv), gv, 0.0)
            ax.streamplot(gx, gy, v[..., 0], v[..., 1], density=0.8, color="0.75", linewidth=0.5, arrowsize=0.5)
        demos = lasa(shape)
        for x in demos.x:
            ax.plot(x[:, 0], x[:, 1], color="k", lw=1.2, alpha=0.8)
        nd, nr = int(a["n_demo"]), int(a["n_ring"])
        for sl, color, lw in ((slice(nd + nr, None), "tab:green", 0.4), (slice(nd, nd + nr), "tab:blue", 0.5)):
            for traj in a["rollouts"][sl]:
                ax.plot(traj[:, 0], traj[:, 1], color=color, lw=lw, alpha=0.7)
            ax.plot(a["starts"][sl, 0], a["starts"][sl, 1], ".", color=color, ms=2)
        for y in a["demo_rollouts"]:
            ax.plot(y[:, 0], y[:, 1], color="tab:red", lw=1.0)
        ax.plot(*demos.goal, "*", color="gold", mec="k", ms=8)
        ax.set_xlim(gx[0], gx[-1])
        ax.set_ylim(gy[0], gy[-1])
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{shape}  DTW {fmt(recs[shape]['metrics']['dtw'], '.0f')}", fontsize=8)
    fig.suptitle(f"LASA, {learner}: demos (black), rollouts from demo starts (red), ring starts (blue), "
                 "box starts (green); grey: streamlines", fontsize=9)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=80))
