"""One line between the paper's two methods: every learner on accuracy against recovery from a push,
and the contracting NODE's trade-off over its rate; writes reports/contracting_node.md and its figure.
Run by ``scripts/recovery_tradeoff.py``.

Part 1, the default job (the spiral on the torque-driven Panda, ``scripts/demo_arm.py``'s defaults, 20 N
for 0.2 s on the hand): every learner and the DMP, unpushed and pushed; per learner the DTW to the demo,
the goal error, the push's largest deviation and the recovery time (``sim.metrics``: back within 5 mm of
the unpushed run for good), and what it states (the contraction rate and sqrt(b/a), or a Lyapunov rate).
Part 2: the contracting NODE trained on the same demos at rates ``RATES`` (1/s) and at its default rate,
the same two runs each. Part 3: LASA's held-out and in-sample mean DTW per learner, read from the
suite's result files (``LASA_RESULTS``). Part 4: the contracting NODE on ``SHAPES`` (LASA, in-sample) through
``lfd.certify`` (the theorem's conditions from the weights, Eq. (C1) on the grid, Eq. (18) with its constant
sampled on the box and 1000 box sizes away, the equilibria search). The figure puts parts 1 and 2 on the
arm's DTW against recovery, and part 1 on LASA's held-out DTW against recovery. Each finished row is
recorded in ``OUT``/records.json (written whole, atomically); a rerun takes the rows recorded there
unless ``--fresh``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import ScalarFormatter  # noqa: E402

import lfd  # noqa: E402
import sim  # noqa: E402
from lfd.errors import LfdError  # noqa: E402
from lfd.io import atomic_write, check_writable, write_json  # noqa: E402
from robots import RobotError  # noqa: E402
from sim.errors import SimError  # noqa: E402
from sim.run.parsing import OneLineParser, fail  # noqa: E402

__all__ = ["main"]

PROG = "recovery_tradeoff"
PRELOAD = ("sim.run.pipeline",)
LEARNERS = ("node", "stable_node", "contraction", "contracting_node", "tracking", "dmp")
RATES = (0.25, 0.5, 1.0, 2.0, 4.0)
LASA_RESULTS = ("reports/lasa_results.json", "reports/lasa_contracting_node.json")
OUT = "out/recovery"
SHAPES = ("Angle", "GShape", "Snake", "JShape_2", "DoubleBendedLine", "Multi_Models_4")


def _job(out: str, **options: Any) -> tuple[dict[str, dict[str, Any]], Any]:
    """({scenario: metrics}, its field or None) of one learner's unpushed and pushed runs of the default job."""
    job = sim.ArmJob(scenarios=("none", "push"), videos=False, plots=False, quiet=True, overwrite=True,
                     out=f"{OUT}/{out}", **options)
    report = sim.run_job(job)
    (entry,) = report.models.values() if report.models else ({"path": None},)
    path = entry.get("path")
    field = lfd.load(str(path)) if path else None
    return {r.scenario: r.metrics for r in report.results}, field


def _records(fresh: bool) -> dict[str, Any]:
    path = Path(OUT) / "records.json"
    if fresh or not path.is_file():
        return {}
    try:
        return dict(json.loads(path.read_text()))
    except (ValueError, TypeError):
        return {}


def _record(records: dict[str, Any], key: str, value: Any) -> None:
    records[key] = value
    write_json(Path(OUT) / "records.json", records, indent=1)


def _certified(shape: str) -> str:
    """Part 4's row for one LASA shape."""
    from lfd.certify import certify

    field = lfd.train("contracting_node", lfd.load_demos(f"lasa:{shape}"), seed=0, progress=False)
    c = certify(field)
    g, k = c.growth or {}, c.structural or {}
    eq = c.equilibria
    return (f"| {shape} | {c.verdict} | {field.rate:.3g} | {k.get('flow_ratio', math.nan):.4g} | "
            f"{g.get('worst_near', math.nan):.4g} | {g.get('worst_far', math.nan):.4g} | "
            f"{c.worst:.4g} / {c.bound:.4g} | "
            f"{'-' if eq is None else f'{100 * eq.goal_fraction:.1f}%'} |")


def _stated(field: Any) -> str:
    """What a field states about its convergence, in one cell."""
    if field is None:
        return "a spring-damper once its phase decays"
    lyap = field.stability_constants()
    if lyap is not None:
        return f"Lyapunov, rate {lyap['rate']:.3g}/s"
    bounds = field.metric_bounds
    if field.rate is not None and bounds is not None:
        return f"contraction {field.rate:.3g}/s, sqrt(b/a) {math.sqrt(bounds[1] / bounds[0]):.3g}"
    return "nothing"


def _row(label: str, runs: dict[str, dict[str, Any]], stated: str) -> tuple[str, dict[str, Any]]:
    none, push = runs["none"], runs["push"]
    rec = push.get("recovery_time_s")
    cells = {"dtw_mm": 1e3 * none["imitation_dtw_m"], "recovery_s": rec}
    text = (f"| {label} | {1e3 * none['imitation_dtw_m']:.2f} | {1e3 * none['final_goal_error_m']:.2f} | "
            f"{1e3 * push['max_deviation_m']:.2f} | {'never' if rec is None else f'{rec:.2f}'} | "
            f"{1e3 * push['final_goal_error_m']:.2f} | {stated} |")
    return text, cells


def _reading(points: dict[str, dict[str, Any]], held_out: dict[str, float]) -> list[str]:
    """The report's reading, from the measured rows."""
    def rec(name: str) -> str:
        r = points[name]["recovery_s"]
        return "never" if r is None else f"{r:.2f} s"

    cn, gc = "contracting_node", "contraction"
    lines = [f"On the default job the contracting NODE recovers from the push in {rec(cn)}, against {rec(gc)} for "
             f"the goal contraction, {rec('node')} for the NODE, {rec('stable_node')} for the stable NODE and "
             f"{rec('tracking')} for the time-indexed tracking learner; its DTW to the demo is "
             f"{points[cn]['dtw_mm']:.2f} mm against {points[gc]['dtw_mm']:.2f} mm (goal contraction) and "
             f"{points['node']['dtw_mm']:.2f} mm (NODE)."]
    if cn in held_out and gc in held_out:
        lines.append(f"On LASA held out its mean DTW is {held_out[cn]:.0f} against {held_out[gc]:.0f} (goal "
                     f"contraction) and {held_out.get('tracking', math.nan):.0f} (tracking): it does not dominate "
                     "the goal contraction, which therefore stays. Both are bound by the same construction: "
                     "a contracting field cannot accelerate from rest or let neighbouring paths part by more "
                     "than sqrt(b/a), so loops and back-turns (heee, WShape, DoubleBendedLine) are cut short "
                     "(docs/equations.md, \"What the construction costs\").")
    return lines


def _lasa() -> tuple[list[str], dict[str, float]]:
    """Part 3's rows from the suite's result files (mean over the shapes, DTW in mm), and
    {learner: held-out mean DTW}."""
    rows, held_out = [], {}
    for path in LASA_RESULTS:
        if not Path(path).is_file():
            continue
        summary = json.loads(Path(path).read_text())["summary"]
        for learner, s in summary.items():
            ins, out = s["in-sample"]["metrics"]["dtw"]["mean"], s.get("held-out", {}).get("metrics", {})
            held = out.get("dtw", {}).get("mean") if out else None
            if held is not None:
                held_out[learner] = float(held)
            rows.append(f"| {learner} | {ins:.0f} | {'-' if held is None else f'{held:.0f}'} | "
                        f"{100 * s['in-sample']['converged']['mean']:.1f}% | {Path(path).name} |")
    return rows, held_out


def _figure(points: dict[str, dict[str, Any]], curve: list[tuple[float, dict[str, Any]]],
            held_out: dict[str, float], path: Path) -> None:
    """Left: the arm's DTW against recovery, every learner and the rate curve; right: LASA's held-out DTW
    against the same recovery. A run that never recovered is drawn at the top, marked."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    never = 1.1 * max(float(c["recovery_s"] or 0.0) for c in [*points.values(), *(c for _, c in curve)])

    def y(c: dict[str, Any]) -> float:
        return never if c["recovery_s"] is None else float(c["recovery_s"])

    for ax, xs in ((axes[0], {k: c["dtw_mm"] for k, c in points.items()}), (axes[1], held_out)):
        for name, x in xs.items():
            if name not in points:
                continue
            i = LEARNERS.index(name) if name in LEARNERS else len(LEARNERS)
            ax.scatter(x, y(points[name]), s=60, zorder=3, color=f"C{i}")
            ax.annotate(name, (x, y(points[name])), textcoords="offset points", xytext=(7, 7 if i % 2 else -12),
                        fontsize=9)
        ax.axhline(0.3, color="tab:red", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_formatter(ScalarFormatter())
        ax.set_ylabel("recovery after a 20 N push on the arm, s (log)")
        ax.grid(alpha=0.3, which="both")
    ax0 = axes[0]
    ax0.plot([c["dtw_mm"] for _, c in curve], [y(c) for _, c in curve], "k.--", lw=1, zorder=2,
             label="contracting NODE over its rate (1/s)")
    shown: list[float] = []
    for k, (rate, c) in enumerate(curve):
        if any(abs(rate - r) <= 0.1 * r for r in shown):     # the default next to a listed rate: one label
            continue
        shown.append(rate)
        ax0.annotate(f"{rate:.3g}", (c["dtw_mm"], y(c)), textcoords="offset points",
                     xytext=(-4, -14 if k % 2 else 8), fontsize=8, color="0.3")
    ax0.text(ax0.get_xlim()[1], 0.3, "target 0.3 s ", color="tab:red", va="bottom", ha="right", fontsize=8)
    ax0.legend(loc="upper right", fontsize=8)
    ax0.set_xlabel("imitation DTW on the arm (spiral), mm")
    ax0.set_title("The default job: accuracy against recovery")
    axes[1].set_xlabel("LASA, 30 shapes, held-out mean DTW (sum, mm)")
    axes[1].set_title("Held-out accuracy against the same recovery")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=110))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the parts of the module docstring and write the report; returns the exit code."""
    p = OneLineParser(prog=PROG, description=" ".join((__doc__ or "").split("\n\n")[0].split()))
    p.add_argument("--report", default="reports/contracting_node.md",
                   help="the report (default reports/contracting_node.md); its figure beside it in figures/")
    p.add_argument("--fresh", action="store_true", help="recompute every row (default: take recorded ones)")
    args = p.parse_args(argv)
    report = Path(args.report)
    figure = report.parent / "figures" / f"{report.stem}_tradeoff.png"
    try:
        check_writable(report)
        demos = lfd.load_demos("spiral")
        records = _records(args.fresh)
        for learner in LEARNERS:
            if learner not in records:
                runs, field = _job(learner, learners=(learner,))
                _record(records, learner, _row(learner, runs, _stated(field)))
            print(f"{learner}: done", flush=True)
        for rate in (*RATES, None):
            key = f"rate {'default' if rate is None else f'{rate:g}'}"
            if key not in records:
                field = lfd.train("contracting_node", demos, seed=0, progress=False,
                                  **({} if rate is None else {"rate": rate}))
                model = Path(OUT) / f"contracting_node-{key.split()[1]}.pt"
                model.parent.mkdir(parents=True, exist_ok=True)
                field.save(str(model))
                runs, _ = _job(model.stem, model=str(model))
                label = f"{field.config['rate']:.3g}" + (" (default)" if rate is None else "")
                _record(records, key, [*_row(label, runs, _stated(field)), float(field.config["rate"])])
            print(f"{key}: done", flush=True)
        rows = [records[learner][0] for learner in LEARNERS]
        points = {learner: records[learner][1] for learner in LEARNERS}
        sweep = [records[k][0] for k in records if k.startswith("rate ")]
        curve = sorted(((float(records[k][2]), records[k][1]) for k in records if k.startswith("rate ")),
                       key=lambda rc: rc[0])
        for shape in SHAPES:
            key = f"certify {shape}"
            if key not in records:
                _record(records, key, _certified(shape))
            print(f"{key}: done", flush=True)
        certified = [records[f"certify {shape}"] for shape in SHAPES]
        lasa_rows, held_out = _lasa()
        _figure(points, curve, held_out, figure)
    except (LfdError, SimError, RobotError, OSError) as e:
        return fail(PROG, str(e))
    header = ["| learner | DTW mm | goal mm | push max dev mm | recovery s | goal mm (pushed) | states |",
              "|---|---|---|---|---|---|---|"]
    text = "\n".join([
        "# The contracting NODE: the paper's two methods in one field", "",
        "Protocol: not a benchmark suite's; `python scripts/recovery_tradeoff.py` (sim.studies.recovery), the default "
        "job's spiral on the torque-driven Panda at 500 Hz, 20 N for 0.2 s on the hand at t = 1 s, seed 0; LASA rows "
        "from the LASA suite's result files (docs/benchmark.md, version 3).", "",
        f"![accuracy against recovery](figures/{figure.name})", "",
        "## Reading", "", *_reading(points, held_out), "",
        "## Every learner on the default job", "", *header, *rows, "",
        "## The contracting NODE over its rate (1/s), same job", "",
        "The rate is stated and certified (`lfd certify`); sqrt(b/a) is the flow's analytic bound.", "",
        *header, *sweep, "",
        "## LASA, 30 shapes: mean DTW (sum, mm)", "",
        "| learner | in-sample | held-out | converged (in-sample starts) | file |", "|---|---|---|---|---|",
        *lasa_rows, "",
        "## The guarantee, checked on LASA shapes (in-sample, `lfd certify`)", "",
        "Growth: the largest |dx(t)| e^(rate t) / |dx(0)| over pairs split along the metric's top eigenvector, "
        "32 pairs on the demos' box grown by half and 32 at 1000 box sizes; it may not exceed s_hi / s_lo. "
        "Eq. (C1) on the grid: the largest generalised eigenvalue against -2 rate. Goal: the starts of the "
        "equilibria search that reach the goal.", "",
        "| shape | verdict | rate (1/s) | s_hi / s_lo | growth near | growth far | Eq. (C1) worst / bound | goal |",
        "|---|---|---|---|---|---|---|---|", *certified, ""])
    atomic_write(report, lambda f: f.write(text.encode()))
    print(f"wrote {report} and {figure}")
    return 0
