"""The text and figures of reports/scaling.md (``sim.studies.scaling`` measures, this module writes):
the learners' exponents and curves (``lfd.bench.scaling``), the control step against the number of
obstacles (``sim.studies.scaling_control``), and where a learner's training time grows (``findings_text``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter, ScalarFormatter

from lfd.bench.scaling import CURVES, STACK_SHAPES, fit_exponent, full_config
from lfd.io import atomic_path

__all__ = ["TARGET_EXPONENT", "TARGET_LEARNERS", "control_figure", "curve_rows", "exponents", "findings_text",
           "learner_figure", "report"]

TARGET_EXPONENT = 1.1
TARGET_LEARNERS = ("contraction", "tracking")
#: what the figures call each cost
METRIC_LABELS = {"train_cpu_s": "training CPU time (s)", "single_point_us": "single-point evaluation (µs)",
                 "rmse": "reproduction RMSE per shape (mm)"}


#: what the operators of a profile do in the learners (the report's gloss)
OP_MEANINGS = {
    "aten::bmm": "batched d x d matrix products, one per point (the flow's Jacobian chain "
                 "J_phi = J_k ... J_1 and the per-point rotations, `flows.BoundedFlow.forward_with_jacobian`): "
                 "O(B d^3) per loss evaluation",
    "aten::linalg_matrix_exp": "matrix exponentials e^(A t) of the latent rollouts "
                               "(`ContractionModule.latent_trajectory`, Eq. (C2)): O(N K d^3)",
    "aten::mm": "dense products (hidden layers, latent matrix)",
    "aten::fill_": "filling (B, d, d) tensors (identity and zero Jacobian blocks)",
    "aten::linalg_lu_factor_ex": "the LU factorisation of J_phi for the solve of Eq. (C3): O(B d^3)",
    "aten::linalg_lu_solve": "the triangular solves of Eq. (C3)",
    "aten::index_select": "gathers of reference or table rows",
    "aten::copy_": "tensor copies",
}
#: operators whose cost is cubic in d
CUBIC_OPS = ("aten::bmm", "aten::linalg_matrix_exp", "aten::linalg_lu_factor_ex")
#: the wrappers that hold a whole fit (left out of the function table)
WRAPPERS = ("__init__.py:train", ":fit", ":_fit", ":closure")


def findings_text(learner: str, b: float, small: dict[str, Any], large: dict[str, Any], lo: int, hi: int,
                  opts: dict[str, Any]) -> str:
    """The report's account of where a learner's training time grows (``profile_targets``)."""
    def growth(a: float | None, c: float | None) -> str:
        if not a or not c or a <= 0 or c <= 0:
            return "–"
        return f"{math.log(c / a) / math.log(hi / lo):.2f}"

    total_lo, total_hi = small["ops_total_s"], large["ops_total_s"]
    lines = [f"**Why {learner} grows faster than linearly** (exponent {b:.2f}). A profile of its training "
             f"({', '.join(f'{k}={v}' for k, v in opts.items()) or 'default options'}; "
             f"`lfd.bench.scaling.profile_fit`) at d = {lo} and d = {hi}: the CPU time of the fit grows with "
             f"exponent {growth(small['cpu_s'], large['cpu_s'])} between them; the autograd backward pass "
             f"takes {large['backward_s'] / max(total_hi, 1e-12):.0%} of the operators' time at d = {hi} "
             f"({small['backward_s'] / max(total_lo, 1e-12):.0%} at d = {lo}).", "",
             f"| torch operator (self CPU time) | d = {lo} s | d = {hi} s | share at d = {hi} | exponent | "
             "what it is |",
             "|---|---|---|---|---|---|"]
    for op, t in list(large["ops"].items())[:8]:
        t_lo = small["ops"].get(op)
        lines.append(f"| `{op}` | {_f(t_lo)} | {_f(t)} | {t / max(total_hi, 1e-12):.0%} | {growth(t_lo, t)} | "
                     f"{OP_MEANINGS.get(op, '')} |")
    lines += ["", f"| learner function (cumulative wall time, nested) | d = {lo} s | d = {hi} s | share at d = {hi} | "
              "exponent |", "|---|---|---|---|---|"]
    fns = [(k, v) for k, v in large["functions"].items() if not any(k.endswith(w) or k == w for w in WRAPPERS)]
    for fn, t in fns[:8]:
        t_lo = small["functions"].get(fn)
        lines.append(f"| `{fn}` | {_f(t_lo)} | {_f(t)} | {t / max(large['wall_s'], 1e-12):.0%} | {growth(t_lo, t)} |")
    top = next(iter(large["ops"]), "")
    lines += ["", f"The operator that dominates at d = {hi}: `{top}`"
              + (f", {OP_MEANINGS[top]}" if top in OP_MEANINGS else "") + "."]
    if top in CUBIC_OPS:
        lines[-1] += (" Its cost per point is cubic in d (dense d x d matrices), so the training time cannot "
                      "stay linear in d; at small d torch's fixed cost per operator hides it, which is why the "
                      "fitted exponent lies between 1 and 3.")
    return "\n".join(lines)


# ---------------------------------------------------------------- figures

def learner_figure(records: list[dict[str, Any]], curve: str, learners: tuple[str, ...], path: Path) -> None:
    """Three log-log panels (training CPU time, single-point time, RMSE) of one curve, a line per learner."""
    symbol, _ = CURVES[curve]
    fig = Figure(figsize=(14, 4.2))
    axes = fig.subplots(1, 3)
    for ax, (metric, label) in zip(axes, METRIC_LABELS.items()):
        for learner in learners:
            rows = curve_rows(records, learner, curve)
            if not rows:
                continue
            x = np.array([r[_size_field(curve)] for r in rows], dtype=float)
            y = np.array([r[metric] if r[metric] is not None else np.nan for r in rows], dtype=float)
            b, c = fit_exponent(x, y)
            line, = ax.loglog(x, y, "o-", label=f"{learner} ({b:.2f})" if math.isfinite(b) else learner)
            if math.isfinite(b):
                ax.loglog(x, c * x ** b, ":", color=line.get_color(), lw=1)
        ax.set_xlabel(symbol)
        ax.set_ylabel(label)
        ax.set_xticks(sorted({r[_size_field(curve)] for r in records if curve in r["curves"]}))
        ax.get_xaxis().set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, title="learner (exponent)", title_fontsize=8)
    fig.suptitle(f"against {_curve_title(curve)} (dotted: the least-squares power law)")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)


def control_figure(records: list[dict[str, Any]], path: Path) -> None:
    """Per-step median (µs) and its ratio to a bare mj_step against the obstacle count, a line per robot
    (K = 0 drawn at 0.5 on the log axis; the plain loop as a cross there)."""
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2)
    for ax, metric, label in ((axes[0], "step_us", "control step, median (µs)"),
                              (axes[1], "ratio", "control step / bare mj_step (medians)")):
        for robot in dict.fromkeys(r["robot"] for r in records):
            rows = sorted((r for r in records if r["robot"] == robot and r["dampers"]), key=lambda r: r["count"])
            k = np.array([r["count"] for r in rows], dtype=float)
            y = np.array([r[metric] for r in rows])
            b, c = fit_exponent(k, y)
            xs = np.where(k == 0, 0.5, k)
            line, = ax.loglog(xs, y, "o-", label=f"{robot} ({b:.2f})")
            plain = [r for r in records if r["robot"] == robot and not r["dampers"]]
            if plain:
                ax.loglog([0.5], [plain[0][metric]], "x", color=line.get_color(), ms=9)
        ticks = [0.5, 1, 2, 4, 8, 16]
        ax.set_xticks(ticks)
        ax.set_xticklabels(["0", "1", "2", "4", "8", "16"])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("spheres in the scene, K (x: no obstacles, no dampers)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, title="robot (exponent, K = 1..16)", title_fontsize=8)
    fig.suptitle("closed-loop control step at 500 Hz against the number of obstacles")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)


# ---------------------------------------------------------------- report

def _defaults(learner: str) -> dict[str, Any]:
    """The learner's default options, read now (``lfd.bench.scaling.full_config``)."""
    return full_config(learner, {})


def _size_field(curve: str) -> str:
    return {"dim": "dim", "demos": "n_demos", "samples": "n_samples"}[curve]


def _curve_title(curve: str) -> str:
    return {"dim": "the dimension d (N = 7 demos, T = 1000 samples)",
            "demos": "the number of demos N (d = 2, T = 1000)",
            "samples": "the samples per demo T (d = 2, N = 7)"}[curve]


def curve_rows(records: list[dict[str, Any]], learner: str, curve: str) -> list[dict[str, Any]]:
    """The records of one learner's curve, in order of size."""
    rows = [r for r in records if r["learner"] == learner and curve in r["curves"]]
    return sorted(rows, key=lambda r: r[_size_field(curve)])


def exponents(records: list[dict[str, Any]], learner: str, curve: str) -> dict[str, float]:
    """The fitted exponent of each cost of one learner's curve (and of training CPU time per iteration)."""
    rows = curve_rows(records, learner, curve)
    x = [r[_size_field(curve)] for r in rows]
    out = {}
    for metric in ("train_cpu_s", "train_wall_s", "single_point_us", "rmse", "dtw_per_sample"):
        out[metric] = fit_exponent(x, [math.nan if r[metric] is None else r[metric] for r in rows])[0]
    per_it = [r["train_cpu_s"] / r["iterations"] if r.get("iterations") else math.nan for r in rows]
    out["cpu_per_iteration"] = fit_exponent(x, per_it)[0]
    return out


def _f(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def report(learner_records: list[dict[str, Any]], control_records: list[dict[str, Any]], learners: tuple[str, ...],
           options: dict[str, dict[str, Any]], control_info: dict[str, Any], figures: Path, out: Path,
           meta: dict[str, Any]) -> str:
    """The markdown of reports/scaling.md."""
    rel = os.path.relpath(figures, out.parent)
    lines = ["# Scaling curves: learners and the control step", "",
             f"Made by `{meta['command']}` ({meta['date']}; {meta['machine']}). "
             + ("**Quick mode (a smoke test): few sizes, few iterations; not a measurement.** " if meta["quick"]
                else "") +
             f"The run that wrote this report took {meta['wall_s']:.0f} s wall, {meta['measured_s']:.0f} s of "
             "it measuring (the rest: warm-up, figures, and the points it read from the cache "
             f"`{meta['cache']}`); the measurements reported here took {meta['cache_total_s']:.0f} s wall in all "
             "when they were made (imports, warm-up and figures not counted). "
             f"Load average {meta['load_start']:.1f} at the start, "
             f"{meta['load_end']:.1f} at the end, on {os.cpu_count()} CPUs: wall times are noisy, so the "
             "exponents are fitted on CPU time (training) and on medians (per-call and per-step times).", "",
             "Exponents: the least-squares slope b of log(cost) against log(size), cost ≈ c size^b, over all "
             "points of a curve (`lfd.bench.scaling.fit_exponent`).", ""]
    # ---- setup
    lines += ["## Setup", "",
              "- **Demos.** d-dimensional demos stack d/2 LASA shapes (as ELCD and CLFD build their 4-D to 32-D "
              "sets): demo i is the concatenation of demo i of each shape, each resampled in time to the common "
              "length T by a cubic spline (`lfd.bench.scaling.stacked_lasa`), all on one clock (T samples "
              "evenly over the mean duration). d = 2k uses the first k of: "
              + ", ".join(f"`{s}`" for s in STACK_SHAPES) + ". "
              "The N and T curves use `Angle` (d = 2). Every curve's other sizes are N = 7, T = 1000, d = 2.",
              "- **Training.** `lfd.train(learner, demos, seed=0)` (`lfd.bench.spaces.fit`; the DMP baseline: "
              "`lfd.bench.dmp.fit_dmp`, one DMP fitted to the mean demo), torch on one thread. Training time is "
              "CPU time (`history[\"train_cpu_s\"]`, `time.process_time` for the DMP) beside wall time; a fit "
              "under 1 s CPU is repeated (same seed, up to 5 times) and the median kept.",
              "- **Single-point time.** The median over 200 blocks of 20 calls of "
              "`field.single_point_evaluator()` cycling through 200 demo points (one `DMP.step` for the DMP, "
              "`DMPModel.step_time_us`).",
              "- **Accuracy.** The reproductions from the demos' starts (`Model.reproduce` of "
              "`lfd.bench.fields`: dopri5 at 1e-6 for NODE and contraction, RK4 on (x, s) for tracking, "
              "`DMP.step`), scored against the same demos at LASA's own 1000 samples (so every point of the T "
              "curve is scored alike): the time-aligned RMSE and the DTW distance per sample "
              "(`lfd.metrics`), per 2-D shape (each 2-D block of a stacked demo scored alone, then averaged "
              "over blocks and demos), in mm. Along d the shape set changes (d = 2 is `Angle` alone, d = 32 the "
              "mean over 16 shapes), so the accuracy curve against d mixes the learner's scaling with how hard "
              "the added shapes are.",
              "- **Noise.** This machine is shared (2 virtual CPUs, other jobs running): a per-call median can "
              "move by about 2x between points as the load changes, so exponents of flat "
              "curves (|b| below about 0.3) are within the noise; training CPU time is steadier.",
              "- **NODE's `samples` option** resamples every demo to at most "
              f"{_defaults('node').get('samples')} samples before training (its default, read at run "
              "time), so the NODE never sees more than that many samples per demo: its T curve measures the "
              "resampling, not T.", ""]
    lines += ["Options (everything else at the learner's defaults, read at run time):", "",
              "| learner | options given | default iterations |", "|---|---|---|"]
    for learner in learners:
        default = _defaults(learner).get("iterations", "–")
        given = ", ".join(f"{k}={v}" for k, v in options[learner].items()) or "none (defaults)"
        lines.append(f"| {learner} | {given} | {default} |")
    reduced = [n for n in learners if options[n].get("iterations")]
    if reduced:
        lines += ["", "**Fewer iterations than the default:** " + "; ".join(
            f"{n} trained with {options[n]['iterations']} iterations (default "
            f"{_defaults(n).get('iterations')})" for n in reduced)
            + (", for a smoke test." if meta["quick"] else ", to keep the full run within about 15 minutes on "
               "this machine.")
            + " Its training time is that of the shorter training (time per iteration is what the curve "
            "measures; the exponent of CPU time per iteration is given too), and its accuracy is not that of "
            "a default training.", ""]
    # ---- summary
    lines += ["## Exponents", "", "| learner | curve | training CPU | training CPU / iteration | training wall | "
              "single point | RMSE | DTW / sample |", "|---|---|---|---|---|---|---|---|"]
    ex: dict[tuple[str, str], dict[str, float]] = {}
    for learner in learners:
        for curve in CURVES:
            e = ex[(learner, curve)] = exponents(learner_records, learner, curve)
            lines.append(f"| {learner} | {CURVES[curve][0]} | {_f(e['train_cpu_s'], 2)} | "
                         f"{_f(e['cpu_per_iteration'], 2)} | {_f(e['train_wall_s'], 2)} | "
                         f"{_f(e['single_point_us'], 2)} | {_f(e['rmse'], 2)} | {_f(e['dtw_per_sample'], 2)} |")
    lines += ["", "### Target: training time of contraction and tracking against d grows at most linearly", "",
              f"Fitted exponent of training CPU time against d = 2..32 must be ≤ {TARGET_EXPONENT}:", ""]
    for learner in TARGET_LEARNERS:
        if learner in learners:
            b = ex[(learner, "dim")]["train_cpu_s"]
            verdict = "MET" if b <= TARGET_EXPONENT else "NOT MET"
            lines.append(f"- {learner}: {_f(b, 3)} — **{verdict}**")
    if meta.get("findings"):
        lines += ["", meta["findings"]]
    lines.append("")
    # ---- per curve
    for curve, (symbol, _) in CURVES.items():
        lines += [f"## Against {_curve_title(curve)}", "",
                  f"![{curve}]({rel}/scaling_{curve}.png)", "",
                  f"| learner | {symbol} | training CPU s | training wall s | fits | single point µs | RMSE mm | "
                  "DTW / sample mm | iterations |", "|---|---|---|---|---|---|---|---|---|"]
        for learner in learners:
            for r in curve_rows(learner_records, learner, curve):
                lines.append(f"| {learner} | {r[_size_field(curve)]} | {_f(r['train_cpu_s'])} | "
                             f"{_f(r['train_wall_s'])} | {r.get('fits', 1)} | {_f(r['single_point_us'])} | "
                             f"{_f(r['rmse'])} | {_f(r['dtw_per_sample'])} | {_f(r.get('iterations'))} |")
            e = ex[(learner, curve)]
            lines.append(f"| **{learner} exponent** | | **{_f(e['train_cpu_s'], 2)}** | {_f(e['train_wall_s'], 2)} | | "
                         f"**{_f(e['single_point_us'], 2)}** | **{_f(e['rmse'], 2)}** | "
                         f"{_f(e['dtw_per_sample'], 2)} | |")
        lines.append("")
    # ---- control
    if control_records:
        lines += ["## Control step against the number of obstacles and the robot", "",
                  f"![control]({rel}/scaling_control.png)", "",
                  f"The closed loop at 500 Hz (`sim.Experiment.simulate`, `RunTrace.step_time_s`) of a "
                  f"{control_info['learner']} field trained on {control_info['demos']} with its defaults, torque "
                  "actuation, on each robot with K spheres (radius 5 % of the demos' extent) off the path: on a "
                  "grid of 4 rows on the far side of the demos from the robot's base "
                  "(`sim.studies.scaling_control.off_path_spheres`), so the tool never comes near them. "
                  "As a job runs obstacles: "
                  "the field avoids them (`lfd.avoid`, grown by the hand's margin), the IK carries the whole-arm "
                  "dampers (`sim.scene.collision.Clearance()`, given for K = 0 too) and the servo leads by "
                  "`OBSTACLE_LEAD_S`. *plain*: the loop of a job without obstacles (no dampers, plain field). "
                  f"Per point: one warm-up run, then {control_records[0]['repeats']} runs of "
                  f"{control_records[0]['steps']} steps, each followed by as many bare `mj_step` calls of the "
                  "same compiled model (obstacles included) at rest at the run's start (interleaved, as "
                  "`scripts/speed.py loop` does); a robot's points are run round-robin, one run of each per "
                  "round, so a change of the machine's load hits them alike. Step: median of every timed step "
                  "(wall, the loop's own timer); CPU/step: the run's thread CPU time per step; ratio: median "
                  "step / median bare step; CPU ratio: the same in CPU time; field alone: the median "
                  "single-point time of the (avoiding) field the loop calls, timed "
                  "alone; max deviation: the largest distance of the tool path from that of the same robot's "
                  "K = 0 run (runs comparable when it is small). A bare `mj_step` takes a few µs, so the ratios "
                  "move with every µs of machine noise; the CPU ratio (CPU time over whole runs) is the steadier "
                  "one.", "",
                  "| robot | K | step µs (median) | p95 µs | CPU µs / step | bare mj_step µs | ratio | CPU ratio | "
                  "field alone µs | max deviation mm | goal error mm |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        fits = []
        for robot in dict.fromkeys(r["robot"] for r in control_records):
            rows = [r for r in control_records if r["robot"] == robot]
            rows.sort(key=lambda r: (r["dampers"], r["count"]))
            for r in rows:
                count = f"{r['count']}" if r["dampers"] else "0 (plain)"
                dev = r.get("max_deviation_m")
                lines.append(f"| {robot} | {count} | {r['step_us']:.1f} | {r['step_p95_us']:.1f} | "
                             f"{r['step_cpu_us']:.1f} | {r['bare_us']:.1f} | {r['ratio']:.2f} | {r['cpu_ratio']:.2f} | "
                             f"{r['field_us']:.1f} | {_f(None if dev is None else dev * 1e3)} | "
                             f"{r['final_goal_error_m'] * 1e3:.2f} |")
            damped = [r for r in rows if r["dampers"]]
            k = [r["count"] for r in damped]
            b, _ = fit_exponent(k, [r["step_us"] for r in damped])
            b_cpu, _ = fit_exponent(k, [r["step_cpu_us"] for r in damped])
            b_ratio, _ = fit_exponent(k, [r["ratio"] for r in damped])
            slope = float(np.polyfit(k, [r["step_us"] for r in damped], 1)[0]) if len(k) > 1 else math.nan
            fits.append(f"| {robot} | {_f(b, 2)} | {_f(b_cpu, 2)} | {_f(b_ratio, 2)} | {_f(slope, 3)} |")
        lines += ["", "Fitted over K = 1..16 (K = 0 has no logarithm; the linear slope uses K = 0..16):", "",
                  "| robot | exponent, step median | exponent, CPU / step | exponent, ratio | µs per obstacle "
                  "(linear slope) |", "|---|---|---|---|---|", *fits, ""]
    return "\n".join(lines) + "\n"


