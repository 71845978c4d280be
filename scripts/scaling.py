#!/usr/bin/env python
"""Scaling curves in one report: the learners' training time, single-point time and accuracy against
the dimension, the number of demos and the samples per demo, and the control step's cost against the
number of obstacles and the robot; writes reports/scaling.md and reports/figures/scaling_*.png.

    .venv/bin/python scripts/scaling.py --out reports/scaling.md     # the full run
    .venv/bin/python scripts/scaling.py --quick                      # a smoke test (out/scaling-quick/)

Learner curves (``lfd.bench.scaling``): each learner trained with ``lfd.train(learner, demos, seed=0)``
(the DMP baseline with ``lfd.bench.dmp.fit_dmp``), its default options except where ``--iterations``
says otherwise (the default gives the NODE a tenth of its default iterations; the report states it),
on LASA shapes stacked into d = 2..32 dimensions, on 1..7 demos and on 250..4000 samples per demo.
Control-step curves (``sim.scaling``): a contraction field on the planar arm, the Panda and a URDF arm
(the UR5 of example-robot-data) with 0..16 spheres off the path, against a bare ``mj_step``.

Every measurement is cached as one JSON file under ``--cache`` (default out/scaling, written atomically
with a key of what it depends on), so an interrupted run resumes where it stopped. Progress bars on a
terminal only. Bad options: one line on stderr, exit 2; Ctrl-C: exit 130.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__)

import argparse
import dataclasses
import hashlib
import json
import math
import platform
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MUJOCO_GL", "egl")
# imported before main with interrupts deferred (lfd.interrupts.run_script)
PRELOAD = ("numpy", "sim", "robots", "lfd.learners", "lfd.cache", "lfd.io", "lfd.bench.scaling", "lfd.bench.evaluate")

PROG = "scaling"
ALL_LEARNERS = ("node", "contraction", "tracking", "dmp")
CONTROL_LEARNER = "contraction"
CONTROL_FORMAT = 3
TARGET_EXPONENT = 1.1
TARGET_LEARNERS = ("contraction", "tracking")
#: the quick mode's sizes, iterations and control points
QUICK = {"dim": (2, 4), "demos": (1, 7), "samples": (250, 1000)}
QUICK_ITERATIONS = {"node": 20, "contraction": 10}
QUICK_COUNTS = (0, 1, 2)
#: what the figures call each cost
METRIC_LABELS = {"train_cpu_s": "training CPU time (s)", "single_point_us": "single-point evaluation (µs)",
                 "rmse": "reproduction RMSE per shape (mm)"}


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{PROG}: error: {message} (see --help)\n")


def fail(message: str) -> int:
    """Print ``scaling: error: message`` on stderr; return 2."""
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def parse_iterations(text: str, learners: tuple[str, ...]) -> dict[str, str]:
    """``node=/10,contraction=50`` -> {"node": "/10", "contraction": "50"}; ValueError on bad text."""
    out: dict[str, str] = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, value = part.partition("=")
        if not sep or name not in ALL_LEARNERS or name == "dmp":
            raise ValueError(f"--iterations: '{part}' is not LEARNER=N or LEARNER=/K (learners: node, contraction)")
        if name == "tracking":
            raise ValueError("--iterations: the tracking learner has no iterations")
        v = value[1:] if value.startswith("/") else value
        if not v.isdigit() or int(v) < 1 or int(v) > 10**6:
            raise ValueError(f"--iterations: '{value}' is not a positive integer or /K")
        out[name] = value
    return out


def learner_options(learners: tuple[str, ...], iterations: dict[str, str]) -> dict[str, dict[str, Any]]:
    """Each learner's options: {} (its defaults) or {"iterations": n}, n from ``iterations`` (a number, or
    /K: the learner's default, read from its config now, divided by K)."""
    import lfd

    out: dict[str, dict[str, Any]] = {}
    for name in learners:
        if name not in iterations:
            out[name] = {}
            continue
        value = iterations[name]
        if value.startswith("/"):
            default = int(lfd.get_learner(name).make_config().iterations)
            out[name] = {"iterations": max(1, default // int(value[1:]))}
        else:
            out[name] = {"iterations": int(value)}
    return out


def default_config(learner: str) -> dict[str, Any]:
    """The learner's default options, read now (the DMP's from ``lfd.bench.dmp``)."""
    if learner == "dmp":
        from lfd.bench.dmp import make_config

        return dataclasses.asdict(make_config())
    import lfd

    return dataclasses.asdict(lfd.get_learner(learner).make_config())


def warm_up(learners: tuple[str, ...]) -> None:
    """One-off imports and compilations out of the timed fits: torch's optimizers import torch._dynamo
    on first use; one tiny fit per learner loads the rest (numba kernels included)."""
    import warnings

    import torch._dynamo  # noqa: F401

    from lfd.bench.evaluate import fit
    from lfd.bench.scaling import stacked_lasa
    from lfd.threads import torch_threads

    demos = stacked_lasa(2, 2, 100)
    tiny = {"node": {"iterations": 2}, "contraction": {"iterations": 2}}
    with warnings.catch_warnings(), torch_threads(1):
        warnings.simplefilter("ignore")
        for name in learners:
            model = fit(name, demos, 0, tiny.get(name, {}))
            if hasattr(model, "field"):
                model.field.single_point_evaluator()(demos.x[0, 0])


# ---------------------------------------------------------------- learner curves

def learner_curves(learners: tuple[str, ...], options: dict[str, dict[str, Any]], cache: Path,
                   sizes: dict[str, tuple[int, ...]] | None, progress: bool) -> tuple[list[dict[str, Any]], float]:
    """Measure (or read) every point of every learner's three curves; returns the records (with a
    ``curves`` list of the curves each belongs to) and the wall time spent measuring now."""
    from tqdm.auto import tqdm

    from lfd.bench.scaling import CURVES, cached_measure, curve_points

    points: dict[Any, list[str]] = {}
    for learner in learners:
        for curve in CURVES:
            for p in curve_points(learner, curve, options[learner], None if sizes is None else sizes[curve]):
                points.setdefault(p, []).append(curve)
    todo = [p for p in points if not _cached(p, cache)]
    if todo:
        warm_up(tuple(dict.fromkeys(p.learner for p in todo)))
    records = []
    spent = 0.0
    bar = tqdm(total=len(points), desc="learners", unit="point", disable=not progress)
    for p, curves in points.items():
        bar.set_postfix_str(p.stem)
        t0 = time.perf_counter()
        rec, new = cached_measure(p, cache)
        if new:
            spent += time.perf_counter() - t0
        records.append({**rec, "curves": curves})
        bar.update(1)
    bar.close()
    return records, spent


def _cached(point: Any, cache: Path) -> bool:
    path = cache / f"{point.stem}.json"
    try:
        return bool(json.loads(path.read_text()).get("key") == point.key())
    except (OSError, ValueError):
        return False


# ---------------------------------------------------------------- control-step curves

def control_key(robot: Any, counts: tuple[int, ...], repeats: int, field_file: str) -> str:
    """A hash of what one robot's control points depend on."""
    spec = {"format": CONTROL_FORMAT, "robot": dataclasses.asdict(robot), "counts": list(counts),
            "repeats": repeats, "field": field_file}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def control_curves(counts: tuple[int, ...], robots: tuple[Any, ...], repeats: int, cache: Path,
                   progress: bool) -> tuple[list[dict[str, Any]], float, dict[str, Any]]:
    """Measure (or read) the control step of every robot at every obstacle count, and each robot's plain
    loop (no obstacles, no dampers), one cached file per robot (``sim.scaling.measure_control``); returns
    the records, the wall time spent measuring now and a description of the field and demos."""
    from tqdm.auto import tqdm

    import lfd
    from lfd.cache import cached_field
    from lfd.io import write_json
    from sim.scaling import load_scaling_robot, measure_control

    demos = lfd.spiral()
    field, model_file, _ = cached_field(CONTROL_LEARNER, demos, 0, {}, verbose=False)
    info = {"learner": CONTROL_LEARNER, "demos": "lfd.spiral() (5 demos, 200 samples, 5 s)",
            "model_file": model_file.name}
    records: list[dict[str, Any]] = []
    spent = 0.0
    bar = tqdm(total=len(robots), desc="control", unit="robot", disable=not progress)
    for robot_spec in robots:
        bar.set_postfix_str(robot_spec.name)
        path = cache / "control" / f"{robot_spec.name.split()[0]}.json"
        key = control_key(robot_spec, counts, repeats, model_file.name)
        rec = _read(path, key)
        if rec is None:
            t0 = time.perf_counter()
            points = measure_control(load_scaling_robot(robot_spec), demos, field, counts, repeats)
            rec = {"key": key, "robot": robot_spec.name, "points": points, "elapsed_s": time.perf_counter() - t0}
            write_json(path, rec)
            spent += rec["elapsed_s"]
        records += [{"robot": rec["robot"], **p} for p in rec["points"]]
        records[-1]["elapsed_s"] = rec["elapsed_s"]   # counted once per robot
        bar.update(1)
    bar.close()
    return records, spent, info


def _read(path: Path, key: str) -> dict[str, Any] | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rec if rec.get("key") == key else None


# ---------------------------------------------------------------- profiles

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
PROFILE_ITERATIONS = 10


def profile_targets(records: list[dict[str, Any]], learners: tuple[str, ...], options: dict[str, dict[str, Any]],
                    cache: Path, dims: tuple[int, ...] | None, progress: bool) -> tuple[str, float, float]:
    """For each target learner whose training-time exponent against d exceeds ``TARGET_EXPONENT``: a
    profile of its training (``lfd.bench.scaling.profile_fit``, at most ``PROFILE_ITERATIONS`` iterations)
    at the smallest and the largest d, cached; returns the report's text, the wall time spent now and the
    wall time the profiles took when they were made."""
    from lfd.bench.scaling import DIMS, profile_fit, stacked_lasa
    from lfd.io import write_json

    dims = dims or DIMS
    lo, hi = min(dims), max(dims)
    parts, spent, took = [], 0.0, 0.0
    for learner in TARGET_LEARNERS:
        if learner not in learners:
            continue
        b = exponents(records, learner, "dim")["train_cpu_s"]
        if not b > TARGET_EXPONENT:
            continue
        opts = dict(options[learner])
        if "iterations" in default_config(learner):
            default = opts.get("iterations", default_config(learner)["iterations"])
            opts["iterations"] = min(int(default), PROFILE_ITERATIONS)
        prof = {}
        for d in (lo, hi):
            path = cache / f"profile_{learner}_d{d}.json"
            key = hashlib.sha256(json.dumps({"v": 1, "learner": learner, "d": d, "options": opts},
                                            sort_keys=True).encode()).hexdigest()[:16]
            rec = _read(path, key)
            if rec is None:
                if progress:
                    print(f"{PROG}: profiling {learner} at d = {d}", file=sys.stderr)
                t0 = time.perf_counter()
                rec = {"key": key, **profile_fit(learner, stacked_lasa(d), opts)}
                rec["elapsed_s"] = time.perf_counter() - t0
                write_json(path, rec)
                spent += rec["elapsed_s"]
            prof[d] = rec
        parts.append(findings_text(learner, b, prof[lo], prof[hi], lo, hi, opts))
        took += sum(float(p.get("elapsed_s", 0.0)) for p in prof.values())
    return "\n\n".join(parts), spent, took


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from lfd.bench.scaling import CURVES, fit_exponent
    from lfd.io import atomic_path

    symbol, _ = CURVES[curve]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
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
        ax.get_xaxis().set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, title="learner (exponent)", title_fontsize=8)
    fig.suptitle(f"against {_curve_title(curve)} (dotted: the least-squares power law)")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def control_figure(records: list[dict[str, Any]], path: Path) -> None:
    """Per-step median (µs) and its ratio to a bare mj_step against the obstacle count, a line per robot
    (K = 0 drawn at 0.5 on the log axis; the plain loop as a cross there)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from lfd.bench.scaling import fit_exponent
    from lfd.io import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
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
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("spheres in the scene, K (x: no obstacles, no dampers)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, title="robot (exponent, K = 1..16)", title_fontsize=8)
    fig.suptitle("closed-loop control step at 500 Hz against the number of obstacles")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------- report

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
    from lfd.bench.scaling import fit_exponent

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
    from lfd.bench.scaling import CURVES, STACK_SHAPES

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
              "- **Training.** `lfd.train(learner, demos, seed=0)` (`lfd.bench.evaluate.fit`; the DMP baseline: "
              "`lfd.bench.dmp.fit_dmp`, one DMP fitted to the mean demo), torch on one thread. Training time is "
              "CPU time (`history[\"train_cpu_s\"]`, `time.process_time` for the DMP) beside wall time; a fit "
              "under 1 s CPU is repeated (same seed, up to 5 times) and the median kept.",
              "- **Single-point time.** The median over 200 blocks of 20 calls of "
              "`field.single_point_evaluator()` cycling through 200 demo points (one `DMP.step` for the DMP, "
              "`DMPModel.step_time_us`).",
              "- **Accuracy.** The reproductions from the demos' starts (`Model.reproduce` of "
              "`lfd.bench.evaluate`: dopri5 at 1e-6 for NODE and contraction, RK4 on (x, s) for tracking, "
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
              f"{default_config('node').get('samples')} samples before training (its default, read at run "
              "time), so the NODE never sees more than that many samples per demo: its T curve measures the "
              "resampling, not T.", ""]
    lines += ["Options (everything else at the learner's defaults, read at run time):", "",
              "| learner | options given | default iterations |", "|---|---|---|"]
    for learner in learners:
        default = default_config(learner).get("iterations", "–")
        given = ", ".join(f"{k}={v}" for k, v in options[learner].items()) or "none (defaults)"
        lines.append(f"| {learner} | {given} | {default} |")
    reduced = [n for n in learners if options[n].get("iterations")]
    if reduced:
        lines += ["", "**Fewer iterations than the default:** " + "; ".join(
            f"{n} trained with {options[n]['iterations']} iterations (default "
            f"{default_config(n).get('iterations')})" for n in reduced)
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
                  "(`sim.scaling.off_path_spheres`), so the tool never comes near them. As a job runs obstacles: "
                  "the field avoids them (`lfd.avoid`, grown by the hand's margin), the IK carries the whole-arm "
                  "dampers (`sim.collision.Clearance()`, given for K = 0 too) and the servo leads by "
                  "`OBSTACLE_LEAD_S`. *plain*: the loop of a job without obstacles (no dampers, plain field). "
                  f"Per point: one warm-up run, then {control_records[0]['repeats']} runs of "
                  f"{control_records[0]['steps']} steps, each followed by as many bare `mj_step` calls of the "
                  "same compiled model (obstacles included) at rest at the run's start (interleaved, as "
                  "`scripts/speed_loop.py` does); a robot's points are run round-robin, one run of each per "
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
        from lfd.bench.scaling import fit_exponent

        fits = []
        for robot in dict.fromkeys(r["robot"] for r in control_records):
            rows = [r for r in control_records if r["robot"] == robot]
            rows.sort(key=lambda r: (r["dampers"], r["count"]))
            for r in rows:
                k = f"{r['count']}" if r["dampers"] else "0 (plain)"
                dev = r.get("max_deviation_m")
                lines.append(f"| {robot} | {k} | {r['step_us']:.1f} | {r['step_p95_us']:.1f} | "
                             f"{r['step_cpu_us']:.1f} | {r['bare_us']:.1f} | {r['ratio']:.2f} | {r['cpu_ratio']:.2f} | "
                             f"{r['field_us']:.1f} | {_f(None if dev is None else dev * 1e3)} | "
                             f"{r['final_goal_error_m'] * 1e3:.2f} |")
            curve = [r for r in rows if r["dampers"]]
            k = [r["count"] for r in curve]
            b, _ = fit_exponent(k, [r["step_us"] for r in curve])
            b_cpu, _ = fit_exponent(k, [r["step_cpu_us"] for r in curve])
            b_ratio, _ = fit_exponent(k, [r["ratio"] for r in curve])
            import numpy as np

            slope = float(np.polyfit(k, [r["step_us"] for r in curve], 1)[0]) if len(k) > 1 else math.nan
            fits.append(f"| {robot} | {_f(b, 2)} | {_f(b_cpu, 2)} | {_f(b_ratio, 2)} | {_f(slope, 3)} |")
        lines += ["", "Fitted over K = 1..16 (K = 0 has no logarithm; the linear slope uses K = 0..16):", "",
                  "| robot | exponent, step median | exponent, CPU / step | exponent, ratio | µs per obstacle "
                  "(linear slope) |", "|---|---|---|---|---|", *fits, ""]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- main

def main(argv: list[str] | None = None) -> int:
    ap = _Parser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="the report (default reports/scaling.md; with --quick "
                                  "out/scaling-quick/scaling.md)")
    ap.add_argument("--figures", help="folder of the PNGs (default: figures/ beside the report)")
    ap.add_argument("--cache", help="folder of the cached measurements (default out/scaling; with --quick "
                                    "out/scaling-quick)")
    ap.add_argument("--quick", action="store_true", help="a smoke test: two sizes per curve, few iterations, "
                                                         "the planar arm with 0-2 obstacles")
    ap.add_argument("--learners", default=",".join(ALL_LEARNERS), help="comma-separated, of node, contraction, "
                                                                        "tracking, dmp")
    ap.add_argument("--iterations", default="node=/10",
                    help="LEARNER=N or LEARNER=/K (the default divided by K), comma-separated; others train "
                         "with their defaults (default: node=/10; '' trains every learner with its defaults)")
    ap.add_argument("--repeats", type=int, default=5, help="timed rounds of the control points (default 5)")
    ap.add_argument("--skip-learners", action="store_true", help="only the control-step curves")
    ap.add_argument("--skip-control", action="store_true", help="only the learner curves")
    args = ap.parse_args(argv)
    learners = tuple(s.strip() for s in args.learners.split(",") if s.strip())
    bad = [s for s in learners if s not in ALL_LEARNERS]
    if bad or not learners:
        return fail(f"--learners: unknown learner(s) {', '.join(bad) or '(none given)'}; known: "
                    f"{', '.join(ALL_LEARNERS)}")
    if not 1 <= args.repeats <= 100:
        return fail("--repeats must be between 1 and 100")
    if args.skip_learners and args.skip_control:
        return fail("--skip-learners and --skip-control leave nothing to do")
    try:
        iterations = parse_iterations(QUICK_ITERATIONS_TEXT if args.quick else args.iterations, learners)
    except ValueError as e:
        return fail(str(e))
    quick_dir = ROOT / "out" / "scaling-quick"
    out = Path(args.out) if args.out else (quick_dir / "scaling.md" if args.quick else ROOT / "reports" / "scaling.md")
    figures = Path(args.figures) if args.figures else out.parent / "figures"
    cache = Path(args.cache) if args.cache else (quick_dir if args.quick else ROOT / "out" / "scaling")
    from lfd.io import check_writable

    try:
        for p in (out, figures / "scaling_dim.png", cache / "probe.json"):
            check_writable(p)
    except (OSError, ValueError) as e:
        return fail(str(e))
    progress = sys.stderr.isatty()
    t_start = time.perf_counter()
    load_start = os.getloadavg()[0]
    from lfd.errors import LfdError
    from robots import RobotError
    from sim.errors import SimError

    try:
        options = learner_options(learners, iterations)
        learner_records: list[dict[str, Any]] = []
        control_records: list[dict[str, Any]] = []
        control_info: dict[str, Any] = {}
        measured = 0.0
        if not args.skip_learners:
            learner_records, spent = learner_curves(learners, options, cache, QUICK if args.quick else None,
                                                    progress)
            measured += spent
        if not args.skip_control:
            from sim.scaling import OBSTACLE_COUNTS, ROBOTS

            counts = QUICK_COUNTS if args.quick else OBSTACLE_COUNTS
            robots = ROBOTS[:1] if args.quick else ROBOTS
            control_records, spent, control_info = control_curves(counts, robots, 1 if args.quick else args.repeats,
                                                                  cache, progress)
            measured += spent
    except (LfdError, RobotError, SimError) as e:
        return fail(str(e).splitlines()[0])
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    learners_done = tuple(n for n in learners if any(r["learner"] == n for r in learner_records))
    if learner_records:
        from lfd.bench.scaling import CURVES

        for curve in CURVES:
            learner_figure(learner_records, curve, learners_done, figures / f"scaling_{curve}.png")
    if control_records:
        control_figure(control_records, figures / "scaling_control.png")
    findings, profiles_s = "", 0.0
    if learner_records:
        try:
            findings, spent, profiles_s = profile_targets(learner_records, learners_done, options, cache,
                                              QUICK["dim"] if args.quick else None, progress)
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted", file=sys.stderr)
            return 130
        measured += spent
    meta = {"command": "scripts/scaling.py" + (" --quick" if args.quick else "") + (f" --out {args.out}" if args.out
                                                                                    else ""),
            "date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()}, Python {platform.python_version()}",
            "quick": args.quick, "wall_s": time.perf_counter() - t_start, "measured_s": measured,
            "cache": os.path.relpath(cache, ROOT) if cache.is_relative_to(ROOT) else str(cache),
            "cache_total_s": sum(float(r.get("elapsed_s", 0.0)) for r in learner_records + control_records)
            + profiles_s,
            "load_start": load_start, "load_end": os.getloadavg()[0], "findings": findings}
    text = report(learner_records, control_records, learners_done, options, control_info, figures, out, meta)
    from lfd.io import atomic_write

    atomic_write(out, lambda f: f.write(text.encode()))
    print(f"wrote {out} ({meta['wall_s']:.0f} s)")
    return 0


QUICK_ITERATIONS_TEXT = ",".join(f"{k}={v}" for k, v in QUICK_ITERATIONS.items())
