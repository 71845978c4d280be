"""The LASA report: aggregates over shapes, a markdown file and one figure grid per learner.

Per learner and shape a metric is the mean over the shape's demos (and over seeds); the
report then gives its mean and median over shapes. A diverged rollout's metric is infinite
(null in JSON): it makes the mean infinite and counts as the worst value for the median.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lfd.bench.evaluate import METRICS
from lfd.bench.protocol import N_LASA_DEMOS, LasaProtocol
from lfd.io import atomic_write

# Each metric under its own name; formulas in docs/benchmark.md ("Reproduction metrics").
LABELS: dict[str, str] = {
    "dtw": "DTW (sum, mm)", "dtw_per_sample": "DTW/T (mm)", "rmse": "RMSE (mm)", "chamfer_dtwd": "DTWD* (mm)",
    "chamfer_dtwd_std": "DTWD*/σ", "frechet": "Fréchet (mm)", "swept_area": "swept area (mm²)",
    "velocity_rmse": "vel. RMSE (mm/s)", "cosine_error": "cos. err.",
}
ORDER: tuple[str, ...] = ("dtw", "dtw_per_sample", "rmse", "chamfer_dtwd", "chamfer_dtwd_std", "frechet",
                          "swept_area", "velocity_rmse", "cosine_error")
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


def _num(v: Any) -> float:
    return float(v) if v is not None else math.inf


def stats(values: list[float]) -> dict[str, float]:
    """The mean and median of ``values`` (NaN for none)."""
    a = np.asarray(values, dtype=np.float64)
    if len(a) == 0:
        return {"mean": math.nan, "median": math.nan}
    with np.errstate(invalid="ignore"):
        return {"mean": float(np.mean(a)), "median": float(np.median(a))}


def per_shape(records: list[dict[str, Any]], learner: str) -> dict[str, dict[str, Any]]:
    """{shape: values} for one learner, averaged over seeds: each metric of ``train`` and of
    ``test`` (None without held-out demos), ``converged`` (all starts), ``converged_perturbed``,
    ``n_perturbed``, ``train_time_s``, ``step_time_us``, ``fallback`` (a rollout needed the
    fixed-step rk4 fallback of ``lfd.bench.evaluate.FieldModel``), ``spurious`` (fraction of the
    35 x 35 grid of starts that does not converge; None for a time-indexed model)."""
    by: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        if r["learner"] == learner:
            by.setdefault(r["shape"], []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for shape, rs in by.items():
        row: dict[str, Any] = {}
        for split in ("train", "test"):
            row[split] = None if rs[0][split] is None else {
                m: float(np.mean([_num(r[split][m]) for r in rs])) for m in METRICS}
        conv = [r["convergence"] for r in rs]
        n_pert = [c["n_ring"] + c["n_box"] for c in conv]
        n_ok = [(c["ring"] or 0.0) * c["n_ring"] + (c["box"] or 0.0) * c["n_box"] for c in conv]
        row["converged"] = float(np.mean([c["rate"] for c in conv]))
        grid = [c.get("spurious_grid") for c in conv]
        row["spurious"] = None if any(g is None for g in grid) else float(np.mean(grid))
        row["converged_perturbed"] = float(np.sum(n_ok) / max(np.sum(n_pert), 1))
        row["n_perturbed"] = int(np.sum(n_pert))
        row["n_perturbed_ok"] = int(round(float(np.sum(n_ok))))
        row["train_time_s"] = float(np.mean([_num(r["train_time_s"]) for r in rs]))
        row["train_cpu_s"] = float(np.mean([r.get("history", {}).get("train_cpu_s", math.nan) for r in rs]))
        row["step_time_us"] = float(np.mean([_num(r["step_time_us"]) for r in rs]))
        row["cell_s"] = float(np.sum([_num(r.get("cell_s")) for r in rs]))
        row["fallback"] = any(str(v).startswith("rk4") for r in rs for v in r.get("integrators", {}).values())
        out[shape] = row
    return out


def summarize(records: list[dict[str, Any]], learners: list[str]) -> dict[str, Any]:
    """{learner: {"shapes", "train": {metric: {mean, median}}, "test" (or None), "converged", "spurious"
    (or None),
    "converged_perturbed" (pooled over all perturbed starts), "shapes_all_converged",
    "train_time_s" (mean, median, total), "step_time_us", "cell_s_total" (wall time of training
    and scoring all its cells, one process each)}}."""
    out: dict[str, Any] = {}
    for learner in learners:
        rows = per_shape(records, learner)
        if not rows:
            continue
        vals = list(rows.values())
        s: dict[str, Any] = {"shapes": len(rows)}
        for split in ("train", "test"):
            s[split] = None if vals[0][split] is None else {
                m: stats([v[split][m] for v in vals]) for m in METRICS}
        s["converged"] = stats([v["converged"] for v in vals])
        grid = [v["spurious"] for v in vals if v["spurious"] is not None]
        s["spurious"] = stats(grid) if len(grid) == len(vals) else None
        s["converged_perturbed"] = (sum(v["n_perturbed_ok"] for v in vals)
                                    / max(sum(v["n_perturbed"] for v in vals), 1))
        s["shapes_all_converged"] = sum(v["converged"] == 1.0 for v in vals)
        s["train_time_s"] = {**stats([v["train_time_s"] for v in vals]),
                             "total": float(sum(v["train_time_s"] for v in vals))}
        s["train_cpu_s"] = stats([v["train_cpu_s"] for v in vals])
        s["step_time_us"] = stats([v["step_time_us"] for v in vals])
        s["cell_s_total"] = float(sum(v["cell_s"] for v in vals))
        out[learner] = s
    return out


def fmt(v: Any, spec: str) -> str:
    """A number for a report table with ``spec``: a dash for None or NaN, ``inf`` for infinity."""
    if v is None:
        return "—"
    v = float(v)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "inf"
    return format(v, spec)


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table of ``header`` and ``rows`` (strings)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def summary_table(summary: dict[str, Any], split: str) -> str:
    """One row per learner, each cell 'mean / median' over shapes."""
    header = ["learner", "shapes"] + [LABELS[m] for m in ORDER]
    if split == "train":
        header += ["converged (all starts)", "converged (perturbed)", "spurious (35×35 grid)", "train (s)",
                   "step (µs)"]
    rows = []
    for learner, s in summary.items():
        if s[split] is None:
            continue
        row = [learner, str(s["shapes"])]
        row += [f"{fmt(s[split][m]['mean'], FORMATS[m])} / {fmt(s[split][m]['median'], FORMATS[m])}"
                for m in ORDER]
        if split == "train":
            all_ok = f"{s['shapes_all_converged']}/{s['shapes']} shapes all"
            row += [f"{100 * s['converged']['mean']:.1f}% ({all_ok})",
                    f"{100 * s['converged_perturbed']:.1f}%",
                    "—" if s["spurious"] is None else f"{100 * s['spurious']['mean']:.1f}% / "
                                                       f"{100 * s['spurious']['median']:.1f}%",
                    f"{fmt(s['train_time_s']['mean'], '.2f')} / {fmt(s['train_time_s']['median'], '.2f')}",
                    f"{fmt(s['step_time_us']['mean'], '.1f')} / {fmt(s['step_time_us']['median'], '.1f')}"]
        rows.append(row)
    return table(header, rows)


def shape_table(rows: dict[str, dict[str, Any]], shapes: list[str], split: str) -> str:
    """One row per shape, then the Mean and Median rows over shapes."""
    shapes = [s for s in shapes if s in rows]

    def getter(m: str) -> Callable[[dict[str, Any]], float]:
        return lambda r: r[split][m]

    def formatter(m: str) -> Callable[[float], str]:
        return lambda v: fmt(v, FORMATS[m])

    cols: list[tuple[str, Callable[[dict[str, Any]], float], Callable[[float], str]]] = [
        (LABELS[m], getter(m), formatter(m)) for m in ORDER]
    if split == "train":
        cols += [("converged", lambda r: r["converged"], lambda v: f"{100 * v:.1f}%"),
                 ("spurious (35×35)", lambda r: math.nan if r["spurious"] is None else r["spurious"],
                  lambda v: "—" if math.isnan(v) else f"{100 * v:.1f}%"),
                 ("train (s)", lambda r: r["train_time_s"], lambda v: fmt(v, ".2f")),
                 ("step (µs)", lambda r: r["step_time_us"], lambda v: fmt(v, ".1f"))]
    body = [[shape] + [fmt(get(rows[shape])) for _, get, fmt in cols] for shape in shapes]
    for name, agg in (("**Mean**", np.mean), ("**Median**", np.median)):
        with np.errstate(invalid="ignore"):
            body.append([name] + [fmt(float(agg([get(rows[s]) for s in shapes]))) for _, get, fmt in cols])
    return table(["shape"] + [c[0] for c in cols], body)


def target_lines(summary: dict[str, Any]) -> list[str]:
    """Each target of the contraction learner with the measured value and met / NOT met."""
    s = summary.get("contraction")
    if s is None:
        return []
    measured = {"dtw": s["train"]["dtw"]["mean"], "rmse": s["train"]["rmse"]["mean"],
                "train_time_s": s["train_time_s"]["mean"], "step_time_us": s["step_time_us"]["mean"],
                "converged": s["converged"]["mean"]}
    names = {"dtw": "mean DTW", "rmse": "mean RMSE (mm)",
             "train_time_s": "mean training time per shape (s)",
             "step_time_us": "mean single-point evaluation (µs)",
             "converged": "fraction of starts converged"}
    out = []
    for key, (op, bound) in TARGETS.items():
        v = measured[key]
        ok = v <= bound if op == "<=" else v >= bound
        verdict = "met" if ok else "**NOT met**"
        out.append(f"- {names[key]}: {fmt(v, '.4g')} (target {op} {bound:g}): {verdict}")
    return out


def reading(summary: dict[str, Any], rows_by: dict[str, dict[str, dict[str, Any]]],
            radius_mm: float, horizon_factor: float, workers: int = 1) -> str:
    """A paragraph per learner generated from the numbers."""
    from lfd.demos import LASA_SHAPES

    parts = []
    for learner, s in summary.items():
        tr = s["train"]
        rows = rows_by[learner]
        worst = sorted(rows, key=lambda k: -rows[k]["train"]["dtw"])[:3]
        failing = [k for k in rows if rows[k]["converged"] < 1.0]
        text = (f"**{learner}** reproduces the demos of {s['shapes']} shapes with DTW "
                f"{fmt(tr['dtw']['mean'], '.0f')} (median {fmt(tr['dtw']['median'], '.0f')}) and RMSE "
                f"{fmt(tr['rmse']['mean'], '.2f')} mm (median {fmt(tr['rmse']['median'], '.2f')} mm); "
                f"{100 * s['converged']['mean']:.1f}% of all starts and "
                f"{100 * s['converged_perturbed']:.1f}% of "
                f"the perturbed starts end within {radius_mm:g} mm of the goal after {horizon_factor:g}x the "
                f"longest demo's duration. Hardest shapes by DTW: "
                + ", ".join(f"{k} ({rows[k]['train']['dtw']:.0f})" for k in worst) + ". "
                f"Its cells took {s['cell_s_total'] / 60:.1f} min of worker time in all "
                f"(training and scoring, one process each); training took "
                f"{fmt(s['train_cpu_s']['mean'], '.2f')} s of CPU time per shape on average (mean wall time "
                f"{fmt(s['train_time_s']['mean'], '.2f')} s, inflated by whatever else ran). ")
        if s.get("spurious") is not None:
            text += (f"On the 35×35 grid of starts over the demos' box, {100 * s['spurious']['mean']:.1f}% "
                     "do not reach the goal (spurious-attractor fraction, mean over shapes). ")
        if failing:
            text += ("Starts that do not converge on: " + ", ".join(
                f"{k} ({100 * rows[k]['converged']:.0f}%)" for k in failing) + ".")
        else:
            text += "Every start converges on every shape."
        est = s["train_time_s"]["mean"] * len(LASA_SHAPES) / max(workers, 1)
        if s["shapes"] < len(LASA_SHAPES) and est >= 60:
            text += (f" It ran on {s['shapes']} of the {len(LASA_SHAPES)} shapes; at its mean training "
                     f"time of {s['train_time_s']['mean']:.0f} s per shape, all {len(LASA_SHAPES)} would "
                     f"take about {est / 60:.0f} min of training with {workers} worker(s).")
        fallback = [k for k in rows if rows[k]["fallback"]]
        if fallback:
            text += (" dopri5 gave up (a very stiff field) and the fixed-step rk4 fallback ran on: "
                     + ", ".join(fallback) + ".")
        if s["test"] is not None:
            te = s["test"]
            text += (f" On held-out demos: DTW {fmt(te['dtw']['mean'], '.0f')}, RMSE "
                     f"{fmt(te['rmse']['mean'], '.2f')} mm (means).")
        parts.append(text)
    if len(summary) > 1:
        best_dtw = min(summary, key=lambda k: summary[k]["train"]["dtw"]["mean"])
        best_rmse = min(summary, key=lambda k: summary[k]["train"]["rmse"]["mean"])
        parts.append(f"Lowest mean DTW: {best_dtw}; lowest mean RMSE: {best_rmse}.")
    if "dmp" in summary:
        parts.append("The DMP is re-timed to each demo's duration (tau) and converges by construction "
                     "(a spring-damper to the goal once its phase has decayed), so its RMSE and "
                     "convergence are not the evidence they are for an autonomous field; it has no "
                     "streamlines, and its velocity metrics compare its rollout's velocity with the "
                     "demo's, sample by sample.")
    return "\n\n".join(parts)


def figure_grid(records: list[dict[str, Any]], learner: str, shapes: list[str],
                arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]], path: str | Path) -> None:
    """All shapes of one learner (first seed): streamlines (fields only, grey), demos (black),
    rollouts from the demo starts (red), from ring starts (blue) and from box starts (green)."""
    from matplotlib.figure import Figure

    from lfd.demos import lasa

    recs: dict[str, dict[str, Any]] = {}
    for r in sorted(records, key=lambda r: r["seed"]):
        if r["learner"] == learner:
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
            ax.streamplot(gx, gy, v[..., 0], v[..., 1], density=0.8, color="0.75", linewidth=0.5,
                          arrowsize=0.5)
        demos = lasa(shape)
        for x in demos.x:
            ax.plot(x[:, 0], x[:, 1], color="k", lw=1.2, alpha=0.8)
        nd, nr = int(a["n_demo"]), int(a["n_ring"])
        groups = ((slice(nd + nr, None), "tab:green", 0.4), (slice(nd, nd + nr), "tab:blue", 0.5))
        for sl, color, lw in groups:
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
        dtw = recs[shape]["train"]["dtw"]
        ax.set_title(f"{shape}  DTW {fmt(dtw, '.0f')}", fontsize=8)
    fig.suptitle(f"LASA, {learner}: demos (black), rollouts from demo starts (red), ring starts (blue), "
                 "box starts (green); grey: streamlines", fontsize=9)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=80))


def run_line(run: dict[str, Any]) -> str:
    """How this invocation ran: workers, wall time, cache use, load, and the cells given up."""
    failed = run.get("failed") or []
    lost = "" if not failed else (
        f" {len(failed)} cell(s) are missing from the tables, given up after their worker process "
        "died on each try: " + "; ".join(f"{f['cell']} ({f['attempts']} tries: {f['reason']})" for f in failed)
        + ".")
    return _run_line(run) + lost


def _run_line(run: dict[str, Any]) -> str:
    head = f"- Run: {run['workers']} worker process(es), one torch thread each, on {run['cpus']} CPU cores; "
    tail = "Timings are inflated by whatever else ran on the machine."
    if run["computed"] == 0:
        return head + (f"all {run['cached']} cells came from the cache of earlier runs, with the timings "
                       f"taken there (each learner's worker time is in the Reading). {tail}")
    return head + (f"wall time {run['wall_s']:.0f} s for the cells computed in this run ({run['computed']} "
                   f"computed, {run['cached']} from the cache; each learner's worker time is in the "
                   f"Reading); load average {run['load_start']} at start, {run['load_end']} at end. {tail}")


def figure_paths(path: str | Path, learners: list[str]) -> dict[str, Path]:
    """{learner: figure path} of the report at ``path``: ``figures/<report stem>_<learner>.png``
    beside it, so reports written into one folder (``lasa.md``, ``quick.md``) keep their own
    figures (``figures/lasa_node.png``, ``figures/quick_node.png``)."""
    path = Path(path)
    return {learner: path.parent / "figures" / f"{path.stem}_{learner}.png" for learner in learners}


def write_report(path: str | Path, records: list[dict[str, Any]], learners: list[str],
                 shapes: list[str], protocol: dict[str, Any], run: dict[str, Any],
                 arrays: Callable[[dict[str, Any]], dict[str, np.ndarray]],
                 notes: str | None = None) -> list[Path]:
    """Write the markdown report and its figures (``figure_paths``). Returns the figure paths."""
    path = Path(path)
    summary = summarize(records, learners)
    rows_by = {learner: per_shape(records, learner) for learner in summary}
    paths = figure_paths(path, list(summary))
    figures = []
    for learner in summary:
        figure_grid(records, learner, shapes, arrays, paths[learner])
        figures.append(paths[learner])
    md = _intro_lines(shapes, protocol, run) + _summary_lines(records, summary, rows_by, shapes, protocol)
    md += ["## Reading", "", reading(summary, rows_by, protocol["radius_mm"], protocol["horizon_factor"],
                                     int(run["workers"])), ""]
    if notes:
        md += [notes.strip(), ""]
    for learner in summary:
        md += [f"## Per shape: {learner}", "", shape_table(rows_by[learner], shapes, "train"), ""]
        if summary[learner]["test"] is not None:
            md += [f"Held-out demos, {learner}:", "", shape_table(rows_by[learner], shapes, "test"), ""]
        rel = paths[learner].relative_to(path.parent)
        md += [f"![LASA {learner}]({rel.as_posix()})", ""]
    text = "\n".join(md)
    atomic_write(path, lambda f: f.write(text.encode()))
    return figures


def n_starts(protocol: dict[str, Any]) -> int:
    """Convergence starts per shape under ``protocol`` (``LasaProtocol.to_dict()``): the demo
    starts, a ring around each, and the box starts (``lfd.bench.protocol.starts``)."""
    return N_LASA_DEMOS * (1 + int(protocol["ring_points"])) + int(protocol["box_points"])


def _intro_lines(shapes: list[str], protocol: dict[str, Any], run: dict[str, Any]) -> list[str]:
    """The report's title and its description of the protocol and of this run."""
    k, n = protocol["train_demos"], N_LASA_DEMOS
    grid = protocol.get("spurious_grid", LasaProtocol.spurious_grid)
    return [
        "# LASA benchmark",
        "",
        f"Generated by `{run['command']}`. Protocol: [docs/benchmark.md](../docs/benchmark.md) "
        f"(version {protocol['version']}).",
        "",
        f"- {len(shapes)} shapes, seeds {run['seeds']}, trained on demos 0..{k - 1}"
        + (f", demos {k}..{n - 1} held out" if k < n else f" (all {n})") + "; metrics in mm, DTW = sum of "
        f"distances along the optimal warping path over every {protocol['dtw_step']}th sample; "
        "DTW/T = DTW over all samples divided by the sample count (CONDOR, PUMA); "
        "DTWD* = closest-point (Chamfer) distance, not DTW; DTWD*/σ = the same on data divided by "
        "its per-coordinate std (ELCD, NCDS); swept area = sum of quadrilateral areas, a crossed one "
        "counted as the sum of its two lobes; formulas in docs/benchmark.md.",
        f"- Spurious attractors (CONDOR, PUMA): fraction of a {grid}×{grid} grid of starts over the "
        "demos' bounding box that does not converge (not computed for the time-indexed DMP).",
        f"- Convergence: within {protocol['radius_mm']:g} mm of the goal after "
        f"{protocol['horizon_factor']:g}x "
        f"the longest demo's duration, from {n} demo starts, {n * protocol['ring_points']} ring starts "
        f"({protocol['ring_radius']:g} x extent around each demo start) and {protocol['box_points']} box "
        f"starts (bounding box grown by {100 * protocol['box_grow']:g}%) per shape.",
        run_line(run),
        "",
    ]


def _summary_lines(records: list[dict[str, Any]], summary: dict[str, Any], rows_by: dict[str, Any],
                   shapes: list[str], protocol: dict[str, Any]) -> list[str]:
    """The summary tables (training demos, common shapes, held-out demos) and the targets."""
    k, n = protocol["train_demos"], N_LASA_DEMOS
    md = [
        "## Summary (mean / median over shapes)",
        "",
        "Reproduction metrics on the training demos"
        + (f" (demos 0..{k - 1}; the held-out demos follow below)." if k < n else f" (all {n}).")
        + f" Convergence: fraction of all {n_starts(protocol)} starts per shape, and of all perturbed "
        "starts pooled.",
        "",
        summary_table(summary, "train"),
        "",
    ]
    common = [s for s in shapes if all(s in rows_by[learner] for learner in summary)]
    if len(summary) > 1 and any(len(rows_by[learner]) != len(common) for learner in summary):
        sub = summarize([r for r in records if r["shape"] in common], list(summary))
        md += [f"## Summary on the {len(common)} shapes every learner ran (mean / median)", "",
               f"Shapes: {', '.join(common)}.", "", summary_table(sub, "train"), ""]
    if any(s["test"] is not None for s in summary.values()):
        md += ["## Held-out demos (mean / median over shapes)", "", summary_table(summary, "test"), ""]
    md += ["## Targets (contraction learner)", ""]
    tl = target_lines(summary)
    md += tl if tl else ["The contraction learner was not part of this run."]
    md += ["", "Reference points measured by peers on six shapes (true DTW, every 4th sample, "
           "one torch thread):", ""]
    md.append(table(["method", "train (s/shape)", "DTW", "RMSE (mm)", "step (µs)", "converged"],
                     [[name, f"{r['train_time_s']:g}", f"{r['dtw']:g}", f"{r['rmse']:g}",
                       f"{r['step_time_us']:g}", f"{100 * r['converged']:g}%"]
                      for name, r in PEER_REFERENCES.items()]))
    return md + [""]
