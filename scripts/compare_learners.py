#!/usr/bin/env python
"""The paper's experiments side by side on the noisy spiral: figures and reports/comparison.md.

Learners (all seed 0, ``lfd.spiral()``: 5 noisy demos over 5 s): the NODE (default options);
goal contraction (``contraction``) at a weak 0.5/s and a strong 3/s rate; tracking contraction
(``tracking``, Eqs. (T1)-(T5), its default reference conditioned on the start, Eqs. (T2)-(T2a)) at
K = 0.5/s and 3/s, and its mean-reference variant at both; the DMP baseline (``lfd.bench.dmp``).
What is measured (the paper's Table 2): ``lfd.bench.comparison``; the figures (the paper's
Figs. 3-8 and the certificates' g(x)) and the report: ``scripts/_comparison_report.py``.

Usage: python scripts/compare_learners.py [--out reports] [--node-iterations N] [--cache DIR | --no-cache].
Trained models are kept in ``out/compare_cache/`` keyed by learner, options, seed and a hash of the
sources its training depends on (the DMP is refitted: it takes milliseconds), so a re-run retrains
only what changed. Runs single-threaded.
Timings are wall clock on a shared machine: the report states the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
if __name__ == "__main__":  # Ctrl-C and SIGTERM handled from here on (lfd.interrupts)
    from lfd.interrupts import run_script

    run_script(__file__)

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import torch  # noqa: E402
from _comparison_report import (  # noqa: E402
    fig_certificate,
    fig_loss,
    fig_rollouts,
    fig_weak_strong,
    write_report,
)
from tqdm.auto import tqdm  # noqa: E402

import lfd  # noqa: E402
from lfd.bench.comparison import STRONG_RATE, WEAK_RATE, Entry, certificate, measure, trained  # noqa: E402
from lfd.bench.dmp import fit_dmp  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "reports"),
                    help="folder for comparison.md and figures/ (default: reports/)")
    ap.add_argument("--node-iterations", type=int, default=None, help="NODE iterations (default: the learner's)")
    ap.add_argument("--cache", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "out",
                                                    "compare_cache"),
                    help="folder of trained models reused across runs (default: out/compare_cache)")
    ap.add_argument("--no-cache", action="store_true", help="train every model afresh")
    args = ap.parse_args(argv)
    cache = None if args.no_cache else os.path.abspath(args.cache)
    if cache:
        os.makedirs(cache, exist_ok=True)
    torch.set_num_threads(1)
    out = os.path.abspath(args.out)
    os.makedirs(os.path.join(out, "figures"), exist_ok=True)
    t_start, load0 = time.perf_counter(), os.getloadavg()[0]
    demos = lfd.spiral()
    extent = demos.extent
    duration = float(demos.t[0, -1] - demos.t[0, 0])

    steps = tqdm(total=13, desc="compare", unit="step")
    steps.set_postfix_str("training the NODE")
    node_opts: dict[str, Any] = {} if args.node_iterations is None else {"iterations": args.node_iterations}
    entries: dict[str, Entry] = {"node": Entry("NODE", trained("node", demos, cache, **node_opts))}
    steps.update()
    steps.set_postfix_str("training the other learners")
    entries["cw"] = Entry(f"goal contraction {WEAK_RATE:g}/s", trained("contraction", demos, cache, rate=WEAK_RATE))
    entries["cs"] = Entry(f"goal contraction {STRONG_RATE:g}/s",
                          trained("contraction", demos, cache, rate=STRONG_RATE))
    entries["tw"] = Entry(f"tracking {WEAK_RATE:g}/s", trained("tracking", demos, cache, rate=WEAK_RATE))
    entries["ts"] = Entry(f"tracking {STRONG_RATE:g}/s", trained("tracking", demos, cache, rate=STRONG_RATE))
    entries["tmw"] = Entry(f"tracking {WEAK_RATE:g}/s, mean reference",
                           trained("tracking", demos, cache, rate=WEAK_RATE, condition_start=False))
    entries["tm"] = Entry(f"tracking {STRONG_RATE:g}/s, mean reference",
                          trained("tracking", demos, cache, rate=STRONG_RATE, condition_start=False))
    entries["dmp"] = Entry("DMP", fit_dmp(demos))
    steps.update()
    lo, hi = demos.bounds(0.5)
    steps.set_postfix_str("certificates")
    for e in entries.values():
        e.cert = certificate(e, lo, hi)
    steps.update()
    for e in entries.values():
        steps.set_postfix_str(f"measuring {e.label}")
        measure(e, demos, extent, duration)
        steps.update()
    figs = {k: f"figures/comparison_{k}.png"
            for k in ("weak_strong", "weak_strong_tracking", "weak_strong_tracking_mean", "rollouts", "loss",
                      "certificate")}
    steps.set_postfix_str("figures")
    fig_weak_strong(entries["cw"], entries["cs"], demos, extent, os.path.join(out, figs["weak_strong"]))
    fig_weak_strong(entries["tw"], entries["ts"], demos, extent, os.path.join(out, figs["weak_strong_tracking"]))
    fig_weak_strong(entries["tmw"], entries["tm"], demos, extent,
                    os.path.join(out, figs["weak_strong_tracking_mean"]))
    fig_rollouts([entries[k] for k in ("node", "cw", "ts", "dmp")], demos, os.path.join(out, figs["rollouts"]))
    fig_loss(entries["node"], entries["cw"], os.path.join(out, figs["loss"]))
    fig_certificate([entries[k] for k in ("node", "cw", "cs")], demos, os.path.join(out, figs["certificate"]))
    steps.update()
    wall = time.perf_counter() - t_start
    write_report(os.path.join(out, "comparison.md"), entries, demos, extent, (load0, os.getloadavg()[0]), wall, figs)
    steps.update()
    steps.close()
    for e in entries.values():
        print(e.label, {k: round(v, 6) for k, v in e.numbers.items()})
        print("   certificate:", e.cert)
    print(f"wrote {os.path.join(out, 'comparison.md')} in {wall:.0f} s")
    return 0
